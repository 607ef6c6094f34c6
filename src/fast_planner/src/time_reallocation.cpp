#include "fast_planner/time_reallocation.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <vector>

namespace fast_planner {

double MaxVelocityRatio(const quad_core::NonUniformBspline& spline, double max_vel_mps) {
  return spline.Derivative().MaxCtrlPtNorm() / max_vel_mps;
}

double MaxAccelerationRatio(const quad_core::NonUniformBspline& spline, double max_acc_mps2) {
  return spline.Derivative(2).MaxCtrlPtNorm() / max_acc_mps2;
}

ReallocationResult ReallocateTime(const quad_core::NonUniformBspline& input, const LimitsConfig& limits,
                                  int max_iterations, double margin, StartPolicy start_policy) {
  const bool keep_start = start_policy == StartPolicy::kKeep;
  const int p = input.order();
  if (p < 2) throw std::invalid_argument("ReallocateTime: the spline's degree must be >= 2");
  if (!(margin >= 1.0)) throw std::invalid_argument("ReallocateTime: margin must be >= 1");
  ValidateLimitsConfig(limits);
  const Eigen::MatrixXd& q = input.ctrl_pts();
  std::vector<double> knots = input.knots();
  const int num_spans = static_cast<int>(knots.size()) - 1;
  // The state at the start (u_p) depends on Q_0..Q_2 and the knots u_0..u_{2p-1}: with a kept start those
  // spans are never stretched, and the derivative control points the start state alone determines (V_0, V_1,
  // A_0) are not checked. A_1 is checked: if only its unstretchable spans could fix it, the start is given up
  // below.
  const int first_stretchable = keep_start ? 2 * p - 1 : 0;
  const int first_v = keep_start ? 2 : 0;
  const int first_a = keep_start ? 1 : 0;

  ReallocationResult result{input,
                            0,
                            false,
                            keep_start,
                            MaxVelocityRatio(input, limits.max_vel_mps),
                            MaxAccelerationRatio(input, limits.max_acc_mps2)};
  const double slack = 1e-9;
  // Stretches the spans [k0, k1] so that their total length grows by `ratio`, using the stretchable ones
  // only.
  auto demand = [&](int k0, int k1, double ratio, std::vector<double>* stretch) {
    k1 = std::min(k1, num_spans - 1);
    double total = 0.0, free = 0.0;
    for (int k = k0; k <= k1; ++k) {
      total += knots[k + 1] - knots[k];
      if (k >= first_stretchable) free += knots[k + 1] - knots[k];
    }
    if (free <= 0.0) return;
    const double s = 1.0 + (ratio - 1.0) * total / free;
    for (int k = std::max(k0, first_stretchable); k <= k1; ++k) (*stretch)[k] = std::max((*stretch)[k], s);
  };
  for (int iter = 0; iter < max_iterations; ++iter) {
    const quad_core::NonUniformBspline spline(q, p, knots);
    const Eigen::MatrixXd vel = spline.Derivative().ctrl_pts();
    const Eigen::MatrixXd acc = spline.Derivative(2).ctrl_pts();
    std::vector<double> stretch(num_spans, 1.0);
    bool feasible = true;
    for (int i = first_v; i < vel.rows(); ++i) {
      const double r = vel.row(i).norm() / limits.max_vel_mps;
      if (r <= 1.0 + slack) continue;
      feasible = false;
      demand(i + 1, i + p, r * margin, &stretch);
    }
    for (int j = first_a; j < acc.rows(); ++j) {
      const double r = acc.row(j).norm() / limits.max_acc_mps2;
      if (r <= 1.0 + slack) continue;
      feasible = false;
      demand(j + 2, j + p, std::sqrt(r) * margin, &stretch);
    }
    if (feasible) {
      result.spline = spline.TimeShifted(-spline.tmin());
      result.iterations = iter;
      return result;
    }
    // Stretch the flagged spans; later knots shift by the accumulated extra time.
    std::vector<double> next(knots.size());
    next[0] = knots[0];
    for (int k = 0; k < num_spans; ++k) next[k + 1] = next[k] + stretch[k] * (knots[k + 1] - knots[k]);
    knots.swap(next);
  }
  if (keep_start) {
    ReallocationResult plain = ReallocateTime(input, limits, max_iterations, margin, StartPolicy::kMayChange);
    plain.start_kept = false;
    return plain;
  }
  const quad_core::NonUniformBspline spline(q, p, knots);
  const double r = std::max(MaxVelocityRatio(spline, limits.max_vel_mps),
                            std::sqrt(MaxAccelerationRatio(spline, limits.max_acc_mps2)));
  result.iterations = max_iterations;
  if (r <= 1.0 + slack) {
    result.spline = spline.TimeShifted(-spline.tmin());
    return result;
  }
  result.used_uniform_fallback = true;
  result.spline = spline.TimeScaled(r * margin).TimeShifted(-spline.tmin());
  return result;
}

}  // namespace fast_planner
