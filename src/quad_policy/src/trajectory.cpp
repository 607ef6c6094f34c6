#include "quad_policy/trajectory.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace quad_policy {

namespace {

// Evaluated in matrix form here, not through quad_core::NonUniformBspline (issue 31 tried it): that class
// refuses non-finite control points when it is built, while the safety layer must judge network outputs that
// hold NaN/Inf and refuse them with a verdict (non_finite_output) rather than an exception; TrajectoryInView
// and policy_replay evaluate such plans too. With NonUniformBspline the parity fixture's replay stopped at
// its NaN trajectory instead of giving the decisions it gave before
// (docs/notebook/2026-12_floor_plan_issue31.md).
const Eigen::Matrix4d& CubicMatrix() {
  // Uniform cubic B-spline in matrix form (Qin 2000): p(u) = [1 u u^2 u^3] M [c_k .. c_k+3]^T.
  static const Eigen::Matrix4d m =
      (Eigen::Matrix4d() << 1, 4, 1, 0, -3, 0, 3, 0, 3, -6, 3, 0, -1, 3, -3, 1).finished() / 6.0;
  return m;
}

// Segment index and local parameter of time t (clamped to the domain).
void Locate(const UniformBspline& s, double t_s, int* k, double* u) {
  if (s.num_ctrl_pts() < 4 || !(s.knot_dt_s > 0.0)) {
    throw std::invalid_argument("a uniform cubic B-spline needs >= 4 control points and knot_dt_s > 0");
  }
  if (!std::isfinite(t_s)) throw std::invalid_argument("B-spline evaluated at a non-finite time");
  const int segments = s.num_ctrl_pts() - 3;
  const double x = std::clamp(t_s / s.knot_dt_s, 0.0, static_cast<double>(segments));
  *k = std::min(static_cast<int>(std::floor(x)), segments - 1);
  *u = x - *k;
}

Eigen::Vector3d Blend(const UniformBspline& s, int k, const Eigen::RowVector4d& powers) {
  const Eigen::RowVector4d w = powers * CubicMatrix();
  return (w * s.ctrl_world.middleRows(k, 4)).transpose();
}

}  // namespace

std::vector<double> UniformBspline::Knots() const {
  std::vector<double> knots(num_ctrl_pts() + 4);
  for (int i = 0; i < static_cast<int>(knots.size()); ++i) knots[i] = (i - 3) * knot_dt_s;
  return knots;
}

Eigen::Vector3d UniformBspline::Position(double t_s) const {
  int k;
  double u;
  Locate(*this, t_s, &k, &u);
  return Blend(*this, k, Eigen::RowVector4d(1.0, u, u * u, u * u * u));
}

Eigen::Vector3d UniformBspline::Velocity(double t_s) const {
  int k;
  double u;
  Locate(*this, t_s, &k, &u);
  return Blend(*this, k, Eigen::RowVector4d(0.0, 1.0, 2.0 * u, 3.0 * u * u)) / knot_dt_s;
}

Eigen::Vector3d UniformBspline::Acceleration(double t_s) const {
  int k;
  double u;
  Locate(*this, t_s, &k, &u);
  return Blend(*this, k, Eigen::RowVector4d(0.0, 0.0, 2.0, 6.0 * u)) / (knot_dt_s * knot_dt_s);
}

CtrlPoints UniformBspline::VelocityCtrlPts() const {
  const int n = num_ctrl_pts();
  if (n < 2) return CtrlPoints(0, 3);
  return (ctrl_world.bottomRows(n - 1) - ctrl_world.topRows(n - 1)) / knot_dt_s;
}

CtrlPoints UniformBspline::AccelerationCtrlPts() const {
  const CtrlPoints v = VelocityCtrlPts();
  const int n = static_cast<int>(v.rows());
  if (n < 2) return CtrlPoints(0, 3);
  return (v.bottomRows(n - 1) - v.topRows(n - 1)) / knot_dt_s;
}

