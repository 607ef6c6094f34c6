// The global voxel map of a world: a voxel is occupied when its cube intersects any box (exact
// separating-axis test), on a grid aligned with OctoMap's keys (voxel centres at (k + 1/2) * resolution), so
// the exported .bt holds exactly these voxels. The ground plane is not included (planners treat z <= 0 as
// occupied themselves).
#pragma once

#include "quad_sim/world.h"

#include <Eigen/Core>

#include <string>
#include <vector>

namespace quad_sim {

struct VoxelMapConfig {
  double resolution_m = 0.1;
};

class VoxelMap {
 public:
  VoxelMap() = default;
  // Voxelises the world within its bounds (grown to whole voxels).
  static VoxelMap FromWorld(const World& world, const VoxelMapConfig& config);

  double resolution_m() const { return resolution_m_; }
  const Eigen::Vector3i& dims() const { return dims_; }
  // Centre of the voxel with the smallest indices.
  Eigen::Vector3d origin_center_m() const { return origin_center_m_; }
  bool IsOccupied(int ix, int iy, int iz) const;
  // Occupancy of the voxel containing p (false outside the map).
  bool IsOccupiedAt(const Eigen::Vector3d& p_world) const;
  size_t NumOccupied() const { return num_occupied_; }
  // Centres of all occupied voxels, in index order (x fastest).
  std::vector<Eigen::Vector3f> OccupiedCenters() const;
  // Writes an OctoMap binary tree (.bt) with every occupied voxel marked occupied; throws on I/O errors.
  void WriteOctomap(const std::string& path) const;

 private:
  size_t Index(int ix, int iy, int iz) const {
    return (static_cast<size_t>(iz) * dims_.y() + iy) * dims_.x() + ix;
  }
  double resolution_m_ = 0.1;
  Eigen::Vector3i dims_ = Eigen::Vector3i::Zero();
  Eigen::Vector3d origin_center_m_ = Eigen::Vector3d::Zero();
  std::vector<uint8_t> occupied_;
  size_t num_occupied_ = 0;
};

}  // namespace quad_sim
