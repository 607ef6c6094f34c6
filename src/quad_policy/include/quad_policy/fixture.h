// Recorded decision inputs on disk: a directory of .npy arrays, written by Python
// (quad_il/inference/fixture.py) or C++ (the benchmark's frame generator) and read by both, so the parity
// test and the benchmark feed exactly the same frames to the C++ and the Python forward passes. Layout (N
// frames of H x W; docs/inference.md):
//   depth_m.npy (N, H, W) <f4 | stamp_s.npy (N,) <f8 | p_world_body.npy, v_world.npy, goal_world.npy (N, 3)
//   <f8 | q_world_body.npy (N, 4) <f8 xyzw | camera_k.npy (4,) <f8 fx, fy, cx, cy | T_body_camera.npy (4, 4)
//   <f8
#pragma once

#include <Eigen/Geometry>

#include <string>
#include <vector>

#include "quad_policy/preprocessing.h"
#include "quad_policy/safety.h"

namespace quad_policy {

struct RecordedFrame {
  double stamp_s = 0.0;
  DepthImage depth;
  VehicleState state;
  Eigen::Vector3d goal_world = Eigen::Vector3d::Zero();
};

struct DecisionFixture {
  std::vector<RecordedFrame> frames;
  double fx = 0.0, fy = 0.0, cx = 0.0, cy = 0.0;
  Eigen::Isometry3d T_body_camera = Eigen::Isometry3d::Identity();

  // The camera of frame i: intrinsics and the pose T_world_body(frame) * T_body_camera.
  CameraModel Camera(std::size_t i) const;
};

// Throws NpyError or std::invalid_argument (inconsistent shapes, naming the file).
DecisionFixture ReadDecisionFixture(const std::string& dir);
// Creates dir if needed; throws on I/O errors or frames of different sizes.
void WriteDecisionFixture(const std::string& dir, const DecisionFixture& fixture);

}  // namespace quad_policy
