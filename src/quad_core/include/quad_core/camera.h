// Pinhole intrinsics of the depth camera (sensor_msgs/CameraInfo's K without skew; REP 118 optical frame:
// z forward, x right, y down).
#pragma once

#include <string>

namespace quad_core {

struct CameraIntrinsics {
  int width = 0;
  int height = 0;
  double fx = 0.0;
  double fy = 0.0;
  double cx = 0.0;
  double cy = 0.0;

  // "" if usable (positive size and focal lengths, finite principal point), else what is wrong.
  std::string Validate() const;
};

}  // namespace quad_core
