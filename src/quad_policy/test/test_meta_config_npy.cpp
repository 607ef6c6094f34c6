// Policy metadata, config/policy.yaml, .npy and fixture round trips, and their error messages.
#include <gtest/gtest.h>

#include <quad_core/strict_yaml.h>

#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "quad_policy/config.h"
#include "quad_policy/fixture.h"
#include "quad_policy/npy.h"
#include "quad_policy/policy_meta.h"
#include "quad_policy/preprocessing.h"

namespace quad_policy {
namespace {

// The metadata as learning/export.py writes it (abridged to what the nodes read, plus unread keys).
std::string MetaJson(const std::string& representation = "bspline", const std::string& order = "3",
                     const std::string& model = "{\"poly_degree\": 5, \"variant\": \"small\"}") {
  return "{\"format\": \"quad_il_policy/1\", \"inputs\": {\"depth_m\": \"(B, H, W) float32 metres\"},"
         " \"output\": {\"bspline_order\": " +
         order +
         ", \"horizon_s\": 2.0, \"knot_dt_s\": 0.2857142857142857,"
         " \"network_frame\": \"local\", \"network_representation\": \"" +
         representation +
         "\","
         " \"num_ctrl_pts\": 10}, \"preprocessing\": {\"input_height\": 96, \"input_width\": 128,"
         " \"max_depth_m\": 10.0, \"position_scale_m\": 10.0, \"state_frame\": \"world\","
         " \"velocity_scale_mps\": 3.0}, \"model\": " +
         model + ", \"run\": null}";
}

std::string ErrorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const std::exception& e) {
    return e.what();
  }
  return "";
}

TEST(PolicyMeta, ParsesTheExportersMetadata) {
  const PolicyMeta m = ParsePolicyMeta(MetaJson(), "p.ts");
  EXPECT_EQ(m.input_height, 96);
  EXPECT_EQ(m.input_width, 128);
  EXPECT_DOUBLE_EQ(m.max_depth_m, 10.0);
  EXPECT_EQ(m.state_frame, PolicyFrame::kWorld);
  EXPECT_EQ(m.output_frame, PolicyFrame::kLocal);
  EXPECT_EQ(m.representation, OutputRepresentation::kBspline);
  EXPECT_EQ(m.num_ctrl_pts, 10);
  EXPECT_NEAR(m.knot_dt_s(), 2.0 / 7.0, 1e-15);
  EXPECT_EQ(m.output_dim(), 30);
  const PolicyMeta p = ParsePolicyMeta(MetaJson("polynomial"), "p.ts");
  EXPECT_EQ(p.poly_degree, 5);
  EXPECT_EQ(p.output_dim(), 18);
}

TEST(PolicyMeta, ErrorsNameTheFileAndTheKey) {
  EXPECT_NE(ErrorOf([] {
              ParsePolicyMeta(MetaJson("spline"), "p.ts");
            }).find("p.ts: policy metadata key 'output.network_representation' must be"),
            std::string::npos);
  EXPECT_NE(ErrorOf([] { ParsePolicyMeta(MetaJson("bspline", "4"), "p.ts"); }).find("'output.bspline_order'"),
            std::string::npos);
  EXPECT_NE(ErrorOf([] {
              ParsePolicyMeta(MetaJson("polynomial", "3", "{}"), "p.ts");
            }).find("'model.poly_degree' is missing"),
            std::string::npos);
  std::string other = MetaJson();
  other.replace(other.find("quad_il_policy/1"), 16, "quad_il_policy/9");
  EXPECT_NE(
      ErrorOf([&] { ParsePolicyMeta(other, "p.ts"); }).find("unsupported policy format 'quad_il_policy/9'"),
      std::string::npos);
  EXPECT_NE(ErrorOf([] { ParsePolicyMeta("{not json", "p.ts"); }).find("not valid JSON"), std::string::npos);
}

