#include "quad_policy/input_checks.h"

#include <cstdio>

namespace quad_policy {

std::string DepthLayoutProblem(const ImageLayout& image) {
  if (image.encoding != "32FC1") return "depth frame encoding is '" + image.encoding + "', not 32FC1";
  if (image.is_bigendian) return "depth frame is big-endian (32FC1 little-endian needed)";
  if (image.width == 0 || image.height == 0) {
    return "depth frame is empty (" + std::to_string(image.width) + "x" + std::to_string(image.height) + ")";
  }
  const uint64_t min_step = 4ull * image.width;
  if (image.step < min_step || image.step % 4 != 0) {
    return "depth frame step " + std::to_string(image.step) +
           " is not a multiple of 4 of at least 4 * width = " + std::to_string(min_step);
  }
  const uint64_t expected = static_cast<uint64_t>(image.step) * image.height;
  if (image.data_bytes != expected) {
    return "depth frame has " + std::to_string(image.data_bytes) +
           " data bytes, step * height = " + std::to_string(expected);
  }
  return "";
}

std::string DepthSizeProblem(uint32_t width, uint32_t height, uint32_t info_width, uint32_t info_height) {
  if (width == info_width && height == info_height) return "";
  return "depth frame is " + std::to_string(width) + "x" + std::to_string(height) + ", camera_info is " +
         std::to_string(info_width) + "x" + std::to_string(info_height);
}

std::string StateProblem(const VehicleState& state, double stamp_s) {
  std::string fields;
  const auto add = [&](bool finite, const char* name) {
    if (!finite) fields += (fields.empty() ? "" : ", ") + std::string(name);
  };
  add(state.p_world_body.allFinite(), "position");
  add(state.v_world.allFinite(), "velocity");
  add(state.q_world_body.coeffs().allFinite(), "orientation");
  if (fields.empty()) return "";
  char at[48];
  std::snprintf(at, sizeof(at), "%.6f", stamp_s);
  return std::string("odometry at ") + at + " s is not finite (" + fields + ")";
}

}  // namespace quad_policy
