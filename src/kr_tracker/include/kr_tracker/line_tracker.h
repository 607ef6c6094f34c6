// Line tracker (goto): a minimum-jerk (quintic) profile from the current reference state to a goal at rest,
// with its duration chosen so that velocity and acceleration stay within limits. Used for take-off and goto.
#pragma once

#include <Eigen/Core>

#include <array>
#include <optional>
#include <string>

#include "kr_tracker/tracker.h"

namespace kr_tracker {

struct LineTrackerConfig {
  double default_max_vel_mps = 2.0;
  double default_max_acc_mps2 = 1.5;
  double max_yaw_rate_radps = 1.0;
  void Validate() const;  // throws std::invalid_argument naming the field
};

// A quintic per axis on [0, T]: p(0), v(0), a(0) to p(T), 0, 0 (the minimum-jerk boundary value problem).
class MinJerkSegment {
 public:
  MinJerkSegment() = default;
  MinJerkSegment(const Eigen::Vector3d& p0, const Eigen::Vector3d& v0, const Eigen::Vector3d& a0,
                 const Eigen::Vector3d& p1, double duration_s);
  double duration_s() const { return duration_s_; }
  // k-th derivative (0..3) at time t (clamped to [0, T]).
  Eigen::Vector3d Eval(double t_s, int k) const;
  // Largest speed / acceleration norm, sampled (n samples).
  double MaxSpeed(int n = 100) const;
  double MaxAccel(int n = 100) const;

 private:
  double duration_s_ = 0.0;
  // coeffs_[i].col(axis): polynomial coefficients c_0..c_5 in powers of t.
  Eigen::Matrix<double, 6, 3> coeffs_ = Eigen::Matrix<double, 6, 3>::Zero();
};

// The shortest duration, searched from the rest-to-rest closed form (peak speed 1.875 D / T, peak
// acceleration 5.7735 D / T^2) upwards in 5 % steps, for which the profile from (p0, v0, a0) respects both
// limits.
double MinJerkDuration(const Eigen::Vector3d& p0, const Eigen::Vector3d& v0, const Eigen::Vector3d& a0,
                       const Eigen::Vector3d& p1, double max_vel_mps, double max_acc_mps2);

class LineTracker : public Tracker {
 public:
  explicit LineTracker(const LineTrackerConfig& config);
  std::string name() const override { return "line"; }
  void Activate(const PositionReference& last_ref, const quad_core::VehicleState& state) override;
  void Deactivate() override;
  PositionReference Update(const quad_core::VehicleState& state) override;
  TrackerStatus status() const override;

  // Sets a goal, flown from the current reference at the next Update. max_vel_mps / max_acc_mps2 <= 0 select
  // the configured defaults. Returns "" or why the goal is refused (non-finite values).
  std::string SetGoal(const Eigen::Vector3d& p_goal_world, double yaw_goal_rad, double max_vel_mps,
                      double max_acc_mps2);
  // SetGoal's checks alone: "" or why the goal would be refused.
  static std::string ValidateGoal(const Eigen::Vector3d& p_goal_world, double yaw_goal_rad,
                                  double max_vel_mps, double max_acc_mps2);
  // Duration of the current profile (0 when holding).
  double duration_s() const { return segment_.duration_s(); }

 private:
  struct Goal {
    Eigen::Vector3d p_world;
    double yaw_rad;
    double max_vel_mps;
    double max_acc_mps2;
  };
  LineTrackerConfig config_;
  bool active_ = false;
  PositionReference last_ref_;
  std::optional<Goal> pending_;
  bool moving_ = false;
  bool completed_ = false;
  double t_start_s_ = 0.0;
  MinJerkSegment segment_;
  double yaw_start_rad_ = 0.0;
  double yaw_delta_rad_ = 0.0;
  double yaw_duration_s_ = 0.0;
};

}  // namespace kr_tracker