TEST(PolicyMeta, VelocityInputIsOptionalAndZeroesTheVelocityEntries) {
  EXPECT_TRUE(ParsePolicyMeta(MetaJson(), "p.ts").velocity_input);  // files exported before the key
  const std::string key = "\"velocity_scale_mps\": 3.0";
  std::string blind = MetaJson();
  blind.replace(blind.find(key), key.size(), key + ", \"velocity_input\": false");
  const PolicyMeta m = ParsePolicyMeta(blind, "p.ts");
  EXPECT_FALSE(m.velocity_input);
  VehicleState s;
  s.p_world_body = Eigen::Vector3d(1.0, 2.0, 1.5);
  s.v_world = Eigen::Vector3d(2.0, -1.0, 0.5);
  s.q_world_body = Eigen::Quaterniond(Eigen::AngleAxisd(0.4, Eigen::Vector3d::UnitZ()));
  const StateVector x = EncodeState(s, Eigen::Vector3d(9.0, 9.0, 1.0), m);
  EXPECT_EQ(x[3], 0.0f);
  EXPECT_EQ(x[4], 0.0f);
  EXPECT_EQ(x[5], 0.0f);
  EXPECT_FLOAT_EQ(x[0], 0.1f);  // the rest is untouched
  std::string bad = MetaJson();
  bad.replace(bad.find(key), key.size(), key + ", \"velocity_input\": 7");
  EXPECT_NE(ErrorOf([&] {
              ParsePolicyMeta(bad, "p.ts");
            }).find("'preprocessing.velocity_input' must be true or false, got 7"),
            std::string::npos);
}

TEST(PolicyMeta, HypothesesAreOptionalBoundedAndSetTheNetworkOutputWidth) {
  const PolicyMeta one = ParsePolicyMeta(MetaJson(), "p.ts");  // files exported before the key
  EXPECT_EQ(one.hypotheses, 1);
  EXPECT_EQ(one.network_output_dim(), 30);
  const std::string key = "\"num_ctrl_pts\": 10";
  const auto with = [&](const std::string& value) {
    std::string j = MetaJson();
    j.replace(j.find(key), key.size(), key + ", \"hypotheses\": " + value);
    return j;
  };
  const PolicyMeta three = ParsePolicyMeta(with("3"), "p.ts");
  EXPECT_EQ(three.hypotheses, 3);
  EXPECT_EQ(three.output_dim(), 30);
  EXPECT_EQ(three.network_output_dim(), 93);
  EXPECT_FALSE(three.mean_first);
  const std::string three_key = "\"hypotheses\": 3";
  std::string mean = with("3");
  mean.replace(mean.find(three_key), three_key.size(), three_key + ", \"hypotheses_first\": \"mean\"");
  EXPECT_TRUE(ParsePolicyMeta(mean, "p.ts").mean_first);
  std::string best = with("3");
  best.replace(best.find(three_key), three_key.size(), three_key + ", \"hypotheses_first\": \"best\"");
  EXPECT_NE(ErrorOf([&] {
              ParsePolicyMeta(best, "p.ts");
            }).find("'output.hypotheses_first' must be 'confidence' or 'mean', got 'best'"),
            std::string::npos);
  for (const std::string bad : {"0", "9", "2.5", "true", "\"3\""}) {
    EXPECT_NE(ErrorOf([&] {
                ParsePolicyMeta(with(bad), "p.ts");
              }).find("p.ts: policy metadata key 'output.hypotheses' must be an integer in [1, 8]"),
              std::string::npos)
        << bad;
  }
}

