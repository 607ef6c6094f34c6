#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <random>
#include <tuple>
#include <vector>

#include "fast_planner/voxel_map.h"
#include "test_util.h"

namespace fast_planner {
namespace {

using test::ConstantDepthFrame;
using test::SmallMapConfig;

// Camera at (0.5, 3, 2) looking along +x; a constant depth of 3.05 m is a wall at x = 3.55 m (voxel x = 35).
class DepthMapTest : public ::testing::Test {
 protected:
  DepthMapTest() : map_(SmallMapConfig(Eigen::Vector3d(6.0, 6.0, 4.0))) {}
  const Eigen::Vector3d cam_{0.5, 3.05, 2.05};
  VoxelMap map_;
};

TEST_F(DepthMapTest, WallSeenThreeTimesBecomesOccupiedAndSpaceBeforeItFree) {
  const DepthFrame f = ConstantDepthFrame(3.05f, cam_);
  map_.IntegrateDepth(f);
  // One hit (p = 0.65) is below the occupancy threshold (p = 0.80).
  EXPECT_FALSE(map_.IsOccupied(Eigen::Vector3i(35, 30, 20)));
  map_.IntegrateDepth(f);
  const MapUpdateStats s = map_.IntegrateDepth(f);
  EXPECT_EQ(s.rays, 64 * 48);
  EXPECT_GT(s.newly_occupied, 0);
  EXPECT_TRUE(map_.IsOccupied(Eigen::Vector3i(35, 30, 20)));
  EXPECT_TRUE(map_.IsOccupied(Eigen::Vector3d(3.55, 4.0, 2.5)));
  for (int x = 6; x < 34; ++x) {
    EXPECT_LT(map_.LogOdds(Eigen::Vector3i(x, 30, 20)), 0.0f) << "x=" << x;
    EXPECT_FALSE(map_.IsOccupied(Eigen::Vector3i(x, 30, 20)));
  }
  // Behind the wall nothing was observed.
  EXPECT_EQ(map_.LogOdds(Eigen::Vector3i(45, 30, 20)), 0.0f);
  EXPECT_FALSE(map_.IsOccupied(Eigen::Vector3i(45, 30, 20)));
}

TEST_F(DepthMapTest, NoReturnPixelsClearFreeSpaceUpToMaxRangeOnly) {
  // 320x240: rays are closer than a voxel up to the 5 m range.
  const DepthFrame f = ConstantDepthFrame(std::numeric_limits<float>::infinity(), cam_, 320, 240);
  for (int i = 0; i < 5; ++i) map_.IntegrateDepth(f);
  EXPECT_EQ(map_.CountOccupied(), 0);
  // Along the optical axis the range is 5 m but the map ends at x = 6 m: everything in between is free.
  for (int x = 6; x < 55; ++x) EXPECT_LT(map_.LogOdds(Eigen::Vector3i(x, 30, 20)), 0.0f) << "x=" << x;
}

TEST_F(DepthMapTest, ReturnsBeyondMaxRangeAreTreatedAsFreeSpace) {
  MapConfig c = SmallMapConfig(Eigen::Vector3d(6.0, 6.0, 4.0));
  c.depth.max_ray_length_m = 2.0;
  VoxelMap map(c);
  const DepthFrame f = ConstantDepthFrame(3.05f, cam_);
  for (int i = 0; i < 5; ++i) map.IntegrateDepth(f);
  EXPECT_EQ(map.CountOccupied(), 0);
  EXPECT_LT(map.LogOdds(Eigen::Vector3i(20, 30, 20)), 0.0f);  // 1.5 m ahead
  EXPECT_EQ(map.LogOdds(Eigen::Vector3i(30, 30, 20)), 0.0f);  // 2.5 m ahead: beyond range
}

TEST_F(DepthMapTest, ClampedLogOddsLetAnObstacleDisappearAfterFourMisses) {
  const DepthFrame wall = ConstantDepthFrame(3.05f, cam_);
  for (int i = 0; i < 50; ++i) map_.IntegrateDepth(wall);
  const Eigen::Vector3i v(35, 30, 20);
  ASSERT_TRUE(map_.IsOccupied(v));
  // Clamped at p = 0.97 (log-odds 3.48); each miss adds log(0.35/0.65) = -0.62; the threshold is 1.39.
  const DepthFrame gone = ConstantDepthFrame(std::numeric_limits<float>::infinity(), cam_);
  for (int i = 0; i < 3; ++i) map_.IntegrateDepth(gone);
  EXPECT_TRUE(map_.IsOccupied(v));
  const MapUpdateStats s = map_.IntegrateDepth(gone);
  EXPECT_FALSE(map_.IsOccupied(v));
  EXPECT_GT(s.newly_free, 0);
  EXPECT_EQ(map_.CountOccupied(), 0);
}

TEST_F(DepthMapTest, InvalidPixelsAreSkipped) {
  DepthFrame f = ConstantDepthFrame(std::numeric_limits<float>::quiet_NaN(), cam_);
  EXPECT_EQ(map_.IntegrateDepth(f).rays, 0);
  f = ConstantDepthFrame(-std::numeric_limits<float>::infinity(), cam_);
  EXPECT_EQ(map_.IntegrateDepth(f).rays, 0);
  f = ConstantDepthFrame(0.05f, cam_);  // closer than min_ray_length_m
  EXPECT_EQ(map_.IntegrateDepth(f).rays, 0);
  EXPECT_EQ(map_.LogOdds(Eigen::Vector3i(10, 30, 20)), 0.0f);
}

TEST_F(DepthMapTest, MalformedFramesAreRejectedWithTheReason) {
  DepthFrame f = ConstantDepthFrame(2.0f, cam_);
  f.image.depth_m.pop_back();
  try {
    map_.IntegrateDepth(f);
    FAIL() << "expected std::invalid_argument";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("depth has 3071 values for a 64x48 image"), std::string::npos)
        << e.what();
  }
  f = ConstantDepthFrame(2.0f, cam_);
  f.intrinsics.fx = std::numeric_limits<double>::quiet_NaN();
  EXPECT_NE(ValidateDepthFrame(f).find("focal lengths"), std::string::npos);
  f = ConstantDepthFrame(2.0f, cam_);
  f.p_world_camera.x() = std::numeric_limits<double>::infinity();
  EXPECT_EQ(ValidateDepthFrame(f), "camera position is not finite");
}

TEST_F(DepthMapTest, CameraOutsideTheMapOnlyUpdatesTheRaysThatEnterIt) {
  // 2 m behind the map's x = 0 face, looking into the map: the wall at 3.05 m is inside at x = 1.05.
  const DepthFrame f = ConstantDepthFrame(3.05f, Eigen::Vector3d(-2.0, 3.05, 2.05));
  for (int i = 0; i < 3; ++i) map_.IntegrateDepth(f);
  EXPECT_TRUE(map_.IsOccupied(Eigen::Vector3d(1.05, 3.05, 2.05)));
  EXPECT_LT(map_.LogOdds(Eigen::Vector3i(5, 30, 20)), 0.0f);
}

TEST(VoxelMapTest, GroundAndCeilingAreObstaclesWithAnInflationBand) {
  MapConfig c = test::SmallMapConfig(Eigen::Vector3d(2.0, 2.0, 4.0), 0.1, 0.2, 0.0, 3.0);
  c.origin_m = Eigen::Vector3d(0.0, 0.0, -0.5);
  VoxelMap map(c);
  EXPECT_EQ(map.ground_layer(), 4);    // centre -0.05
  EXPECT_EQ(map.ceiling_layer(), 35);  // centre 3.05
  EXPECT_TRUE(map.IsOccupied(Eigen::Vector3d(1.0, 1.0, -0.05)));
  EXPECT_TRUE(map.IsOccupied(Eigen::Vector3d(1.0, 1.0, -3.0)));  // below the map too
  EXPECT_FALSE(map.IsOccupied(Eigen::Vector3d(1.0, 1.0, 0.05)));
  EXPECT_TRUE(map.IsOccupied(Eigen::Vector3d(1.0, 1.0, 3.05)));
  // Inflated: within 0.2 m of a ground voxel centre, i.e. centres up to z = 0.15.
  EXPECT_TRUE(map.IsInflated(Eigen::Vector3d(1.0, 1.0, 0.15)));
  EXPECT_FALSE(map.IsInflated(Eigen::Vector3d(1.0, 1.0, 0.25)));
  EXPECT_FALSE(map.IsInflated(Eigen::Vector3d(1.0, 1.0, 2.75)));
  EXPECT_TRUE(map.IsInflated(Eigen::Vector3d(1.0, 1.0, 2.85)));
  // Outside the map is never plannable.
  EXPECT_TRUE(map.IsInflated(Eigen::Vector3d(-0.5, 1.0, 1.0)));
}

TEST(VoxelMapTest, InflationIsABallAroundEachObstacleAndIsUndoneWhenItIsFreed) {
  VoxelMap map(test::SmallMapConfig(Eigen::Vector3d(3.0, 3.0, 3.0), 0.1, 0.25));
  const Eigen::Vector3i c(15, 15, 15);
  ASSERT_EQ(map.SetOccupied({map.ToPosition(c)}), 1);
  for (int dz = -4; dz <= 4; ++dz) {
    for (int dy = -4; dy <= 4; ++dy) {
      for (int dx = -4; dx <= 4; ++dx) {
        const bool inside = (dx * dx + dy * dy + dz * dz) * 0.01 <= 0.25 * 0.25 + 1e-9;
        EXPECT_EQ(map.IsInflated(Eigen::Vector3i(c + Eigen::Vector3i(dx, dy, dz))), inside)
            << dx << " " << dy << " " << dz;
      }
    }
  }
  // Free it with rays that pass through it (clamped at p_max: 4 misses) and nothing stays inflated.
  DepthFrame f =
      test::ConstantDepthFrame(std::numeric_limits<float>::infinity(), Eigen::Vector3d(0.55, 1.55, 1.55));
  for (int i = 0; i < 4; ++i) map.IntegrateDepth(f);
  EXPECT_FALSE(map.IsOccupied(c));
  for (int dz = -4; dz <= 4; ++dz) {
    for (int dy = -4; dy <= 4; ++dy) {
      for (int dx = -4; dx <= 4; ++dx)
        EXPECT_FALSE(map.IsInflated(Eigen::Vector3i(c + Eigen::Vector3i(dx, dy, dz))));
    }
  }
}

TEST(VoxelMapTest, InflationEqualsTheBallsOfRandomObstaclesInsideAndAtTheMapBorder) {
  // Obstacles whose ball lies in the map take the unchecked path (runs of linear offsets), those near a face
  // the checked one: both must mark exactly the voxels within the radius of an obstacle voxel.
  MapConfig c = test::SmallMapConfig(Eigen::Vector3d(1.6, 1.3, 1.2), 0.1, 0.3);
  VoxelMap map(c);
  const Eigen::Vector3i n = map.size_voxels();
  std::mt19937 rng(7);
  std::bernoulli_distribution occupied(0.01);
  std::vector<Eigen::Vector3i> obstacles;
  std::vector<Eigen::Vector3d> pts;
  for (int z = 0; z < n.z(); ++z) {
    for (int y = 0; y < n.y(); ++y) {
      for (int x = 0; x < n.x(); ++x) {
        if (!occupied(rng)) continue;
        obstacles.emplace_back(x, y, z);
        pts.push_back(map.ToPosition(obstacles.back()));
      }
    }
  }
  ASSERT_GT(obstacles.size(), 10u);
  ASSERT_EQ(map.SetOccupied(pts), static_cast<int>(pts.size()));
  const int band = map.inflation_voxels();
  for (int z = 0; z < n.z(); ++z) {
    // The ground and ceiling bands are inflated whatever the obstacles.
    if (z <= map.ground_layer() + band || z >= map.ceiling_layer() - band) continue;
    for (int y = 0; y < n.y(); ++y) {
      for (int x = 0; x < n.x(); ++x) {
        const Eigen::Vector3i v(x, y, z);
        bool near = false;
        for (const Eigen::Vector3i& o : obstacles) near |= (o - v).squaredNorm() * 0.01 <= 0.09 + 1e-9;
        ASSERT_EQ(map.IsInflated(v), near) << v.transpose();
      }
    }
  }
}
TEST(VoxelMapTest, ResetForgetsEverything) {
  VoxelMap map(test::SmallMapConfig(Eigen::Vector3d(3.0, 3.0, 3.0)));
  test::AddBox(&map, Eigen::Vector3d(1.0, 1.0, 1.0), Eigen::Vector3d(1.5, 1.5, 1.5));
  EXPECT_EQ(map.CountOccupied(), 125);
  map.Reset();
  EXPECT_EQ(map.CountOccupied(), 0);
  EXPECT_FALSE(map.IsInflated(Eigen::Vector3d(1.2, 1.2, 1.2)));
}

TEST(VoxelMapTest, LocalWindowIsClippedToTheMap) {
  MapConfig c = test::SmallMapConfig(Eigen::Vector3d(10.0, 10.0, 4.0));
  c.local_update_range_m = Eigen::Vector3d(2.0, 3.0, 10.0);
  VoxelMap map(c);
  Eigen::Vector3i lo, hi;
  map.LocalWindow(Eigen::Vector3d(1.05, 5.05, 2.05), &lo, &hi);
  EXPECT_EQ(lo, Eigen::Vector3i(0, 20, 0));
  EXPECT_EQ(hi, Eigen::Vector3i(30, 80, 39));
}

// The ray casting as it was before issue 32 made it faster (per-frame marks cleared by a full fill, the step
// axis chosen on arrays indexed by the axis), written plainly here as the reference: the optimised
// IntegrateDepth must give bit-identical log-odds, occupancy, inflation and statistics (the collection's
// records must not change). Same arithmetic in the same order; marks keyed by the voxel instead of a box.
struct ReferenceMap {
  explicit ReferenceMap(const VoxelMap& geometry)
      : g(geometry), log_odds(static_cast<size_t>(geometry.size_voxels().prod()), 0.0f) {}

