// The trajectories the policy node sends: uniform cubic B-splines in the world frame, as quad_msgs/Bspline
// carries them (knots (i - 3) dt for i = 0 .. K + 3, so knots[3] = 0 is flown at start_time). Evaluated in
// matrix form, not through quad_core::NonUniformBspline: see trajectory.cpp.
#pragma once

#include <Eigen/Core>

#include <optional>
#include <vector>

#include "quad_policy/preprocessing.h"

namespace quad_policy {

struct UniformBspline {
  double start_time_s = 0.0;  // when knots[order] = 0 is flown (the depth frame's stamp)
  double knot_dt_s = 0.0;
  // K x 3, K >= 4. No yaw: the tracker turns the vehicle along its direction of travel.
  CtrlPoints ctrl_world;

  int num_ctrl_pts() const { return static_cast<int>(ctrl_world.rows()); }
  double duration_s() const { return (num_ctrl_pts() - 3) * knot_dt_s; }
  // (i - 3) * knot_dt_s for i = 0 .. K + 3 (K + 4 knots: control points + order + 1).
  std::vector<double> Knots() const;
  // Position, velocity, acceleration at t_s seconds after start_time (clamped to [0, duration]).
  Eigen::Vector3d Position(double t_s) const;
  Eigen::Vector3d Velocity(double t_s) const;
  Eigen::Vector3d Acceleration(double t_s) const;
  // Control points of the derivative splines (convex-hull bounds of velocity and acceleration):
  // V_i = (c_{i+1} - c_i) / dt (K - 1 rows), A_i = (V_{i+1} - V_i) / dt (K - 2 rows).
  CtrlPoints VelocityCtrlPts() const;
  CtrlPoints AccelerationCtrlPts() const;
};

// The policy's output as a trajectory: its control points over its fixed horizon, started at stamp_s.
UniformBspline PolicyTrajectory(const CtrlPoints& ctrl_world, const PolicyMeta& meta, double stamp_s);

// The stopping trajectory sent when a plan is refused (refusal action `stop`): from p0 with velocity v0 to
// rest along a straight line, p(t) = p0 + v0 T / 3 (1 - (1 - t / T)^3) for t in [0, T] (velocity v0 (1 -
// t/T)^2, acceleration largest at t = 0: 2 |v0| / T), with T = max(2 |v0| / max_decel_mps2, min_duration_s).
// It is one cubic, so the uniform cubic B-spline with K = 4 and knot interval T represents it exactly
// (control points c_i = P(tau_i) - T^2 / 6 P''(tau_i) at the Greville abscissae tau_i = (i - 1) T). Throws
// std::invalid_argument on non-finite input or non-positive limits.
UniformBspline BrakingTrajectory(const Eigen::Vector3d& p0_world, const Eigen::Vector3d& v0_world,
                                 double max_decel_mps2, double min_duration_s, double start_time_s);

// The final approach (recovery.final_approach_m): from p0 with velocity v0 to rest at the goal, p(t) = p0 +
// v0 T / 3 (1 - (1 - u)^3) + b (3 u^2 - 2 u^3), u = t / T, b = goal - p0 - v0 T / 3. Its acceleration is
// linear in u, -2 v0 (1 - u) / T + b (6 - 12 u) / T^2, so largest at an end; T is the first of min_duration_s
// + k * 0.02 s (k = 0 .. 2000) at which both ends are within max_acc_mps2. nullopt when no such T exists. One
// cubic (K = 4). Throws std::invalid_argument on non-finite input or non-positive limits.
std::optional<UniformBspline> FinalApproach(const Eigen::Vector3d& p0_world, const Eigen::Vector3d& v0_world,
                                            const Eigen::Vector3d& goal_world, double max_acc_mps2,
                                            double min_duration_s, double start_time_s);

}  // namespace quad_policy
