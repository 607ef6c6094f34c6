#include "kr_tracker/types.h"

#include <cmath>

namespace kr_tracker {

bool PositionReference::AllFinite() const {
  return p_world.allFinite() && v_world.allFinite() && a_world.allFinite() && j_world.allFinite() &&
         std::isfinite(yaw_rad) && std::isfinite(yaw_rate_radps);
}

PositionReference PositionReference::Hold(const Eigen::Vector3d& p_world, double yaw_rad) {
  PositionReference r;
  r.p_world = p_world;
  r.yaw_rad = quad_core::WrapAngle(yaw_rad);
  return r;
}

bool So3Command::AllFinite() const {
  return force_world_N.allFinite() && q_world_des.coeffs().allFinite() && w_body_des_radps.allFinite() &&
         kR.allFinite() && kOm.allFinite();
}

}  // namespace kr_tracker
