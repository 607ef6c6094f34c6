#include "kr_tracker/reference_trajectories.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <vector>

namespace kr_tracker {

quad_core::NonUniformBspline MakeFigureEight(const FigureEightSpec& spec, double t0_s) {
  if (!(spec.half_length_m > 0.0) || !(spec.half_width_m > 0.0) || spec.laps < 1 ||
      !(spec.peak_speed_mps > 0.0) || !(spec.ctrl_pt_dt_s > 0.0) ||
      !(spec.ramp_fraction > 0.0 && spec.ramp_fraction < 0.5)) {
    throw std::invalid_argument("MakeFigureEight: sizes, laps, speed, dt must be positive, ramp in (0, 0.5)");
  }
  // Nominal: theta runs 0 -> 2 pi laps with a speed profile s'(tau) that ramps up with a smoothstep, cruises
  // and ramps down; the absolute timing is fixed later by the time scaling.
  const int n_samples = 40 * spec.laps;  // control points along the curve
  const double theta_total = 2.0 * M_PI * spec.laps;
  // Cumulative profile: integrate a trapezoid-like smooth rate r(tau) on tau in [0, 1].
  const int fine = 20000;
  std::vector<double> cum(fine + 1, 0.0);
  auto rate = [&](double tau) {
    const double rf = spec.ramp_fraction;
    auto smooth = [](double x) { return x * x * (3.0 - 2.0 * x); };
    if (tau < rf) return smooth(tau / rf);
    if (tau > 1.0 - rf) return smooth((1.0 - tau) / rf);
    return 1.0;
  };
  for (int i = 1; i <= fine; ++i) {
    const double a = (i - 1) / static_cast<double>(fine);
    const double b = i / static_cast<double>(fine);
    cum[i] = cum[i - 1] + 0.5 * (rate(a) + rate(b)) / fine;
  }
  Eigen::MatrixXd pts(n_samples + 1 + 4, 3);
  int row = 0;
  auto curve = [&](double theta) -> Eigen::Vector3d {
    return Eigen::Vector3d(spec.half_length_m * std::sin(theta), spec.half_width_m * std::sin(2.0 * theta),
                           0.0) +
           spec.center_world;
  };
  // Tripled end points: a uniform cubic starts at (P0 + 4 P1 + P2) / 6 with zero velocity and acceleration.
  pts.row(row++) = curve(0.0).transpose();
  pts.row(row++) = curve(0.0).transpose();
  for (int k = 0; k <= n_samples; ++k) {
    const double tau = k / static_cast<double>(n_samples);
    const double theta = theta_total * cum[static_cast<int>(std::lround(tau * fine))] / cum[fine];
    pts.row(row++) = curve(theta).transpose();
  }
  pts.row(row++) = curve(theta_total).transpose();
  pts.row(row++) = curve(theta_total).transpose();
  const quad_core::NonUniformBspline raw =
      quad_core::NonUniformBspline::Uniform(pts, 3, spec.ctrl_pt_dt_s, t0_s);
  const double peak = SampledPeakSpeed(raw);
  return raw.TimeScaled(peak / spec.peak_speed_mps);
}

double SampledPeakSpeed(const quad_core::NonUniformBspline& pos, double dt_s) {
  const quad_core::NonUniformBspline vel = pos.Derivative();
  double peak = 0.0;
  const int n = std::max(1, static_cast<int>(std::ceil(pos.duration() / dt_s)));
  for (int i = 0; i <= n; ++i)
    peak = std::max(peak, vel.Evaluate(pos.tmin() + pos.duration() * i / n).norm());
  return peak;
}

}  // namespace kr_tracker