  static float LogOddsOf(double p) { return static_cast<float>(std::log(p / (1.0 - p))); }

  MapUpdateStats Integrate(const DepthFrame& frame) {
    const MapConfig& cfg = g.config();
    const auto& dc = cfg.depth;
    const double res = g.resolution(), inv_res = 1.0 / res;
    const Eigen::Vector3d origin = g.origin();
    MapUpdateStats stats;
    const auto& k = frame.intrinsics;
    const Eigen::Matrix3d R = frame.q_world_camera.normalized().toRotationMatrix();
    const Eigen::Vector3d cam = frame.p_world_camera;
    const Eigen::Vector3d cam_vox = (cam - origin) * inv_res;
    const Eigen::Vector3d lo = origin.array() + 1e-6 * res;
    const Eigen::Vector3d hi = g.max_corner().array() - 1e-6 * res;
    const int reach = static_cast<int>(std::ceil(dc.max_ray_length_m * inv_res)) + 2;
    const Eigen::Vector3i cam_idx = cam_vox.array().floor().cast<int>();
    std::map<std::tuple<int, int, int>, uint8_t> marks;
    auto mark = [&](const Eigen::Vector3i& v, uint8_t bits) { marks[{v.x(), v.y(), v.z()}] |= bits; };
    for (int v = 0; v < k.height; v += dc.skip_pixel) {
      for (int u = 0; u < k.width; u += dc.skip_pixel) {
        const float d = frame.image.depth_m[static_cast<size_t>(v) * k.width + u];
        if (std::isnan(d) || d == -std::numeric_limits<float>::infinity()) continue;
        const Eigen::Vector3d dir_c((u - k.cx) / k.fx, (v - k.cy) / k.fy, 1.0);
        const double range_per_depth = dir_c.norm();
        bool hit = true;
        double depth = d;
        if (std::isinf(d) || d * range_per_depth > dc.max_ray_length_m) {
          hit = false;
          depth = dc.max_ray_length_m / range_per_depth;
        } else if (d * range_per_depth < dc.min_ray_length_m) {
          continue;
        }
        Eigen::Vector3d end = cam + R * (dir_c * depth);
        if (!g.InMap(end)) {
          const Eigen::Vector3d seg = end - cam;
          double t0 = 0.0, t1 = 1.0;
          bool inside = true;
          for (int a = 0; a < 3 && inside; ++a) {
            if (std::abs(seg[a]) < 1e-12) {
              inside = cam[a] >= lo[a] && cam[a] <= hi[a];
              continue;
            }
            double ta = (lo[a] - cam[a]) / seg[a];
            double tb = (hi[a] - cam[a]) / seg[a];
            if (ta > tb) std::swap(ta, tb);
            t0 = std::max(t0, ta);
            t1 = std::min(t1, tb);
            inside = t0 <= t1;
          }
          if (!inside) continue;
          end = cam + seg * t1;
          hit = false;
          if (!g.InMap(end)) continue;
        }
        ++stats.rays;
        const Eigen::Vector3d s = (end - origin) * inv_res;
        const Eigen::Vector3d dir = cam_vox - s;
        Eigen::Vector3i idx = s.array().floor().cast<int>();
        if (((idx - cam_idx).array().abs() >= reach).any()) continue;
        int move[3];
        double t_max[3], t_delta[3];
        int steps = 0;
        for (int a = 0; a < 3; ++a) {
          steps += std::abs(cam_idx[a] - idx[a]);
          if (dir[a] > 0.0) {
            move[a] = 1;
            t_max[a] = (idx[a] + 1 - s[a]) / dir[a];
            t_delta[a] = 1.0 / dir[a];
          } else if (dir[a] < 0.0) {
            move[a] = -1;
            t_max[a] = (idx[a] - s[a]) / dir[a];
            t_delta[a] = -1.0 / dir[a];
          } else {
            move[a] = 0;
            t_max[a] = std::numeric_limits<double>::infinity();
            t_delta[a] = std::numeric_limits<double>::infinity();
          }
        }
        mark(idx, hit ? 1 : 2);
        for (int i = 0; i < steps; ++i) {
          const int a = t_max[0] < t_max[1] ? (t_max[0] < t_max[2] ? 0 : 2) : (t_max[1] < t_max[2] ? 1 : 2);
          idx[a] += move[a];
          t_max[a] += t_delta[a];
          mark(idx, 2);
        }
      }
    }
    const float l_hit = LogOddsOf(dc.prob_hit), l_miss = LogOddsOf(dc.prob_miss);
    const float l_min = LogOddsOf(dc.prob_min), l_max = LogOddsOf(dc.prob_max);
    const float l_occ = LogOddsOf(dc.prob_occupied);
    for (const auto& [key, bits] : marks) {
      const Eigen::Vector3i v(std::get<0>(key), std::get<1>(key), std::get<2>(key));
      if (!g.InMap(v)) continue;
      float& l = log_odds[g.Linear(v)];
      const float old = l;
      l = std::clamp(l + ((bits & 1) ? l_hit : l_miss), l_min, l_max);
      if (l != old) ++stats.voxels_updated;
      if ((l > l_occ) != (old > l_occ)) ++((l > l_occ) ? stats.newly_occupied : stats.newly_free);
    }
    return stats;
  }

