#include "quad_core/vehicle_state.h"

#include <cmath>

namespace quad_core {

bool VehicleState::AllFinite() const {
  return std::isfinite(t_s) && p_world_body.allFinite() && v_world.allFinite() &&
         q_world_body.coeffs().allFinite() && w_body.allFinite() && a_world.allFinite() &&
         q_world_body.norm() > 0.5;
}

double VehicleState::Yaw() const {
  // Well defined except at +-90 deg pitch.
  const Eigen::Vector3d x_world = q_world_body.normalized() * Eigen::Vector3d::UnitX();
  return WrapAngle(std::atan2(x_world.y(), x_world.x()));
}

double WrapAngle(double a_rad) {
  const double two_pi = 2.0 * M_PI;
  double w = std::fmod(a_rad + M_PI, two_pi);
  if (w < 0.0) w += two_pi;
  w -= M_PI;
  // fmod maps +pi to -pi: the convention is (-pi, pi].
  return w <= -M_PI ? M_PI : w;
}

}  // namespace quad_core
