// Ziegler-Nichols closed-loop tuning (Ziegler & Nichols 1942; Patel, Resonance 25(10), 2020, the reference
// the thesis used), ROS-free: find the ultimate gain Ku at which a P-only loop oscillates with constant
// amplitude and the period Tu of that oscillation, then derive PID gains from the classic rules.
//
// The experiment itself is a callback (gain -> response samples), so the search is tested on analytic plants
// and run on the simulator by the zn_tune tool.
#pragma once

#include <functional>
#include <string>
#include <vector>

namespace kr_tracker {

struct OscillationAnalysis {
  int num_peaks = 0;          // local extrema of the signal above the noise floor
  double growth_ratio = 0.0;  // amplitude ratio per half period (> 1 growing, < 1 decaying)
  double period_s = 0.0;      // mean spacing of same-sign extrema (0 if fewer than 3 extrema)
};

// Extrema of y after t_from_s whose magnitude exceeds noise_floor; the growth ratio is exp(slope) of a
// least-squares line through log |extremum| against the extremum's index, over the first max_extrema extrema
// only: a real loop that is unstable grows until an actuator saturates and then settles into a limit cycle of
// constant amplitude, which must not be mistaken for the marginal case.
OscillationAnalysis AnalyzeOscillation(const std::vector<double>& t_s, const std::vector<double>& y,
                                       double t_from_s, double noise_floor, int max_extrema = 8);

enum class UltimateGainStatus { kFound, kNoInstability, kUnstableAtMinimum };
const char* ToString(UltimateGainStatus s);

struct UltimateGainResult {
  UltimateGainStatus status = UltimateGainStatus::kFound;
  double ku = 0.0;    // ultimate gain (bisection midpoint)
  double tu_s = 0.0;  // ultimate period, from the experiments nearest Ku
  int experiments = 0;
  // Every experiment: gain, growth ratio, period (for the report).
  struct Trial {
    double gain;
    double growth_ratio;
    double period_s;
  };
  std::vector<Trial> trials;
};

struct UltimateGainSearch {
  double k_min = 0.1;          // assumed stable; the search first checks it
  double k_max = 1000.0;       // give up (kNoInstability) if still stable here
  double relative_tol = 0.02;  // bisection until (hi - lo) / hi < tol
  double t_from_s = 0.0;       // ignore samples before this time (the excitation)
  double noise_floor = 1e-6;   // extrema below this magnitude are ignored
  int max_extrema = 8;         // extrema used for the growth ratio (before saturation sets in)
};

// experiment(gain) returns (t_s, y) of the loop's response with that proportional gain. Growth ratio >= 1
// counts as unstable. The bracket is grown by doubling from k_min, then bisected.
using GainExperiment = std::function<void(double gain, std::vector<double>* t_s, std::vector<double>* y)>;
UltimateGainResult FindUltimateGain(const GainExperiment& experiment, const UltimateGainSearch& search);

// A PID in the standard form u = Kp (e + 1/Ti integral(e) + Td de/dt); ti_s = inf means no integral term.
struct PidGains {
  std::string rule;
  double kp = 0.0;
  double ti_s = 0.0;
  double td_s = 0.0;
};

// The classic Ziegler-Nichols table and its common variants: P, PI, PD, classic PID, "some overshoot",
// "no overshoot".
std::vector<PidGains> ZieglerNicholsRules(double ku, double tu_s);

}  // namespace kr_tracker
