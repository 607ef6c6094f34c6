#include "kr_tracker/types.h"

#include <cmath>

namespace kr_tracker {

bool VehicleState::AllFinite() const {
  return std::isfinite(t_s) && p_world_body.allFinite() && v_world.allFinite() &&
         q_world_body.coeffs().allFinite() && w_body.allFinite() && a_world.allFinite() &&
         q_world_body.norm() > 0.5;
}

double VehicleState::Yaw() const {
  // Heading of the body x axis projected on the world xy plane (well defined except at +-90 deg pitch).
  const Eigen::Vector3d x_world = q_world_body.normalized() * Eigen::Vector3d::UnitX();
  return WrapAngle(std::atan2(x_world.y(), x_world.x()));
}

bool PositionReference::AllFinite() const {
  return p_world.allFinite() && v_world.allFinite() && a_world.allFinite() && j_world.allFinite() &&
         std::isfinite(yaw_rad) && std::isfinite(yaw_rate_radps);
}

PositionReference PositionReference::Hold(const Eigen::Vector3d& p_world, double yaw_rad) {
  PositionReference r;
  r.p_world = p_world;
  r.yaw_rad = WrapAngle(yaw_rad);
  return r;
}

bool So3Command::AllFinite() const {
  return force_world_N.allFinite() && q_world_des.coeffs().allFinite() && w_body_des_radps.allFinite() &&
         kR.allFinite() && kOm.allFinite();
}

double WrapAngle(double a_rad) {
  const double two_pi = 2.0 * M_PI;
  double w = std::fmod(a_rad + M_PI, two_pi);
  if (w < 0.0) w += two_pi;
  w -= M_PI;
  // fmod maps +pi to -pi: the convention is (-pi, pi].
  return w <= -M_PI ? M_PI : w;
}

}  // namespace kr_tracker
