#include "quad_core/camera.h"

#include <cmath>
#include <sstream>

namespace quad_core {

std::string CameraIntrinsics::Validate() const {
  std::ostringstream why;
  if (width <= 0 || height <= 0) {
    why << "image size " << width << " x " << height << " is not positive";
  } else if (!(std::isfinite(fx) && std::isfinite(fy) && fx > 0.0 && fy > 0.0)) {
    why << "focal lengths fx=" << fx << " fy=" << fy << " are not finite and positive";
  } else if (!(std::isfinite(cx) && std::isfinite(cy))) {
    why << "principal point cx=" << cx << " cy=" << cy << " is not finite";
  }
  return why.str();
}

}  // namespace quad_core
