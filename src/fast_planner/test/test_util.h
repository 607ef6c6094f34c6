// Helpers shared by the fast_planner gtests: small hand-made maps and a default configuration.
#pragma once

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include "fast_planner/planner_config.h"
#include "fast_planner/voxel_map.h"

namespace fast_planner::test {

// A map box of the given size with its lower corner at (0, 0, 0), ground just below the box (no ground voxel
// inside) and the ceiling above it, unless ground/ceiling are given.
inline MapConfig SmallMapConfig(const Eigen::Vector3d& size_m, double resolution_m = 0.1,
                                double inflation_m = 0.2, double ground_z_m = 0.0,
                                double ceiling_z_m = 1.0e3) {
  MapConfig c;
  c.resolution_m = resolution_m;
  c.origin_m = Eigen::Vector3d::Zero();
  c.size_m = size_m;
  c.ground_z_m = ground_z_m;
  c.ceiling_z_m = ceiling_z_m;
  c.inflation_m = inflation_m;
  c.local_update_range_m = size_m;
  c.depth.skip_pixel = 1;
  return c;
}

// Marks an axis-aligned box [lo, hi] (metres) occupied, one point per voxel centre.
inline void AddBox(VoxelMap* map, const Eigen::Vector3d& lo, const Eigen::Vector3d& hi) {
  std::vector<Eigen::Vector3d> pts;
  const double r = map->resolution();
  for (double x = lo.x() + 0.5 * r; x < hi.x(); x += r) {
    for (double y = lo.y() + 0.5 * r; y < hi.y(); y += r) {
      for (double z = lo.z() + 0.5 * r; z < hi.z(); z += r) pts.emplace_back(x, y, z);
    }
  }
  map->SetOccupied(pts);
}

// The camera optical frame (z forward, x right, y down) looking along world +x from a level body.
inline Eigen::Quaterniond CameraLookingAlongX() {
  Eigen::Matrix3d r;
  r.col(0) = Eigen::Vector3d(0, -1, 0);  // optical x (right) = world -y
  r.col(1) = Eigen::Vector3d(0, 0, -1);  // optical y (down) = world -z
  r.col(2) = Eigen::Vector3d(1, 0, 0);   // optical z (forward) = world +x
  return Eigen::Quaterniond(r);
}

inline DepthFrame ConstantDepthFrame(float depth_m, const Eigen::Vector3d& p_world_camera, int width = 64,
                                     int height = 48) {
  DepthFrame f;
  f.intrinsics = quad_core::CameraIntrinsics{
      width, height, 0.6 * width, 0.6 * width, 0.5 * (width - 1), 0.5 * (height - 1)};
  f.image =
      quad_core::DepthImage{width, height, std::vector<float>(static_cast<size_t>(width) * height, depth_m)};
  f.p_world_camera = p_world_camera;
  f.q_world_camera = CameraLookingAlongX();
  return f;
}

}  // namespace fast_planner::test

namespace fast_planner::test {

struct Aabb {
  Eigen::Vector3d lo, hi;
};

// Depth (along the optical axis) of the nearest box along each pixel's ray, +Inf when nothing is hit within
// max_range_m: an exact renderer for axis-aligned test worlds.
inline DepthFrame RenderDepth(const std::vector<Aabb>& boxes, const Eigen::Vector3d& p_world_camera,
                              const Eigen::Quaterniond& q_world_camera, int width = 160, int height = 120,
                              double max_range_m = 10.0) {
  DepthFrame f;
  f.intrinsics = quad_core::CameraIntrinsics{
      width, height, 0.6 * width, 0.6 * width, 0.5 * (width - 1), 0.5 * (height - 1)};
  f.image = quad_core::DepthImage{
      width, height,
      std::vector<float>(static_cast<size_t>(width) * height, std::numeric_limits<float>::infinity())};
  f.p_world_camera = p_world_camera;
  f.q_world_camera = q_world_camera;
  const Eigen::Matrix3d R = q_world_camera.toRotationMatrix();
  for (int v = 0; v < height; ++v) {
    for (int u = 0; u < width; ++u) {
      const Eigen::Vector3d d_c((u - f.intrinsics.cx) / f.intrinsics.fx,
                                (v - f.intrinsics.cy) / f.intrinsics.fy, 1.0);
      const Eigen::Vector3d d = R * d_c;  // t along d is the depth
      double best = std::numeric_limits<double>::infinity();
      for (const Aabb& b : boxes) {
        double t0 = 0.0, t1 = best;
        bool hit = true;
        for (int a = 0; a < 3 && hit; ++a) {
          if (std::abs(d[a]) < 1e-12) {
            hit = p_world_camera[a] >= b.lo[a] && p_world_camera[a] <= b.hi[a];
            continue;
          }
          double ta = (b.lo[a] - p_world_camera[a]) / d[a], tb = (b.hi[a] - p_world_camera[a]) / d[a];
          if (ta > tb) std::swap(ta, tb);
          t0 = std::max(t0, ta);
          t1 = std::min(t1, tb);
          hit = t0 <= t1;
        }
        if (hit) best = t0;
      }
      if (best * d_c.norm() <= max_range_m)
        f.image.depth_m[static_cast<size_t>(v) * width + u] = static_cast<float>(best);
    }
  }
  return f;
}

// The camera of a level body with yaw `yaw_rad` about world z (looking along the body's x axis).
inline Eigen::Quaterniond CameraWithYaw(double yaw_rad) {
  return Eigen::Quaterniond(Eigen::AngleAxisd(yaw_rad, Eigen::Vector3d::UnitZ())) * CameraLookingAlongX();
}

}  // namespace fast_planner::test
