// World generation (determinism, clear zones, gaps) and the world YAML format (round trip, strict errors).
#include "quad_sim/world.h"

#include "test_util.h"

#include <gtest/gtest.h>
#include <quad_core/strict_yaml.h>

#include <regex>
#include <string>

using quad_sim::GenerateWorld;
using quad_sim::World;
using quad_sim::WorldGenConfig;
using quad_sim_test::TempFile;

namespace {

WorldGenConfig DefaultGen() { return quad_sim_test::DefaultSimConfig().world_gen; }

void ExpectWorldError(const std::string& text, const std::string& needle) {
  try {
    quad_sim::WorldFromYaml(text, "test.yaml");
    FAIL() << "expected an error mentioning '" << needle << "'";
  } catch (const quad_core::ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
  }
}

const char* kOneBox = R"(format: quad_sim_world
version: 1
seed: 3
bounds_min_m: [-1, -1, 0]
bounds_max_m: [1, 1, 2]
boxes:
  - {center_m: [0.5, 0, 1], q_xyzw: [0, 0, 0, 1], size_m: [0.2, 0.2, 0.2]}
)";

}  // namespace

TEST(WorldGenerator, SameSeedGivesTheSameWorld) {
  const WorldGenConfig cfg = DefaultGen();
  const World a = GenerateWorld(cfg, 12345);
  const World b = GenerateWorld(cfg, 12345);
  EXPECT_TRUE(a == b);
  const World c = GenerateWorld(cfg, 12346);
  EXPECT_FALSE(a == c);
  EXPECT_EQ(a.seed, 12345u);
}

TEST(WorldGenerator, DefaultConfigFills40x40x5AreaWith200Boxes) {
  const WorldGenConfig cfg = DefaultGen();
  const World w = GenerateWorld(cfg, 1);
  ASSERT_EQ(w.boxes.size(), 200u);
  EXPECT_EQ(w.bounds_max_m - w.bounds_min_m, Eigen::Vector3d(40, 40, 5));
  for (const auto& b : w.boxes) {
    EXPECT_GE(b.center_world_m.x(), cfg.bounds_min_m.x());
    EXPECT_LE(b.center_world_m.x(), cfg.bounds_max_m.x());
    EXPECT_GE(b.center_world_m.y(), cfg.bounds_min_m.y());
    EXPECT_LE(b.center_world_m.y(), cfg.bounds_max_m.y());
    EXPECT_GE(b.center_world_m.z(), cfg.center_z_min_m);
    EXPECT_LE(b.center_world_m.z(), cfg.center_z_max_m);
    EXPECT_TRUE((b.size_m.array() >= cfg.size_min_m.array()).all());
    EXPECT_TRUE((b.size_m.array() <= cfg.size_max_m.array()).all());
    EXPECT_NEAR(b.q_world_box.norm(), 1.0, 1e-15);
  }
}

TEST(WorldGenerator, ClearZonesAndMinimumGapAreRespected) {
  WorldGenConfig cfg = DefaultGen();
  ASSERT_EQ(cfg.clear_zones.size(), 2u);  // start and goal from sim.yaml
  cfg.AddClearZone(Eigen::Vector3d(0, 0, 1));
  for (uint64_t seed : {1u, 2u, 3u}) {
    const World w = GenerateWorld(cfg, seed);
    for (const auto& z : cfg.clear_zones) {
      for (size_t i = 0; i < w.boxes.size(); ++i) {
        EXPECT_GT(quad_sim::PointBoxDistance(z.center_world_m, w.boxes[i]), z.radius_m) << "box " << i;
      }
    }
    for (size_t i = 0; i < w.boxes.size(); ++i) {
      for (size_t j = i + 1; j < w.boxes.size(); ++j) {
        ASSERT_GE(quad_sim::BoxBoxDistance(w.boxes[i], w.boxes[j]), cfg.min_gap_m) << i << " " << j;
      }
    }
  }
}

TEST(WorldGenerator, DensityOverridesCount) {
  WorldGenConfig cfg = DefaultGen();
  cfg.density_boxes_per_100m2 = 5.0;  // 1600 m^2 -> 80 boxes
  EXPECT_EQ(GenerateWorld(cfg, 1).boxes.size(), 80u);
}

TEST(WorldGenerator, ImpossibleDensityIsAClearError) {
  WorldGenConfig cfg = DefaultGen();
  cfg.bounds_min_m = Eigen::Vector3d(-2, -2, 0);
  cfg.bounds_max_m = Eigen::Vector3d(2, 2, 5);
  cfg.clear_zones.clear();
  cfg.num_boxes = 500;
  try {
    GenerateWorld(cfg, 1);
    FAIL();
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("of 500 boxes"), std::string::npos) << e.what();
  }
}

TEST(WorldFile, SaveLoadRoundTripIsIdentical) {
  const World w = GenerateWorld(DefaultGen(), 99);
  TempFile f(".yaml");
  quad_sim::SaveWorld(w, f.path());
  const World back = quad_sim::LoadWorld(f.path());
  EXPECT_TRUE(back == w);
  // Saving the loaded world again gives the same bytes.
  EXPECT_EQ(quad_sim::WorldToYaml(back), quad_sim_test::ReadFile(f.path()));
}

TEST(WorldFile, HandBuiltGateWorldLoads) {
  const World w = quad_sim::LoadWorld(quad_sim_test::RepoPath("config/worlds/gate.yaml"));
  ASSERT_EQ(w.boxes.size(), 4u);
  EXPECT_NEAR(w.boxes[3].q_world_box.norm(), 1.0, 1e-15);
  EXPECT_EQ(w.boxes[2].size_m, Eigen::Vector3d(0.5, 3.5, 0.5));
}

TEST(WorldFile, MinimalFileLoads) {
  const World w = quad_sim::WorldFromYaml(kOneBox);
  ASSERT_EQ(w.boxes.size(), 1u);
  EXPECT_EQ(w.seed, 3u);
}

TEST(WorldFile, UnknownBoxKeyIsNamed) {
  ExpectWorldError(std::regex_replace(kOneBox, std::regex("size_m"), "size_m: [1, 1, 1], colour: red, x"),
                   "boxes[0]: unknown config key(s): 'colour'");
}

TEST(WorldFile, MissingKeyIsNamed) {
  ExpectWorldError(std::regex_replace(kOneBox, std::regex("seed: 3\n"), ""), "missing required key 'seed'");
  ExpectWorldError(std::regex_replace(kOneBox, std::regex(", q_xyzw: \\[0, 0, 0, 1\\]"), ""),
                   "boxes[0]: missing required key 'q_xyzw'");
}

TEST(WorldFile, BadValuesAreNamed) {
  ExpectWorldError(std::regex_replace(kOneBox, std::regex("quad_sim_world"), "other"),
                   "'format' has value 'other'");
  ExpectWorldError(std::regex_replace(kOneBox, std::regex("version: 1"), "version: 2"), "supports version 1");
  ExpectWorldError(std::regex_replace(kOneBox, std::regex("\\[0, 0, 0, 1\\]"), "[0, 0, 0, 0]"),
                   "zero quaternion");
  ExpectWorldError(std::regex_replace(kOneBox, std::regex("\\[0.2, 0.2, 0.2\\]"), "[0.2, -0.2, 0.2]"),
                   "'size_m' has element");
  ExpectWorldError(std::regex_replace(kOneBox, std::regex("\\[0.5, 0, 1\\]"), "[0.5, .nan, 1]"), "center_m");
}
