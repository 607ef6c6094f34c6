// Checks of the inputs a policy node takes from ROS messages (issue 30: bad input is refused with a reason,
// never decided on). Each returns "" when the input is usable, else the reason the frame is refused, which
// the node publishes on policy/decision (status bad_input). The Python node calls these through the bindings
// (quad_il.inference.core), so both nodes publish the same texts.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>

#include "quad_policy/preprocessing.h"

namespace quad_policy {

// The layout fields of a sensor_msgs/Image.
struct ImageLayout {
  std::string encoding;
  bool is_bigendian = false;
  uint32_t width = 0;
  uint32_t height = 0;
  uint32_t step = 0;
  std::size_t data_bytes = 0;
};

// A depth frame the nodes read: 32FC1 little-endian (metres, REP 118), not empty, rows of `step` bytes
// (a multiple of 4, at least 4 * width), exactly step * height bytes of data.
std::string DepthLayoutProblem(const ImageLayout& image);

// The frame's size must be the camera model's (camera_info): the safety layer projects with that model.
std::string DepthSizeProblem(uint32_t width, uint32_t height, uint32_t info_width, uint32_t info_height);

// Odometry the nodes decide from: finite position, velocity and orientation (stamp_s names it in the reason).
std::string StateProblem(const VehicleState& state, double stamp_s);

}  // namespace quad_policy
