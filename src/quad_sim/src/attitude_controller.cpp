#include "quad_sim/attitude_controller.h"

#include "quad_sim/math_utils.h"

#include <Eigen/LU>

#include <algorithm>
#include <cmath>

namespace quad_sim {

AttitudeTarget AttitudeTarget::FromSo3(const So3Command& cmd) {
  AttitudeTarget t;
  t.thrust_from_force = true;
  t.force_world_N = cmd.force_world_N;
  t.R_world_des = cmd.q_world_des.normalized().toRotationMatrix();
  t.w_body_des_radps = cmd.w_body_des_radps;
  t.kR = cmd.kR;
  t.kOm = cmd.kOm;
  t.enable_motors = cmd.enable_motors;
  return t;
}

AttitudeTarget AttitudeTarget::FromTrpy(const TrpyCommand& cmd) {
  AttitudeTarget t;
  t.thrust_from_force = false;
  t.thrust_N = cmd.thrust_N;
  t.R_world_des = QuatFromRpy(cmd.roll_rad, cmd.pitch_rad, cmd.yaw_rad).toRotationMatrix();
  t.w_body_des_radps = cmd.w_body_des_radps;
  t.kR = cmd.kR;
  t.kOm = cmd.kOm;
  t.enable_motors = cmd.enable_motors;
  return t;
}

AttitudeController::AttitudeController(const quad_core::VehicleParams& vehicle) : vehicle_(vehicle) {
  vehicle_.Validate();
  mixer_inv_ = vehicle_.Mixer().inverse();
}

Eigen::Vector4d AttitudeController::ThrustAndMoment(const AttitudeTarget& t, const DynamicsState& s) const {
  const Eigen::Matrix3d R = s.q_world_body.toRotationMatrix();
  const Eigen::Matrix3d& Rd = t.R_world_des;
  const Eigen::Vector3d& W = s.w_body;
  const Eigen::Vector3d e_R = 0.5 * Vee(Rd.transpose() * R - R.transpose() * Rd);
  const Eigen::Vector3d W_d_in_body = R.transpose() * Rd * t.w_body_des_radps;
  const Eigen::Vector3d e_W = W - W_d_in_body;
  const Eigen::Matrix3d& J = vehicle_.inertia_kgm2;
  const Eigen::Vector3d M =
      -t.kR.cwiseProduct(e_R) - t.kOm.cwiseProduct(e_W) + W.cross(J * W) - J * (Hat(W) * W_d_in_body);
  const double f = t.thrust_from_force ? t.force_world_N.dot(R.col(2)) : t.thrust_N;
  Eigen::Vector4d out;
  out << f, M;
  return out;
}

Eigen::Vector4d AttitudeController::MotorCommands(const AttitudeTarget& t, const DynamicsState& s) const {
  if (!t.enable_motors) return Eigen::Vector4d::Zero();
  const Eigen::Vector4d w2 = mixer_inv_ * ThrustAndMoment(t, s);
  const double lo = vehicle_.min_motor_speed_radps * vehicle_.min_motor_speed_radps;
  const double hi = vehicle_.max_motor_speed_radps * vehicle_.max_motor_speed_radps;
  Eigen::Vector4d out;
  for (int i = 0; i < 4; ++i) out(i) = std::sqrt(std::clamp(w2(i), lo, hi));
  return out;
}

}  // namespace quad_sim
