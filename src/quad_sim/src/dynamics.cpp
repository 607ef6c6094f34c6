#include "quad_sim/dynamics.h"

#include "quad_sim/math_utils.h"

#include <Eigen/LU>

#include <algorithm>
#include <cmath>

namespace quad_sim {

bool DynamicsState::AllFinite() const {
  return p_world_body.allFinite() && v_world.allFinite() && q_world_body.coeffs().allFinite() &&
         w_body.allFinite() && motor_speeds_radps.allFinite();
}

quad_core::VehicleState DynamicsState::Odometry(double t_s) const {
  quad_core::VehicleState o;
  o.t_s = t_s;
  o.p_world_body = p_world_body;
  o.v_world = v_world;
  o.q_world_body = q_world_body;
  o.w_body = w_body;
  return o;
}

QuadrotorDynamics::QuadrotorDynamics(const quad_core::VehicleParams& vehicle,
                                     const GroundContactParams& ground)
    : vehicle_(vehicle), ground_(ground) {
  vehicle_.Validate();
  mixer_ = vehicle_.Mixer();
  inertia_inv_ = vehicle_.inertia_kgm2.inverse();
  const Eigen::Vector3d h = 0.5 * vehicle_.collision_box_m;
  int k = 0;
  for (int sx = -1; sx <= 1; sx += 2) {
    for (int sy = -1; sy <= 1; sy += 2) {
      for (int sz = -1; sz <= 1; sz += 2)
        corners_body_[k++] = Eigen::Vector3d(sx * h.x(), sy * h.y(), sz * h.z());
    }
  }
}

Wrench QuadrotorDynamics::RotorWrench(const DynamicsState& s) const {
  const Eigen::Vector4d w2 = s.motor_speeds_radps.cwiseProduct(s.motor_speeds_radps);
  const Eigen::Vector4d fm = mixer_ * w2;
  Wrench out;
  out.force_world_N = s.q_world_body * Eigen::Vector3d(0.0, 0.0, fm(0));
  out.moment_body_Nm = fm.tail<3>();
  return out;
}

double QuadrotorDynamics::LowestPointZ(const DynamicsState& s) const {
  const Eigen::Matrix3d R = s.q_world_body.toRotationMatrix();
  double z = s.p_world_body.z() + (R * corners_body_[0]).z();
  for (const auto& c : corners_body_) z = std::min(z, s.p_world_body.z() + (R * c).z());
  return z;
}

Wrench QuadrotorDynamics::GroundWrench(const DynamicsState& s) const {
  Wrench out;
  const Eigen::Matrix3d R = s.q_world_body.toRotationMatrix();
  const Eigen::Vector3d w_world = R * s.w_body;
  for (const auto& c_body : corners_body_) {
    const Eigen::Vector3d r_world = R * c_body;
    const double depth = -(s.p_world_body.z() + r_world.z());
    if (depth <= 0.0) continue;
    const Eigen::Vector3d v_corner = s.v_world + w_world.cross(r_world);
    // Unilateral normal force: the damper may not pull the corner down into the ground.
    const double normal =
        std::max(0.0, ground_.stiffness_N_per_m * depth - ground_.damping_Ns_per_m * v_corner.z());
    Eigen::Vector3d tangential(-ground_.friction_damping_Ns_per_m * v_corner.x(),
                               -ground_.friction_damping_Ns_per_m * v_corner.y(), 0.0);
    const double limit = ground_.friction_coeff * normal;
    const double t_norm = tangential.norm();
    if (t_norm > limit && t_norm > 0.0) tangential *= limit / t_norm;
    const Eigen::Vector3d f(tangential.x(), tangential.y(), normal);
    out.force_world_N += f;
    out.moment_body_Nm += c_body.cross(R.transpose() * f);
  }
  return out;
}

QuadrotorDynamics::Derivative QuadrotorDynamics::Evaluate(const DynamicsState& s,
                                                          const Eigen::Vector4d& motor_cmd_radps) const {
  // RK4's intermediate quaternions drift off the unit sphere by O(h^2): forces use the normalised attitude.
  DynamicsState sn = s;
  sn.q_world_body.normalize();
  const Eigen::Matrix3d R = sn.q_world_body.toRotationMatrix();
  const Wrench rotor = RotorWrench(sn);
  const Wrench ground = GroundWrench(sn);
  const Eigen::Vector3d v_body = R.transpose() * s.v_world;
  const Eigen::Vector3d drag_world = R * (-vehicle_.drag_coeff_Ns_per_m.cwiseProduct(v_body));

  Derivative d;
  d.p_dot = s.v_world;
  d.v_dot = (rotor.force_world_N + ground.force_world_N + drag_world) / vehicle_.mass_kg -
            Eigen::Vector3d(0.0, 0.0, vehicle_.gravity_mps2);
  // q_dot = 1/2 q (x) (0, w_body), stored as (w, x, y, z).
  const Eigen::Quaterniond& q = s.q_world_body;
  const Eigen::Vector3d& w = s.w_body;
  d.q_dot << 0.5 * (-q.x() * w.x() - q.y() * w.y() - q.z() * w.z()),
      0.5 * (q.w() * w.x() + q.y() * w.z() - q.z() * w.y()),
      0.5 * (q.w() * w.y() + q.z() * w.x() - q.x() * w.z()),
      0.5 * (q.w() * w.z() + q.x() * w.y() - q.y() * w.x());
  const Eigen::Vector3d moment = rotor.moment_body_Nm + ground.moment_body_Nm;
  d.w_dot = inertia_inv_ * (moment - w.cross(vehicle_.inertia_kgm2 * w));
  d.motor_dot = (motor_cmd_radps - s.motor_speeds_radps) / vehicle_.motor_time_constant_s;
  return d;
}

DynamicsState QuadrotorDynamics::Advance(const DynamicsState& s, const Derivative& d, double h) {
  DynamicsState out;
  out.p_world_body = s.p_world_body + h * d.p_dot;
  out.v_world = s.v_world + h * d.v_dot;
  out.q_world_body =
      Eigen::Quaterniond(s.q_world_body.w() + h * d.q_dot(0), s.q_world_body.x() + h * d.q_dot(1),
                         s.q_world_body.y() + h * d.q_dot(2), s.q_world_body.z() + h * d.q_dot(3));
  out.w_body = s.w_body + h * d.w_dot;
  out.motor_speeds_radps = s.motor_speeds_radps + h * d.motor_dot;
  return out;
}

DynamicsState QuadrotorDynamics::Step(const DynamicsState& s, const Eigen::Vector4d& motor_cmd_radps,
                                      double dt_s) const {
  const Eigen::Vector4d cmd = motor_cmd_radps.cwiseMax(0.0).cwiseMin(vehicle_.max_motor_speed_radps);
  const Derivative k1 = Evaluate(s, cmd);
  const Derivative k2 = Evaluate(Advance(s, k1, 0.5 * dt_s), cmd);
  const Derivative k3 = Evaluate(Advance(s, k2, 0.5 * dt_s), cmd);
  const Derivative k4 = Evaluate(Advance(s, k3, dt_s), cmd);
  Derivative sum;
  sum.p_dot = (k1.p_dot + 2.0 * k2.p_dot + 2.0 * k3.p_dot + k4.p_dot) / 6.0;
  sum.v_dot = (k1.v_dot + 2.0 * k2.v_dot + 2.0 * k3.v_dot + k4.v_dot) / 6.0;
  sum.q_dot = (k1.q_dot + 2.0 * k2.q_dot + 2.0 * k3.q_dot + k4.q_dot) / 6.0;
  sum.w_dot = (k1.w_dot + 2.0 * k2.w_dot + 2.0 * k3.w_dot + k4.w_dot) / 6.0;
  sum.motor_dot = (k1.motor_dot + 2.0 * k2.motor_dot + 2.0 * k3.motor_dot + k4.motor_dot) / 6.0;
  DynamicsState out = Advance(s, sum, dt_s);
  out.q_world_body.normalize();
  // Rotor speeds are physically non-negative; RK4 cannot overshoot a first-order lag for dt < tau, but keep
  // it so.
  out.motor_speeds_radps = out.motor_speeds_radps.cwiseMax(0.0);
  return out;
}

}  // namespace quad_sim
