// The back end: the front-end path fitted to a uniform cubic B-spline, then optimised on its control points
// (Zhou et al. 2019, Sec. IV) with NLopt's L-BFGS and analytic gradients.
//
// Cost (control points Q_0..Q_{N-1}, knot span ts):
//   smoothness   sum |Q_{i+3} - 3 Q_{i+2} + 3 Q_{i+1} - Q_i|^2            (jerk of the control polygon)
//   distance     sum over free Q_i with d(Q_i) < d_safe of (d(Q_i) - d_safe)^2, d the ESDF (trilinear)
//   feasibility  sum ((|V_i|^2 - v_max^2) / v_max^2)^2 over |V_i| > v_max, V_i = (Q_{i+1} - Q_i) / ts, and
//   the same
//                for A_i = (Q_{i+2} - 2 Q_{i+1} + Q_i) / ts^2 against a_max (the convex-hull property:
//                bounding the derivative control points bounds the curve's velocity and acceleration)
//   endpoint     |(Q_{N-3} + 4 Q_{N-2} + Q_{N-1}) / 6 - p_end|^2 when the end is not fixed (local plans
//   ending at
//                the horizon keep their end near the front end's)
// The first three control points are fixed (they set the start position, velocity and acceleration); the last
// three too when the plan ends at the goal at rest.
#pragma once

#include <Eigen/Core>

#include <string>

#include "fast_planner/esdf.h"
#include "fast_planner/planner_config.h"
#include "fast_planner/poly_path.h"

namespace fast_planner {

// Cubic B-spline degree used throughout the planner.
constexpr int kSplineDegree = 3;

// Control points of the uniform cubic B-spline with knot span ts_s (on the knots of
// quad_core::NonUniformBspline::Uniform, valid domain [0, K ts_s], K = num rows - 3) fitted to the path:
// K = ceil(duration / ts_nominal_s) spans, ts_s = duration / K. The start position, velocity and acceleration
// are met exactly (the first three control points follow from them in closed form); positions at the K knots
// after the start and the end velocity and acceleration are matched by least squares (exactly, when fix_end,
// for the last three control points from the end state). Returns an (K + 3) x 3 matrix; throws
// std::invalid_argument on an empty path or a non-positive span.
Eigen::MatrixXd FitUniformBspline(const PolyPath& path, double ts_nominal_s, const Eigen::Vector3d& start_acc,
                                  bool fix_end, double* ts_s);

// The three control points of a uniform cubic B-spline whose value, first and second derivatives at a knot
// are (p, v, a); returned as rows 0..2 of a 3 x 3 matrix.
Eigen::Matrix3d ControlPointsFromState(const Eigen::Vector3d& p, const Eigen::Vector3d& v,
                                       const Eigen::Vector3d& a, double ts_s);

struct BsplineCostParams {
  double ts_s = 0.0;
  double w_smooth = 0.0;
  double w_distance = 0.0;
  double w_feasibility = 0.0;
  double w_endpoint = 0.0;
  double safe_distance_m = 0.0;
  double max_vel_mps = 0.0;
  double max_acc_mps2 = 0.0;
  bool fix_end = false;
  Eigen::Vector3d end_target = Eigen::Vector3d::Zero();
};

struct BsplineCost {
  double smooth = 0.0;
  double distance = 0.0;
  double feasibility = 0.0;
  double endpoint = 0.0;
  double total = 0.0;  // the weighted sum
};

// The weighted cost of control points q (N x 3, N >= 4) and, if grad is not null, its gradient (N x 3; rows
// of fixed control points are zero).
BsplineCost EvaluateBsplineCost(const BsplineCostParams& params, const Esdf& esdf, const Eigen::MatrixXd& q,
                                Eigen::MatrixXd* grad);

struct OptimizationResult {
  Eigen::MatrixXd ctrl_pts;
  BsplineCost initial;
  BsplineCost final;
  int evaluations = 0;
  std::string nlopt_result;  // NLopt's stop reason (or the exception it threw; the best point is kept)
};

class BsplineOptimizer {
 public:
  // Throws quad_core::ConfigError on invalid optimiser or limit values.
  BsplineOptimizer(const OptimizerConfig& cfg, const LimitsConfig& limits);

  // Optimises the free control points of `ctrl_pts` (N x 3, N >= 4 + fixed). distance_weight_scale multiplies
  // w_distance (raised when a result was found in collision).
  OptimizationResult Optimize(const Eigen::MatrixXd& ctrl_pts, double ts_s, const Esdf& esdf, bool fix_end,
                              const Eigen::Vector3d& end_target, double distance_weight_scale = 1.0) const;

  BsplineCostParams Params(double ts_s, bool fix_end, const Eigen::Vector3d& end_target,
                           double distance_weight_scale) const;

 private:
  OptimizerConfig cfg_;
  LimitsConfig limits_;
};

}  // namespace fast_planner
