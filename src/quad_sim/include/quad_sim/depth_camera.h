// Pinhole depth camera: exact analytic ray/box distances (no voxelisation), REP 118 conventions.
#pragma once

#include "quad_core/camera.h"
#include "quad_core/depth_image.h"
#include "quad_sim/world_index.h"

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cstdint>
#include <random>
#include <vector>

namespace quad_sim {

struct DepthCameraConfig {
  quad_core::CameraIntrinsics intrinsics{320, 240, 193.6, 193.6, 159.5, 119.5};
  double rate_hz = 30.0;
  double min_depth_m = 0.1;   // closer returns are -Inf (REP 118)
  double max_depth_m = 10.0;  // farther returns and no return are +Inf
  // Mount: the camera's optical frame (z forward, x right, y down) relative to base_link (FLU).
  Eigen::Vector3d p_body_camera_m = Eigen::Vector3d(0.1, 0.0, 0.0);
  Eigen::Quaterniond q_body_camera = Eigen::Quaterniond(0.5, -0.5, 0.5, -0.5);  // optical, looking along +x
  // Optional Gaussian noise, sigma = noise_std_at_1m_m * depth^2 (stereo-like growth); 0 disables it.
  double noise_std_at_1m_m = 0.0;
  int num_threads =
      1;  // tile rows are split among threads; pixels are independent, so output is deterministic

  // Intrinsics with the same field of view as Fast-Planner's simulated camera (640 x 480, fx = fy = 387.2),
  // scaled to width x height, principal point at the image centre.
  static quad_core::CameraIntrinsics FastPlannerFov(int width, int height);
  void Validate() const;
};

// The optical-frame rotation for a camera mounted with roll/pitch/yaw (body FLU) relative to looking forward.
Eigen::Quaterniond OpticalMountRotation(double roll_rad, double pitch_rad, double yaw_rad);

class DepthRenderer {
 public:
  explicit DepthRenderer(const DepthCameraConfig& config);

  // Renders from the camera pose q_world_camera (optical frame) at p_world_camera.
  // Depth along the optical axis (not along the ray).
  quad_core::DepthImage Render(const WorldIndex& index, const Eigen::Vector3d& p_world_camera,
                               const Eigen::Quaterniond& q_world_camera) const;
  // Adds the configured Gaussian noise in place (sequentially, so it is deterministic for a seeded rng).
  void AddNoise(quad_core::DepthImage* image, std::mt19937_64* rng) const;

  const DepthCameraConfig& config() const { return config_; }

 private:
  DepthCameraConfig config_;
};

}  // namespace quad_sim
