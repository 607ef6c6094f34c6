#include <gtest/gtest.h>

#include <cmath>
#include <limits>

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

}  // namespace
}  // namespace fast_planner