  const VoxelMap& g;
  std::vector<float> log_odds;
};

// Random frames (random poses inside and outside the map, depths with NaN, +-Inf, too short and too long
// returns, rays leaving the map) through the map and through the reference.
TEST(VoxelMapRayCastingTest, BitIdenticalToThePlainReferenceOnRandomFrames) {
  MapConfig c = SmallMapConfig(Eigen::Vector3d(6.0, 5.0, 3.0));
  c.origin_m = Eigen::Vector3d(-1.0, -2.0, -0.5);
  c.ground_z_m = 0.0;
  c.ceiling_z_m = 2.0;
  c.depth.max_ray_length_m = 3.0;
  c.depth.skip_pixel = 2;
  c.local_update_range_m = Eigen::Vector3d(2.0, 2.0, 1.0);
  VoxelMap map(c);
  ReferenceMap ref(map);
  std::mt19937 rng(32);
  std::uniform_real_distribution<double> ux(-1.5, 5.5), uy(-2.5, 3.5), uz(-0.3, 2.6), unit(-1.0, 1.0);
  std::uniform_real_distribution<float> base(0.05f, 3.8f), slope(-0.02f, 0.02f);
  std::uniform_int_distribution<int> kind(0, 19);
  int newly_occupied = 0, newly_free = 0;
  // Each pose sees a sloped surface three or four times (voxels become occupied), then one farther away
  // (some are freed again); a fifth of the pixels are NaN, +Inf, -Inf or random.
  for (int pose = 0; pose < 12; ++pose) {
    DepthFrame f = test::ConstantDepthFrame(1.0f, Eigen::Vector3d(ux(rng), uy(rng), uz(rng)), 48, 36);
    f.q_world_camera =
        Eigen::Quaterniond(unit(rng), unit(rng), unit(rng), unit(rng));  // normalised by the map
    const float d0 = base(rng), su = slope(rng), sv = slope(rng);
    for (int rep = 0; rep < 5; ++rep) {
      for (int v = 0; v < 36; ++v) {
        for (int u = 0; u < 48; ++u) {
          float& d = f.image.depth_m[static_cast<size_t>(v) * 48 + u];
          d = d0 + su * u + sv * v + (rep == 4 ? 0.8f : 0.0f);
          switch (kind(rng)) {
            case 0:
              d = std::numeric_limits<float>::quiet_NaN();
              break;
            case 1:
              d = std::numeric_limits<float>::infinity();
              break;
            case 2:
              d = -std::numeric_limits<float>::infinity();
              break;
            case 3:
              d = base(rng);
              break;
            default:
              break;
          }
        }
      }
      const MapUpdateStats got = map.IntegrateDepth(f);
      const MapUpdateStats want = ref.Integrate(f);
      ASSERT_EQ(got.rays, want.rays) << "pose " << pose << " frame " << rep;
      ASSERT_EQ(got.voxels_updated, want.voxels_updated) << "pose " << pose << " frame " << rep;
      ASSERT_EQ(got.newly_occupied, want.newly_occupied) << "pose " << pose << " frame " << rep;
      ASSERT_EQ(got.newly_free, want.newly_free) << "pose " << pose << " frame " << rep;
      newly_occupied += got.newly_occupied;
      newly_free += got.newly_free;
    }
  }
  // Rays through voxel corners, where the step axis is a tie (the tie-breaking must be the same): from a
  // voxel corner, pixels at 45 degrees (fx = fy = 10, u - cx and v - cy multiples of 10).
  for (int rep = 0; rep < 3; ++rep) {
    DepthFrame f = test::ConstantDepthFrame(rep == 0 ? 2.0f : 1.5f, Eigen::Vector3d(0.0, 0.0, 1.0), 48, 36);
    f.intrinsics = quad_core::CameraIntrinsics{48, 36, 10.0, 10.0, 20.0, 20.0};
    f.q_world_camera = test::CameraLookingAlongX();
    const MapUpdateStats got = map.IntegrateDepth(f);
    const MapUpdateStats want = ref.Integrate(f);
    ASSERT_EQ(got.rays, want.rays) << "corner frame " << rep;
    ASSERT_EQ(got.voxels_updated, want.voxels_updated) << "corner frame " << rep;
    ASSERT_EQ(got.newly_occupied, want.newly_occupied) << "corner frame " << rep;
    ASSERT_EQ(got.newly_free, want.newly_free) << "corner frame " << rep;
  }
  EXPECT_GT(newly_occupied, 100);  // the frames did build and change a map
  EXPECT_GT(newly_free, 10);
  const Eigen::Vector3i n = map.size_voxels();
  const float l_occ = ReferenceMap::LogOddsOf(c.depth.prob_occupied);
  int64_t occupied = 0, observed = 0;
  for (int z = 0; z < n.z(); ++z) {
    for (int y = 0; y < n.y(); ++y) {
      for (int x = 0; x < n.x(); ++x) {
        const Eigen::Vector3i v(x, y, z);
        const float want = ref.log_odds[map.Linear(v)];
        ASSERT_EQ(map.LogOdds(v), want) << v.transpose();  // bit-identical floats
        occupied += want > l_occ ? 1 : 0;
        observed += want != 0.0f ? 1 : 0;
      }
    }
  }
  EXPECT_EQ(map.CountOccupied(), occupied);
  EXPECT_GT(occupied, 100);
  EXPECT_GT(observed, 5000);
  // The inflation counts follow the occupancy (a brute-force check of the incremental counts).
  const int r = map.inflation_voxels();
  const double r_vox = c.inflation_m * (1.0 / c.resolution_m);  // as the map computes its sphere
  for (int z = 0; z < n.z(); ++z) {
    for (int y = 0; y < n.y(); ++y) {
      for (int x = 0; x < n.x(); ++x) {
        const Eigen::Vector3i v(x, y, z);
        bool near = z <= map.ground_layer() + r || z >= map.ceiling_layer() - r;
        for (int dz = -r; dz <= r && !near; ++dz) {
          for (int dy = -r; dy <= r && !near; ++dy) {
            for (int dx = -r; dx <= r && !near; ++dx) {
              const Eigen::Vector3i w = v + Eigen::Vector3i(dx, dy, dz);
              if (dx * dx + dy * dy + dz * dz > r_vox * r_vox + 1e-9 || !map.InMap(w)) continue;
              near = ref.log_odds[map.Linear(w)] > l_occ;
            }
          }
        }
        ASSERT_EQ(map.IsInflated(v), near) << v.transpose();
      }
    }
  }
}

}  // namespace
}  // namespace fast_planner