TEST(OrderedPlans, MostConfidentFirstTiesByIndexNanLast) {
  PolicyMeta m = ParsePolicyMeta(MetaJson(), "p.ts");
  m.hypotheses = 3;
  std::vector<float> y(93);
  for (int i = 0; i < 90; ++i) y[i] = static_cast<float>(i);
  const auto order = [&](float a, float b, float c) {
    y[90] = a;
    y[91] = b;
    y[92] = c;
    std::vector<int> idx;
    for (const HypothesisPlan& p : OrderedPlans(y, m)) {
      EXPECT_EQ(p.y.size(), 30u);
      EXPECT_EQ(p.y.front(), 30.0f * p.index);
      idx.push_back(p.index);
    }
    return idx;
  };
  EXPECT_EQ(order(0.1f, 2.0f, -1.0f), (std::vector<int>{1, 0, 2}));
  EXPECT_EQ(order(1.0f, 1.0f, 1.0f), (std::vector<int>{0, 1, 2}));
  const float nan = std::numeric_limits<float>::quiet_NaN();
  EXPECT_EQ(order(nan, 0.0f, 3.0f), (std::vector<int>{2, 1, 0}));
  EXPECT_EQ(order(nan, nan, 0.0f), (std::vector<int>{2, 0, 1}));
  m.mean_first = true;  // plan 0 first whatever its logit, then the others by logit
  EXPECT_EQ(order(9.0f, 0.0f, 3.0f), (std::vector<int>{0, 2, 1}));
  m.mean_first = false;
  y.pop_back();
  EXPECT_NE(ErrorOf([&] { OrderedPlans(y, m); }).find("network output has 92 values, the policy declares 93"),
            std::string::npos);
  m.hypotheses = 1;
  const std::vector<float> single(30, 1.5f);
  const std::vector<HypothesisPlan> plans = OrderedPlans(single, m);
  ASSERT_EQ(plans.size(), 1u);
  EXPECT_EQ(plans[0].index, 0);
  EXPECT_EQ(plans[0].y, single);
}

TEST(PolicyNodeConfig, TheRepositoryConfigLoads) {
  // config/policy.yaml holds every default: the configuration `make eval`, `make demo` and infer.launch fly.
  const PolicyNodeConfig c = LoadPolicyNodeConfig(QUAD_IL_CONFIG_DIR "/policy.yaml");
  EXPECT_EQ(c.num_threads, 1);
  EXPECT_EQ(c.replan_rate_hz, 10.0);
  EXPECT_EQ(c.lockstep_consumer, "policy");
  EXPECT_EQ(c.odom_period_s, 0.005);
  EXPECT_EQ(c.refusal.action, RefusalAction::kStop);
  EXPECT_TRUE(c.safety.enabled);
  EXPECT_NO_THROW(ValidateSafetyConfig(c.safety));
  EXPECT_EQ(c.recovery.goal_yaw_offsets_deg, (std::vector<double>{20, -20, 40, -40, 60, -60}));
  EXPECT_EQ(c.recovery.final_approach_m, 1.5);
  EXPECT_EQ(c.keeping.commit_s, 0.3);
  EXPECT_TRUE(c.keeping.on_refusal);
  EXPECT_EQ(c.safety.vehicle_radius_m, 0.40);
}

TEST(PolicyNodeConfig, OverlaysChangeOnlyTheirKeys) {
  const PolicyNodeConfig base = LoadPolicyNodeConfig(QUAD_IL_CONFIG_DIR "/policy.yaml");
  const PolicyNodeConfig r = LoadPolicyNodeConfig(QUAD_IL_CONFIG_DIR "/policy_recovery.yaml");
  EXPECT_EQ(r.recovery.goal_yaw_offsets_deg, base.recovery.goal_yaw_offsets_deg);
  EXPECT_EQ(r.safety.vehicle_radius_m, 0.40);
  EXPECT_EQ(r.replan_rate_hz, 0.0);
  EXPECT_EQ(r.recovery.final_approach_m, 0.0);
  EXPECT_EQ(r.keeping.commit_s, 0.0);
  EXPECT_FALSE(r.keeping.on_refusal);
  const PolicyNodeConfig r10 = LoadPolicyNodeConfig(QUAD_IL_CONFIG_DIR "/policy_recovery_r10.yaml");
  EXPECT_EQ(r10.replan_rate_hz, 10.0);  // an overlay of policy_recovery.yaml: a chain
  EXPECT_EQ(r10.keeping.commit_s, 0.0);
  const PolicyNodeConfig keep = LoadPolicyNodeConfig(QUAD_IL_CONFIG_DIR "/policy_keep.yaml");
  EXPECT_EQ(keep.keeping.commit_s, base.keeping.commit_s);  // the default under its measured name
  EXPECT_EQ(keep.recovery.final_approach_m, base.recovery.final_approach_m);
}

class TempDir : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = std::filesystem::temp_directory_path() /
           ("quad_policy_test_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    std::filesystem::create_directories(dir_);
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }
  std::string Path(const std::string& name) const { return (dir_ / name).string(); }
  std::string Write(const std::string& name, const std::string& text) const {
    std::ofstream(Path(name)) << text;
    return Path(name);
  }
  std::filesystem::path dir_;
};

