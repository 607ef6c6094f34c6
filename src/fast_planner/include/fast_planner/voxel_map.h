// Occupancy voxel map built from depth frames by ray casting with log-odds (ROS-free).
//
// The map is a fixed box (config map.origin_m / map.size_m) at map.resolution_m. Each depth frame updates the
// voxels its rays traverse: the voxel of a return is a hit, the voxels between the camera and the return are
// misses; every voxel is updated at most once per frame (a hit wins over a miss), and log-odds are clamped so
// a voxel can change its mind quickly (Zhou et al. 2019, Sec. VI; the usual OctoMap sensor model). Returns
// beyond max_ray_length (and REP 118 +Inf "no return" pixels) clear free space up to that range.
//
// Everything at or below the ground and at or above the ceiling is an obstacle, whether seen or not
// (Fast-Planner treated unseen space below the ground as free and planned through it). Occupied voxels are
// inflated by map.inflation_m with an incrementally maintained count per voxel, so inflation costs only what
// changed. Unknown space is free (optimistic local planning; replanning handles what is seen later).
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "fast_planner/planner_config.h"
#include "quad_core/camera.h"
#include "quad_core/depth_image.h"

namespace fast_planner {

// One depth frame as the planner integrates it: the image (quad_core::DepthImage: metres along the optical
// axis, row-major, REP 118 NaN/+Inf/-Inf), the intrinsics it was taken with (same size) and the pose of the
// camera optical frame (z forward, x right, y down) in the world frame at the frame's stamp.
struct DepthFrame {
  double stamp_s = 0.0;
  uint64_t seq = 0;  // the simulator's frame counter (quad_msgs/FrameAck frame_seq), 0 if unknown
  quad_core::CameraIntrinsics intrinsics;
  quad_core::DepthImage image;  // intrinsics.width x intrinsics.height
  Eigen::Vector3d p_world_camera = Eigen::Vector3d::Zero();
  Eigen::Quaterniond q_world_camera = Eigen::Quaterniond::Identity();
};

// "" when the frame can be integrated, else why not (size mismatch, bad intrinsics, non-finite pose...).
std::string ValidateDepthFrame(const DepthFrame& frame);

struct MapUpdateStats {
  int rays = 0;            // pixels cast
  int voxels_updated = 0;  // distinct voxels whose log-odds changed this frame
  int newly_occupied = 0;  // voxels that became occupied
  int newly_free = 0;      // voxels that stopped being occupied
};

class VoxelMap {
 public:
  // Throws quad_core::ConfigError if the map part of the config is invalid.
  explicit VoxelMap(const MapConfig& cfg);

  // Forgets every observation (a new episode).
  void Reset();

  // Ray-casts one depth frame. Throws std::invalid_argument with ValidateDepthFrame's reason on a bad frame.
  MapUpdateStats IntegrateDepth(const DepthFrame& frame);

  // Marks the voxels containing these world points occupied with the maximum log-odds (the `global` map
  // source: the simulator's voxel map). Points outside the map are ignored; returns how many were inside.
  int SetOccupied(const std::vector<Eigen::Vector3d>& p_world);

  // Geometry.
  double resolution() const { return resolution_; }
  const Eigen::Vector3d& origin() const { return origin_; }
  const Eigen::Vector3i& size_voxels() const { return size_; }
  Eigen::Vector3d max_corner() const { return origin_ + size_.cast<double>() * resolution_; }
  int inflation_voxels() const { return inflation_voxels_; }
  double inflation_m() const { return cfg_.inflation_m; }
  const MapConfig& config() const { return cfg_; }

  bool InMap(const Eigen::Vector3d& p) const;
  bool InMap(const Eigen::Vector3i& idx) const {
    return (idx.array() >= 0).all() && (idx.array() < size_.array()).all();
  }
  Eigen::Vector3i ToIndex(const Eigen::Vector3d& p) const {
    return ((p - origin_) * inv_resolution_).array().floor().cast<int>();
  }
  Eigen::Vector3d ToPosition(const Eigen::Vector3i& idx) const {
    return origin_ + (idx.cast<double>().array() + 0.5).matrix() * resolution_;
  }
  int64_t Linear(const Eigen::Vector3i& idx) const {
    return idx.x() + static_cast<int64_t>(size_.x()) * (idx.y() + static_cast<int64_t>(size_.y()) * idx.z());
  }

  // Obstacle voxel: observed occupied, or at/below the ground or at/above the ceiling. Outside the map: false
  // for the observed part (nothing is known there) but ground/ceiling still count.
  bool IsOccupied(const Eigen::Vector3i& idx) const;
  bool IsOccupied(const Eigen::Vector3d& p) const { return IsOccupied(ToIndex(p)); }
  // Within map.inflation_m of an obstacle voxel (voxel centres), or outside the map (never plan out of it).
  bool IsInflated(const Eigen::Vector3i& idx) const;
  bool IsInflated(const Eigen::Vector3d& p) const { return IsInflated(ToIndex(p)); }
  // Log-odds of an in-map voxel (0 = never observed).
  float LogOdds(const Eigen::Vector3i& idx) const { return log_odds_[Linear(idx)]; }
  // The highest z layer that is ground and the lowest that is ceiling (may lie outside [0, size.z)).
  int ground_layer() const { return ground_layer_; }
  int ceiling_layer() const { return ceiling_layer_; }

  // The voxel box [min_idx, max_idx] (inclusive, clipped to the map) of the local update window around p.
  void LocalWindow(const Eigen::Vector3d& p_center, Eigen::Vector3i* min_idx, Eigen::Vector3i* max_idx) const;

  // The observed occupancy (ground and ceiling not included) of every voxel of the box [min_idx, max_idx]
  // (inclusive, inside the map), x fastest, as 0/1.
  void ExtractObservedOccupancy(const Eigen::Vector3i& min_idx, const Eigen::Vector3i& max_idx,
                                std::vector<uint8_t>* occupied) const;

  // Number of observed-occupied voxels (ground/ceiling excluded), for tests and diagnostics.
  int64_t CountOccupied() const;

 private:
  void SetOccupiedFlag(int64_t lin, const Eigen::Vector3i& idx, bool occupied);

  MapConfig cfg_;
  double resolution_;
  double inv_resolution_;
  Eigen::Vector3d origin_;
  Eigen::Vector3i size_;
  int ground_layer_;
  int ceiling_layer_;
  int inflation_voxels_;  // floor(inflation / resolution): the ground/ceiling band width in voxels
  std::vector<Eigen::Vector3i> inflation_offsets_;
  // The same offsets as runs along x: (linear offset of the run's first voxel, run length), for voxels whose
  // whole inflation ball lies in the map (no bounds checks; contiguous increments).
  std::vector<std::pair<int64_t, int>> inflation_runs_;
  float l_hit_, l_miss_, l_min_, l_max_, l_occupied_;

  std::vector<float> log_odds_;
  std::vector<uint8_t> occupied_;        // 1 if log-odds > l_occupied
  std::vector<uint16_t> inflate_count_;  // number of occupied voxels within the inflation radius
  // Per-frame marks over the box within ray range of the camera: bit0 hit, bit1 miss (a hit wins).
  std::vector<uint8_t> local_mark_;
  std::vector<int64_t> touched_;  // box voxels marked in the current frame
};

}  // namespace fast_planner
