#include "kr_tracker/response_metrics.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

namespace kr_tracker {

StepMetrics AnalyzeStep(const std::vector<double>& t_s, const std::vector<double>& y, double y0, double y1,
                        double t_step_s, double settle_band, double final_window_s) {
  if (t_s.size() != y.size() || t_s.empty()) {
    throw std::invalid_argument("AnalyzeStep: time and value samples must be non-empty and of equal length");
  }
  const double step = y1 - y0;
  if (!(std::fabs(step) > 0.0)) throw std::invalid_argument("AnalyzeStep: zero step (y1 == y0)");
  const double dir = step > 0.0 ? 1.0 : -1.0;
  const double mag = std::fabs(step);
  StepMetrics m;
  double t10 = -1.0;
  double t90 = -1.0;
  double max_beyond = 0.0;
  double last_outside = t_step_s;
  for (size_t i = 0; i < t_s.size(); ++i) {
    if (t_s[i] < t_step_s) continue;
    const double progress = dir * (y[i] - y0) / mag;  // 0 at the start, 1 at the target
    if (t10 < 0.0 && progress >= 0.1) t10 = t_s[i];
    if (t90 < 0.0 && progress >= 0.9) t90 = t_s[i];
    max_beyond = std::max(max_beyond, dir * (y[i] - y1));
    if (std::fabs(y[i] - y1) > settle_band * mag) last_outside = t_s[i];
  }
  m.rose = t90 >= 0.0;
  m.rise_time_s = m.rose ? t90 - t10 : std::numeric_limits<double>::infinity();
  m.overshoot_pct = 100.0 * max_beyond / mag;
  m.settled = std::fabs(y.back() - y1) <= settle_band * mag;
  // Settled: the first sample after the last one outside the band.
  m.settling_time_s = m.settled ? last_outside - t_step_s : std::numeric_limits<double>::infinity();
  double sum = 0.0;
  int n = 0;
  for (size_t i = 0; i < t_s.size(); ++i) {
    if (t_s[i] >= t_s.back() - final_window_s) {
      sum += std::fabs(y[i] - y1);
      ++n;
    }
  }
  m.steady_state_error = sum / n;
  return m;
}

TrackingError ComputeTrackingError(const std::vector<Eigen::Vector3d>& p,
                                   const std::vector<Eigen::Vector3d>& p_ref) {
  if (p.size() != p_ref.size() || p.empty()) {
    throw std::invalid_argument("ComputeTrackingError: position lists must be non-empty and of equal length");
  }
  TrackingError e;
  double sum_sq = 0.0;
  for (size_t i = 0; i < p.size(); ++i) {
    const double d = (p[i] - p_ref[i]).norm();
    sum_sq += d * d;
    e.max_m = std::max(e.max_m, d);
  }
  e.samples = static_cast<int>(p.size());
  e.rms_m = std::sqrt(sum_sq / e.samples);
  return e;
}

}  // namespace kr_tracker
