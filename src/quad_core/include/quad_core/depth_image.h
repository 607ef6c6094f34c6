// Depth images in metres along the optical axis (sensor_msgs/Image 32FC1; REP 118: +Inf no return within
// range, -Inf too near, NaN invalid), row-major.
#pragma once

#include <cstddef>
#include <vector>

namespace quad_core {

// Not owning: `data` must outlive the view.
struct DepthImageView {
  int width = 0;
  int height = 0;
  std::size_t row_stride = 0;  // floats between the starts of two rows (>= width)
  const float* data = nullptr;
  float at(int row, int col) const { return data[static_cast<std::size_t>(row) * row_stride + col]; }
};

// Owning.
struct DepthImage {
  int width = 0;
  int height = 0;
  std::vector<float> depth_m;  // width * height values
  float at(int row, int col) const { return depth_m[static_cast<std::size_t>(row) * width + col]; }
  DepthImageView view() const {
    return DepthImageView{width, height, static_cast<std::size_t>(width), depth_m.data()};
  }
};

}  // namespace quad_core
