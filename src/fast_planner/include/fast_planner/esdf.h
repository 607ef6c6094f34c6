// Euclidean signed distance field over a window of the voxel map (ROS-free).
//
// Exact Euclidean distance transform by Felzenszwalb & Huttenlocher ("Distance Transforms of Sampled
// Functions", 2012): the squared distance is separable, so three 1-D lower-envelope-of-parabolas passes (x,
// y, z) give the exact result in O(voxels). Definition (tested against brute force): for a free voxel, the
// distance between its centre and the nearest obstacle voxel centre, where obstacles are the observed
// occupied voxels of the window and the ground and ceiling layers (planes: their distance is analytic,
// straight down or up, so their layers are left out of the window and the transform); for an observed
// obstacle voxel, minus the distance to the nearest free voxel centre of the window. Magnitudes are clamped
// to the configured maximum (map.esdf_max_distance_m). The window sees no observed obstacle outside itself.
// Distances and gradients between voxel centres come from trilinear interpolation.
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <limits>
#include <vector>

#include "fast_planner/voxel_map.h"

namespace fast_planner {

// "No seed" in the squared-distance transform.
constexpr int32_t kEdtInfinity = std::numeric_limits<int32_t>::max();

// 1-D squared distance transform of a sampled function: out[q] = min_p (q - p)^2 + f[p], for f[p] either a
// non-negative integer (below 2^30) or kEdtInfinity. v (n ints), z_num and z_den (n + 1 each) are scratch.
// Exposed for tests.
void DistanceTransform1d(const int32_t* f, int n, int32_t* out, int* v, int64_t* z_num, int64_t* z_den);

class Esdf {
 public:
  // Distance reported where no obstacle (or no free voxel) exists in the window.
  static constexpr float kFarDistance = 1.0e3f;

  // Distances are exact up to max_distance_m and clamped to it beyond (a truncated transform: the planner's
  // costs vanish beyond its safe distance, and far regions then cost nothing to compute). Throws
  // std::invalid_argument if max_distance_m is not positive.
  explicit Esdf(double max_distance_m = kFarDistance);

  // Recomputes the field over the voxel box [min_idx, max_idx] of `map` (inclusive; must be inside the map),
  // less the ground and ceiling layers. Throws std::invalid_argument on an empty or out-of-map box, or one
  // that lies entirely in the ground or the ceiling.
  void Update(const VoxelMap& map, const Eigen::Vector3i& min_idx, const Eigen::Vector3i& max_idx);

  // Frees the scratch buffers of the transform (about 9 bytes per window voxel; the field itself, 4 bytes per
  // voxel, stays). For a field computed once and kept (the global map source); the next Update() allocates
  // them again.
  void ReleaseScratch();

  bool valid() const { return !dist_.empty(); }
  const Eigen::Vector3i& window_min() const { return min_; }
  const Eigen::Vector3i& window_max() const { return max_; }

  // Signed distance at a voxel of the map (voxel-centre value); kFarDistance outside the window.
  float VoxelDistance(const Eigen::Vector3i& map_idx) const;
  // Trilinear interpolation of the voxel-centre distances. Positions outside the window are clamped into the
  // box spanned by its voxel centres (so the gradient along a clamped axis is zero). Without a valid field:
  // kFarDistance and a zero gradient.
  double Distance(const Eigen::Vector3d& p) const;
  double DistanceAndGradient(const Eigen::Vector3d& p, Eigen::Vector3d* grad) const;

 private:
  int64_t Local(int x, int y, int z) const { return x + static_cast<int64_t>(n_.x()) * (y + n_.y() * z); }

  double max_distance_m_ = kFarDistance;
  double resolution_ = 0.0;
  Eigen::Vector3d origin_ = Eigen::Vector3d::Zero();  // map origin
  Eigen::Vector3i min_ = Eigen::Vector3i::Zero();
  Eigen::Vector3i max_ = Eigen::Vector3i::Zero();
  Eigen::Vector3i n_ = Eigen::Vector3i::Zero();
  std::vector<float> dist_;
  // Scratch reused between updates (no allocation per frame once sized).
  std::vector<uint8_t> occ_;
  std::vector<int32_t> sq_out_, sq_in_, block_, line_f_, line_d_;
  std::vector<int> line_v_;
  std::vector<int64_t> line_zn_, line_zd_;
};

}  // namespace fast_planner