using Overlay = TempDir;

TEST_F(Overlay, MergesSectionsKeyByKeyAndReplacesListsAndNamesBadKeys) {
  Write("base.yaml", "a: 1\nsec:\n  x: [1, 2]\n  y: 2\n");
  const YAML::Node merged = LoadOverlayTree(Write("o.yaml", "overlay_of: base.yaml\nsec:\n  x: [3]\n"));
  EXPECT_EQ(merged["a"].as<int>(), 1);
  EXPECT_EQ(merged["sec"]["x"].as<std::vector<int>>(), (std::vector<int>{3}));
  EXPECT_EQ(merged["sec"]["y"].as<int>(), 2);
  EXPECT_FALSE(merged["overlay_of"].IsDefined());
  const std::string typo =
      ErrorOf([&] { LoadOverlayTree(Write("t.yaml", "overlay_of: base.yaml\nsec:\n  z: 1\n")); });
  EXPECT_NE(typo.find("t.yaml (overlay of"), std::string::npos) << typo;
  EXPECT_NE(typo.find("key 'sec.z' does not exist in the base config"), std::string::npos) << typo;
  const std::string kind =
      ErrorOf([&] { LoadOverlayTree(Write("k.yaml", "overlay_of: base.yaml\nsec: 1\n")); });
  EXPECT_NE(kind.find("key 'sec' is a section in the base config"), std::string::npos) << kind;
  EXPECT_NE(
      ErrorOf([&] { LoadOverlayTree(Write("m.yaml", "overlay_of: nowhere.yaml\n")); }).find("cannot open"),
      std::string::npos);
  Write("c1.yaml", "overlay_of: c2.yaml\n");
  Write("c2.yaml", "overlay_of: c1.yaml\n");
  EXPECT_NE(ErrorOf([&] { LoadOverlayTree(Path("c1.yaml")); }).find("overlay cycle"), std::string::npos);
}

TEST_F(Overlay, APolicyOverlayLoadsStrictlyAfterTheMerge) {
  const std::string base = std::string(QUAD_IL_CONFIG_DIR) + "/policy.yaml";
  const PolicyNodeConfig c =
      LoadPolicyNodeConfig(Write("p.yaml", "overlay_of: " + base + "\nsafety:\n  max_vel_mps: 2.0\n"));
  EXPECT_EQ(c.safety.max_vel_mps, 2.0);
  EXPECT_EQ(c.safety.max_acc_mps2, LoadPolicyNodeConfig(base).safety.max_acc_mps2);
  EXPECT_NE(
      ErrorOf([&] {
        LoadPolicyNodeConfig(Write("q.yaml", "overlay_of: " + base + "\nsafety:\n  max_vel_mps: -2.0\n"));
      }).find("'safety.max_vel_mps' has value -2"),
      std::string::npos);
  // A removed knob is an unknown key, named.
  EXPECT_NE(ErrorOf([&] {
              LoadPolicyNodeConfig(
                  Write("r.yaml", "overlay_of: " + base + "\nrecovery:\n  steer_clearance_m: 1.0\n"));
            }).find("'recovery.steer_clearance_m' does not exist"),
            std::string::npos);
}