UniformBspline PolicyTrajectory(const CtrlPoints& ctrl_world, const PolicyMeta& meta, double stamp_s) {
  if (ctrl_world.rows() != meta.num_ctrl_pts) {
    throw std::invalid_argument("the policy's output has " + std::to_string(ctrl_world.rows()) +
                                " control points, its metadata declares " +
                                std::to_string(meta.num_ctrl_pts));
  }
  UniformBspline s;
  s.start_time_s = stamp_s;
  s.knot_dt_s = meta.knot_dt_s();
  s.ctrl_world = ctrl_world;
  return s;
}

namespace {

// p(t) = p0 + v0 T / 3 (1 - (1 - t/T)^3) + b (3 (t/T)^2 - 2 (t/T)^3) (b = 0: braking; else the final
// approach): one cubic, so the uniform cubic
// B-spline with K = 4 and knot interval T has it exactly with control points P(tau_i) - T^2 / 6 P''(tau_i) at
// the Greville abscissae tau_i = (i - 1) T (both extended beyond [0, T] as the polynomial).
UniformBspline StopCubic(const Eigen::Vector3d& p0, const Eigen::Vector3d& v0, const Eigen::Vector3d& b,
                         double duration, double start_time_s) {
  const auto position = [&](double t) {
    const double u = t / duration, r = 1.0 - u;
    return Eigen::Vector3d(p0 + v0 * (duration / 3.0) * (1.0 - r * r * r) +
                           b * (3.0 * u * u - 2.0 * u * u * u));
  };
  const auto acceleration = [&](double t) {
    const double u = t / duration;
    return Eigen::Vector3d(-2.0 * v0 * (1.0 - u) / duration + b * (6.0 - 12.0 * u) / (duration * duration));
  };
  UniformBspline s;
  s.start_time_s = start_time_s;
  s.knot_dt_s = duration;
  s.ctrl_world.resize(4, 3);
  for (int i = 0; i < 4; ++i) {
    const double tau = (i - 1) * duration;
    s.ctrl_world.row(i) = (position(tau) - duration * duration / 6.0 * acceleration(tau)).transpose();
  }
  return s;
}

void CheckStopInputs(const Eigen::Vector3d& p0, const Eigen::Vector3d& v0, double max_decel_mps2,
                     double min_duration_s, double start_time_s) {
  if (!p0.allFinite() || !v0.allFinite() || !std::isfinite(start_time_s)) {
    throw std::invalid_argument("stopping trajectory: non-finite start state");
  }
  if (!(max_decel_mps2 > 0.0) || !(min_duration_s > 0.0)) {
    throw std::invalid_argument("stopping trajectory: max_decel_mps2 and min_duration_s must be > 0");
  }
}

}  // namespace

UniformBspline BrakingTrajectory(const Eigen::Vector3d& p0_world, const Eigen::Vector3d& v0_world,
                                 double max_decel_mps2, double min_duration_s, double start_time_s) {
  CheckStopInputs(p0_world, v0_world, max_decel_mps2, min_duration_s, start_time_s);
  const double duration = std::max(2.0 * v0_world.norm() / max_decel_mps2, min_duration_s);
  return StopCubic(p0_world, v0_world, Eigen::Vector3d::Zero(), duration, start_time_s);
}

std::optional<UniformBspline> FinalApproach(const Eigen::Vector3d& p0_world, const Eigen::Vector3d& v0_world,
                                            const Eigen::Vector3d& goal_world, double max_acc_mps2,
                                            double min_duration_s, double start_time_s) {
  CheckStopInputs(p0_world, v0_world, max_acc_mps2, min_duration_s, start_time_s);
  if (!goal_world.allFinite()) throw std::invalid_argument("final approach: non-finite goal");
  constexpr double kStepS = 0.02;
  constexpr int kMaxSteps = 2000;
  for (int k = 0; k <= kMaxSteps; ++k) {
    const double duration = min_duration_s + k * kStepS;
    const Eigen::Vector3d b = goal_world - p0_world - v0_world * (duration / 3.0);
    const Eigen::Vector3d a_start = -2.0 * v0_world / duration + 6.0 * b / (duration * duration);
    const Eigen::Vector3d a_end = -6.0 * b / (duration * duration);
    if (std::max(a_start.norm(), a_end.norm()) <= max_acc_mps2) {
      return StopCubic(p0_world, v0_world, b, duration, start_time_s);
    }
  }
  return std::nullopt;
}

}  // namespace quad_policy
