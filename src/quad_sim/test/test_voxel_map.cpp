// The global voxel map: exact occupancy on the OctoMap-aligned grid, and the .bt export read back with
// OctoMap.
#include "quad_sim/math_utils.h"
#include "quad_sim/voxel_map.h"

#include "test_util.h"

#include <gtest/gtest.h>
#include <octomap/OcTree.h>

#include <cmath>

using quad_sim::OrientedBox;
using quad_sim::VoxelMap;
using quad_sim::World;

namespace {

World OneBoxWorld(const Eigen::Vector3d& c, const Eigen::Vector3d& size, double roll, double pitch,
                  double yaw) {
  World w;
  w.bounds_min_m = Eigen::Vector3d(-3, -3, 0);
  w.bounds_max_m = Eigen::Vector3d(3, 3, 3);
  OrientedBox b;
  b.center_world_m = c;
  b.size_m = size;
  b.q_world_box = quad_sim::QuatFromRpy(roll, pitch, yaw);
  w.boxes.push_back(b);
  return w;
}

}  // namespace

TEST(VoxelMap, GridAlignedBoxOccupiesExactlyItsVoxels) {
  // A 1.0 x 0.6 x 0.4 box spanning [0.2, 1.2] x [-0.3, 0.3] x [1.0, 1.4] (shrunk by a hair so touching faces
  // do not count): 10 x 6 x 4 voxels of 0.1 m.
  const World w = OneBoxWorld(Eigen::Vector3d(0.7, 0.0, 1.2),
                              Eigen::Vector3d(1.0 - 1e-9, 0.6 - 1e-9, 0.4 - 1e-9), 0, 0, 0);
  const VoxelMap m = VoxelMap::FromWorld(w, {0.1});
  EXPECT_EQ(m.NumOccupied(), 240u);
  EXPECT_TRUE(m.IsOccupiedAt(Eigen::Vector3d(0.25, -0.25, 1.05)));
  EXPECT_FALSE(m.IsOccupiedAt(Eigen::Vector3d(0.15, 0.0, 1.2)));
  EXPECT_EQ(m.dims(), Eigen::Vector3i(60, 60, 30));
  EXPECT_TRUE(m.origin_center_m().isApprox(Eigen::Vector3d(-2.95, -2.95, 0.05)));
}

TEST(VoxelMap, RotatedBoxOccupancyEqualsTheExactVoxelBoxTest) {
  const World w =
      OneBoxWorld(Eigen::Vector3d(0.31, -0.17, 1.43), Eigen::Vector3d(1.3, 0.45, 0.8), 0.3, -0.5, 0.9);
  const VoxelMap m = VoxelMap::FromWorld(w, {0.1});
  size_t expected = 0;
  for (int iz = 0; iz < m.dims().z(); ++iz) {
    for (int iy = 0; iy < m.dims().y(); ++iy) {
      for (int ix = 0; ix < m.dims().x(); ++ix) {
        OrientedBox voxel;
        voxel.center_world_m = m.origin_center_m() + 0.1 * Eigen::Vector3d(ix, iy, iz);
        voxel.size_m = Eigen::Vector3d::Constant(0.1);
        const bool truth = quad_sim::BoxesOverlap(voxel, w.boxes[0]);
        expected += truth;
        ASSERT_EQ(m.IsOccupied(ix, iy, iz), truth) << ix << " " << iy << " " << iz;
      }
    }
  }
  EXPECT_EQ(m.NumOccupied(), expected);
  // Conservative: at least the box volume, not much more than volume + surface shell.
  EXPECT_GT(expected * 1e-3, 1.3 * 0.45 * 0.8);
}

TEST(VoxelMap, OctomapExportReadsBackWithTheSameVoxels) {
  const World w = quad_sim::GenerateWorld(quad_sim_test::DefaultSimConfig().world_gen, 4);
  World small = w;
  small.boxes.resize(20);
  const VoxelMap m = VoxelMap::FromWorld(small, {0.1});
  quad_sim_test::TempFile f(".bt");
  m.WriteOctomap(f.path());
  octomap::OcTree tree(f.path());
  EXPECT_DOUBLE_EQ(tree.getResolution(), 0.1);
  size_t occupied_leaves_volume = 0;
  for (auto it = tree.begin_leafs(); it != tree.end_leafs(); ++it) {
    if (!tree.isNodeOccupied(*it)) continue;
    // Pruned leaves stand for 8^(depth below) voxels.
    const int below = tree.getTreeDepth() - it.getDepth();
    occupied_leaves_volume += static_cast<size_t>(1) << (3 * below);
    const octomap::point3d c = it.getCoordinate();
    if (below == 0) {
      EXPECT_TRUE(m.IsOccupiedAt(Eigen::Vector3d(c.x(), c.y(), c.z())));
    }
  }
  EXPECT_EQ(occupied_leaves_volume, m.NumOccupied());
  for (const Eigen::Vector3f& c : m.OccupiedCenters()) {
    const octomap::OcTreeNode* n = tree.search(c.x(), c.y(), c.z());
    ASSERT_NE(n, nullptr);
    ASSERT_TRUE(tree.isNodeOccupied(n));
  }
}
