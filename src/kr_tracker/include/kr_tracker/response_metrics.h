// Step-response and tracking-error metrics (ROS-free), used by the closed-loop checks and the benchmark.
#pragma once

#include <Eigen/Core>

#include <vector>

namespace kr_tracker {

struct StepMetrics {
  double overshoot_pct = 0.0;       // largest excursion beyond the target, in % of the step
  double rise_time_s = 0.0;         // 10 % -> 90 % of the step
  double settling_time_s = 0.0;     // from the step until the response stays within the band for good
  double steady_state_error = 0.0;  // mean |y - target| over the final window
  bool rose = false;                // reached 90 % of the step
  bool settled = false;             // inside the band at the end
};

// One axis. t_s and y are samples (same length, t increasing); the step from y0 to y1 is applied at t_step_s.
// settle_band is a fraction of |y1 - y0| (0.02: the 2 % criterion); the steady-state error is averaged over
// the last final_window_s seconds. Throws std::invalid_argument for mismatched/empty input or y1 == y0.
StepMetrics AnalyzeStep(const std::vector<double>& t_s, const std::vector<double>& y, double y0, double y1,
                        double t_step_s, double settle_band = 0.02, double final_window_s = 1.0);

struct TrackingError {
  double rms_m = 0.0;
  double max_m = 0.0;
  int samples = 0;
};

// Euclidean position errors |p - p_ref| (pairs of equal-length sample lists).
TrackingError ComputeTrackingError(const std::vector<Eigen::Vector3d>& p,
                                   const std::vector<Eigen::Vector3d>& p_ref);

}  // namespace kr_tracker