std::string RepoConfigWith(const std::string& from, const std::string& to) {
  std::ifstream f(QUAD_IL_CONFIG_DIR "/policy.yaml");
  std::string text((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  const std::size_t at = text.find(from);
  if (at == std::string::npos) throw std::runtime_error("test setup: '" + from + "' not in policy.yaml");
  return text.replace(at, from.size(), to);
}

TEST(PolicyNodeConfig, TyposMissingKeysAndBadValuesAreNamed) {
  EXPECT_NE(ErrorOf([] {
              PolicyNodeConfigFromString(
                  RepoConfigWith("  max_vel_mps:", "  max_vel_mp: 3.0\n  max_vel_mps:"), "c");
            }).find("unknown config key(s): 'safety.max_vel_mp'"),
            std::string::npos);
  EXPECT_NE(ErrorOf([] {
              PolicyNodeConfigFromString(RepoConfigWith("action: stop", "action: land"), "c");
            }).find("'refusal.action' has value 'land'"),
            std::string::npos);
  EXPECT_NE(ErrorOf([] {
              PolicyNodeConfigFromString(RepoConfigWith("num_threads: 1", "num_threads: 0"), "c");
            }).find("'num_threads' has value 0"),
            std::string::npos);
  EXPECT_NE(ErrorOf([] {
              PolicyNodeConfigFromString(RepoConfigWith("goal_tolerance_m: 0.5", ""), "c");
            }).find("missing required key 'goal_tolerance_m'"),
            std::string::npos);
  EXPECT_NE(ErrorOf([] {
              PolicyNodeConfigFromString(RepoConfigWith("odom_wait_s: 0.2", "odom_wait_s: 0"), "c");
            }).find("'odom_wait_s' has value 0"),
            std::string::npos);
  EXPECT_NE(ErrorOf([] {
              PolicyNodeConfigFromString(RepoConfigWith("commit_s: 0.3", "commit_s: -1"), "c");
            }).find("'keeping.commit_s' has value -1"),
            std::string::npos);
  EXPECT_NE(ErrorOf([] {
              PolicyNodeConfigFromString(
                  RepoConfigWith("final_approach_acc_mps2: 2.0", "final_approach_acc_mps2: 0"), "c");
            }).find("'recovery.final_approach_acc_mps2' has value 0"),
            std::string::npos);
}

TEST(PolicyNodeConfig, RecoveryTurnsAreReadAndBadOnesNamed) {
  const std::string key = "goal_yaw_offsets_deg: [20, -20, 40, -40, 60, -60]";
  const PolicyNodeConfig c =
      PolicyNodeConfigFromString(RepoConfigWith(key, "goal_yaw_offsets_deg: [30, -30.5]"), "c");
  EXPECT_EQ(c.recovery.goal_yaw_offsets_deg, (std::vector<double>{30.0, -30.5}));
  for (const auto& [value, message] : std::vector<std::pair<std::string, std::string>>{
           {"[0]", "non-zero"}, {"[200]", "within [-180, 180]"}, {"[.nan]", "finite"}}) {
    const std::string err = ErrorOf(
        [&] { PolicyNodeConfigFromString(RepoConfigWith(key, "goal_yaw_offsets_deg: " + value), "c"); });
    EXPECT_NE(err.find("recovery.goal_yaw_offsets_deg"), std::string::npos) << err;
    EXPECT_NE(err.find(message), std::string::npos) << err;
  }
  std::string many = "[";
  for (int i = 1; i <= 17; ++i) many += std::to_string(i) + (i < 17 ? ", " : "]");
  EXPECT_NE(ErrorOf([&] {
              PolicyNodeConfigFromString(RepoConfigWith(key, "goal_yaw_offsets_deg: " + many), "c");
            }).find("17 angles, at most 16"),
            std::string::npos);
  RecoveryConfig bad;
  bad.final_approach_m = std::nan("");
  EXPECT_NE(ErrorOf([&] { ValidateRecoveryConfig(bad); }).find("recovery.final_approach_m must be >= 0"),
            std::string::npos);
}

using Npy = TempDir;

TEST_F(Npy, ArraysRoundTripWithShapeAndDtype) {
  const NpyArray f = NpyArray::FromFloat({1.5f, -2.0f, 3.25f, 0.0f, 1e-7f, 7.0f}, {2, 3});
  WriteNpy(Path("f.npy"), f);
  const NpyArray g = ReadNpy(Path("f.npy"));
  EXPECT_EQ(g.dtype, "<f4");
  EXPECT_EQ(g.shape, (std::vector<std::size_t>{2, 3}));
  EXPECT_EQ(g.as_float(), f.as_float());
  WriteNpy(Path("d.npy"), NpyArray::FromDouble({0.1, 0.2, 0.3, 0.4}, {4}));
  EXPECT_EQ(ReadNpy(Path("d.npy")).as_double(), (std::vector<double>{0.1, 0.2, 0.3, 0.4}));
  WriteNpy(Path("s.npy"), NpyArray::FromInt32({-7}, {}));
  const NpyArray s = ReadNpy(Path("s.npy"));
  EXPECT_TRUE(s.shape.empty());
  EXPECT_EQ(s.as_double(), std::vector<double>{-7.0});
}

TEST_F(Npy, BadFilesAreRejectedWithTheReason) {
  WriteNpy(Path("f.npy"), NpyArray::FromFloat({1, 2, 3, 4}, {4}));
  std::filesystem::resize_file(Path("f.npy"), std::filesystem::file_size(Path("f.npy")) - 3);
  EXPECT_NE(ErrorOf([&] { ReadNpy(Path("f.npy")); }).find("truncated data"), std::string::npos);
  std::ofstream(Path("x.npy")) << "hello";
  EXPECT_NE(ErrorOf([&] { ReadNpy(Path("x.npy")); }).find("not an .npy file"), std::string::npos);
  EXPECT_NE(ErrorOf([&] { ReadNpy(Path("missing.npy")); }).find("cannot open"), std::string::npos);
  NpyArray fortran = NpyArray::FromFloat({1, 2}, {2});
  WriteNpy(Path("o.npy"), fortran);
  std::fstream io(Path("o.npy"), std::ios::in | std::ios::out | std::ios::binary);
  std::string head(64, '\0');
  io.read(head.data(), 64);
  head.replace(head.find("False"), 5, "True ");
  io.seekp(0);
  io.write(head.data(), 64);
  io.close();
  EXPECT_NE(ErrorOf([&] { ReadNpy(Path("o.npy")); }).find("Fortran"), std::string::npos);
}

using Fixture = TempDir;

TEST_F(Fixture, DecisionFixturesRoundTrip) {
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> u(-5.0, 5.0);
  DecisionFixture fx;
  fx.fx = 96.8;
  fx.fy = 96.8;
  fx.cx = 79.5;
  fx.cy = 59.5;
  fx.T_body_camera.translation() = Eigen::Vector3d(0.1, 0.0, 0.0);
  for (int i = 0; i < 3; ++i) {
    RecordedFrame f;
    f.stamp_s = 1.0 + i / 30.0;
    f.depth.width = 4;
    f.depth.height = 3;
    for (int k = 0; k < 12; ++k) f.depth.depth_m.push_back(static_cast<float>(u(rng)));
    f.state.p_world_body = Eigen::Vector3d(u(rng), u(rng), u(rng));
    f.state.v_world = Eigen::Vector3d(u(rng), u(rng), u(rng));
    f.state.q_world_body = Eigen::Quaterniond(u(rng), u(rng), u(rng), u(rng)).normalized();
    f.goal_world = Eigen::Vector3d(u(rng), u(rng), u(rng));
    fx.frames.push_back(f);
  }
  WriteDecisionFixture(Path("fx"), fx);
  const DecisionFixture back = ReadDecisionFixture(Path("fx"));
  ASSERT_EQ(back.frames.size(), 3u);
  EXPECT_EQ(back.fx, fx.fx);
  EXPECT_EQ(back.cy, fx.cy);
  EXPECT_TRUE(back.T_body_camera.isApprox(fx.T_body_camera, 0.0));
  for (int i = 0; i < 3; ++i) {
    EXPECT_EQ(back.frames[i].stamp_s, fx.frames[i].stamp_s);
    EXPECT_EQ(back.frames[i].depth.depth_m, fx.frames[i].depth.depth_m);
    EXPECT_EQ(back.frames[i].state.p_world_body, fx.frames[i].state.p_world_body);
    EXPECT_EQ(back.frames[i].state.v_world, fx.frames[i].state.v_world);
    EXPECT_EQ(back.frames[i].state.q_world_body.coeffs(), fx.frames[i].state.q_world_body.coeffs());
    EXPECT_EQ(back.frames[i].goal_world, fx.frames[i].goal_world);
  }
  // A file of the wrong shape is named.
  WriteNpy(Path("fx/goal_world.npy"), NpyArray::FromDouble(std::vector<double>(6), {2, 3}));
  EXPECT_NE(
      ErrorOf([&] { ReadDecisionFixture(Path("fx")); }).find("goal_world.npy: dimension 0 is 2, expected 3"),
      std::string::npos);
}

}  // namespace
}  // namespace quad_policy
