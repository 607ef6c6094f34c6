#include "kr_tracker/ziegler_nichols.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

namespace kr_tracker {

OscillationAnalysis AnalyzeOscillation(const std::vector<double>& t_s, const std::vector<double>& y,
                                       double t_from_s, double noise_floor, int max_extrema) {
  if (max_extrema < 3) throw std::invalid_argument("AnalyzeOscillation: max_extrema must be >= 3");
  if (t_s.size() != y.size()) throw std::invalid_argument("AnalyzeOscillation: size mismatch");
  std::vector<double> ext_t;
  std::vector<double> ext_abs;
  for (size_t i = 1; i + 1 < y.size(); ++i) {
    if (t_s[i] < t_from_s) continue;
    const bool is_max = y[i] > y[i - 1] && y[i] >= y[i + 1] && y[i] > 0.0;
    const bool is_min = y[i] < y[i - 1] && y[i] <= y[i + 1] && y[i] < 0.0;
    if ((is_max || is_min) && std::fabs(y[i]) > noise_floor && static_cast<int>(ext_t.size()) < max_extrema) {
      ext_t.push_back(t_s[i]);
      ext_abs.push_back(std::fabs(y[i]));
    }
  }
  OscillationAnalysis a;
  a.num_peaks = static_cast<int>(ext_t.size());
  if (a.num_peaks < 3) {
    // Too few extrema above the floor: a response that died out (or never oscillated) is stable.
    a.growth_ratio = 0.0;
    return a;
  }
  // Least squares of log amplitude against extremum index.
  const int n = a.num_peaks;
  double sx = 0, sy = 0, sxx = 0, sxy = 0;
  for (int i = 0; i < n; ++i) {
    const double ly = std::log(ext_abs[i]);
    sx += i;
    sy += ly;
    sxx += static_cast<double>(i) * i;
    sxy += i * ly;
  }
  const double slope = (n * sxy - sx * sy) / (n * sxx - sx * sx);
  a.growth_ratio = std::exp(slope);
  // Consecutive extrema alternate in sign: a full period spans two of them.
  a.period_s = 2.0 * (ext_t.back() - ext_t.front()) / (n - 1);
  return a;
}

const char* ToString(UltimateGainStatus s) {
  switch (s) {
    case UltimateGainStatus::kFound:
      return "found";
    case UltimateGainStatus::kNoInstability:
      return "no sustained oscillation up to k_max";
    case UltimateGainStatus::kUnstableAtMinimum:
      return "already unstable at k_min";
  }
  return "unknown";
}

UltimateGainResult FindUltimateGain(const GainExperiment& experiment, const UltimateGainSearch& search) {
  if (!(search.k_min > 0.0) || !(search.k_max > search.k_min) || !(search.relative_tol > 0.0)) {
    throw std::invalid_argument("FindUltimateGain: need 0 < k_min < k_max and relative_tol > 0");
  }
  UltimateGainResult r;
  auto run = [&](double k) {
    std::vector<double> t, y;
    experiment(k, &t, &y);
    const OscillationAnalysis a =
        AnalyzeOscillation(t, y, search.t_from_s, search.noise_floor, search.max_extrema);
    r.trials.push_back({k, a.growth_ratio, a.period_s});
    ++r.experiments;
    return a;
  };
  OscillationAnalysis at_lo = run(search.k_min);
  if (at_lo.growth_ratio >= 1.0) {
    r.status = UltimateGainStatus::kUnstableAtMinimum;
    r.ku = search.k_min;
    r.tu_s = at_lo.period_s;
    return r;
  }
  double lo = search.k_min;
  double hi = lo;
  OscillationAnalysis at_hi;
  while (true) {
    hi = std::min(2.0 * hi, search.k_max);
    at_hi = run(hi);
    if (at_hi.growth_ratio >= 1.0) break;
    lo = hi;
    at_lo = at_hi;
    if (hi >= search.k_max) {
      r.status = UltimateGainStatus::kNoInstability;
      r.ku = search.k_max;
      return r;
    }
  }
  while ((hi - lo) / hi > search.relative_tol) {
    const double mid = 0.5 * (lo + hi);
    const OscillationAnalysis a = run(mid);
    if (a.growth_ratio >= 1.0) {
      hi = mid;
      at_hi = a;
    } else {
      lo = mid;
      at_lo = a;
    }
  }
  r.ku = 0.5 * (lo + hi);
  // Near Ku both neighbours oscillate at about the ultimate frequency; a strongly damped side has no period.
  if (at_lo.period_s > 0.0 && at_hi.period_s > 0.0) {
    r.tu_s = 0.5 * (at_lo.period_s + at_hi.period_s);
  } else {
    r.tu_s = std::max(at_lo.period_s, at_hi.period_s);
  }
  return r;
}

std::vector<PidGains> ZieglerNicholsRules(double ku, double tu_s) {
  const double inf = std::numeric_limits<double>::infinity();
  return {
      {"P", 0.5 * ku, inf, 0.0},
      {"PI", 0.45 * ku, tu_s / 1.2, 0.0},
      {"PD", 0.8 * ku, inf, tu_s / 8.0},
      {"PID classic", 0.6 * ku, tu_s / 2.0, tu_s / 8.0},
      {"PID some overshoot", ku / 3.0, tu_s / 2.0, tu_s / 3.0},
      {"PID no overshoot", 0.2 * ku, tu_s / 2.0, tu_s / 3.0},
  };
}

}  // namespace kr_tracker
