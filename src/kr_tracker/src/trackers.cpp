#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include "kr_tracker/line_tracker.h"
#include "kr_tracker/tracker.h"

namespace kr_tracker {

const char* ToString(TrackerStatus status) {
  switch (status) {
    case TrackerStatus::kInactive:
      return "inactive";
    case TrackerStatus::kHolding:
      return "holding";
    case TrackerStatus::kTracking:
      return "tracking";
    case TrackerStatus::kSucceeded:
      return "succeeded";
  }
  return "unknown";
}

void HoverTracker::Activate(const PositionReference& last_ref, const quad_core::VehicleState& /*state*/) {
  hold_ = PositionReference::Hold(last_ref.p_world, last_ref.yaw_rad);
  active_ = true;
}

PositionReference HoverTracker::Update(const quad_core::VehicleState& /*state*/) { return hold_; }

// ---------------------------------------------------------------------------------------------------------------
// Line tracker

void LineTrackerConfig::Validate() const {
  auto positive = [](double v, const char* name) {
    if (!(v > 0.0) || !std::isfinite(v)) {
      throw std::invalid_argument(std::string("LineTrackerConfig: ") + name + " = " + std::to_string(v) +
                                  " must be > 0");
    }
  };
  positive(default_max_vel_mps, "default_max_vel_mps");
  positive(default_max_acc_mps2, "default_max_acc_mps2");
  positive(max_yaw_rate_radps, "max_yaw_rate_radps");
}

MinJerkSegment::MinJerkSegment(const Eigen::Vector3d& p0, const Eigen::Vector3d& v0,
                               const Eigen::Vector3d& a0, const Eigen::Vector3d& p1, double duration_s)
    : duration_s_(duration_s) {
  if (!(duration_s > 0.0)) throw std::invalid_argument("MinJerkSegment: duration must be > 0");
  const double t = duration_s;
  const Eigen::Vector3d dp = p1 - p0;
  // Closed-form solution of p(T) = p1, v(T) = 0, a(T) = 0 for the three highest coefficients.
  coeffs_.row(0) = p0.transpose();
  coeffs_.row(1) = v0.transpose();
  coeffs_.row(2) = 0.5 * a0.transpose();
  coeffs_.row(3) = ((20.0 * dp - 12.0 * v0 * t - 3.0 * a0 * t * t) / (2.0 * std::pow(t, 3))).transpose();
  coeffs_.row(4) = ((-30.0 * dp + 16.0 * v0 * t + 3.0 * a0 * t * t) / (2.0 * std::pow(t, 4))).transpose();
  coeffs_.row(5) = ((12.0 * dp - 6.0 * v0 * t - a0 * t * t) / (2.0 * std::pow(t, 5))).transpose();
}

Eigen::Vector3d MinJerkSegment::Eval(double t_s, int k) const {
  const double t = std::clamp(t_s, 0.0, duration_s_);
  Eigen::Vector3d out = Eigen::Vector3d::Zero();
  for (int i = k; i < 6; ++i) {
    double factor = 1.0;  // i! / (i - k)!
    for (int j = 0; j < k; ++j) factor *= i - j;
    out += factor * std::pow(t, i - k) * coeffs_.row(i).transpose();
  }
  return out;
}

double MinJerkSegment::MaxSpeed(int n) const {
  double m = 0.0;
  for (int i = 0; i <= n; ++i) m = std::max(m, Eval(duration_s_ * i / n, 1).norm());
  return m;
}

double MinJerkSegment::MaxAccel(int n) const {
  double m = 0.0;
  for (int i = 0; i <= n; ++i) m = std::max(m, Eval(duration_s_ * i / n, 2).norm());
  return m;
}

double MinJerkDuration(const Eigen::Vector3d& p0, const Eigen::Vector3d& v0, const Eigen::Vector3d& a0,
                       const Eigen::Vector3d& p1, double max_vel_mps, double max_acc_mps2) {
  const double dist = (p1 - p0).norm();
  // Peak speed and acceleration of the rest-to-rest quintic: 15/8 D/T and 10/sqrt(3) D/T^2.
  double t = std::max({1.875 * dist / max_vel_mps, std::sqrt(5.773502691896258 * dist / max_acc_mps2), 0.2});
  // A start already beyond a limit cannot be fixed by slowing down: allow it, do not make it worse.
  const double vel_lim = std::max(max_vel_mps, v0.norm()) * (1.0 + 1e-6);
  const double acc_lim = std::max(max_acc_mps2, a0.norm()) * (1.0 + 1e-6);
  for (int i = 0; i < 200; ++i) {
    const MinJerkSegment seg(p0, v0, a0, p1, t);
    if (seg.MaxSpeed() <= vel_lim && seg.MaxAccel() <= acc_lim) break;
    t *= 1.05;
  }
  return t;
}

LineTracker::LineTracker(const LineTrackerConfig& config) : config_(config) { config_.Validate(); }

void LineTracker::Activate(const PositionReference& last_ref, const quad_core::VehicleState& /*state*/) {
  last_ref_ = last_ref;
  active_ = true;
  moving_ = false;
  completed_ = false;
  if (!pending_) last_ref_ = PositionReference::Hold(last_ref.p_world, last_ref.yaw_rad);
}

void LineTracker::Deactivate() {
  active_ = false;
  moving_ = false;
  completed_ = false;
  pending_.reset();
}

TrackerStatus LineTracker::status() const {
  if (!active_) return TrackerStatus::kInactive;
  if (moving_ || pending_) return TrackerStatus::kTracking;
  return completed_ ? TrackerStatus::kSucceeded : TrackerStatus::kHolding;
}

std::string LineTracker::ValidateGoal(const Eigen::Vector3d& p_goal_world, double yaw_goal_rad,
                                      double max_vel_mps, double max_acc_mps2) {
  if (!p_goal_world.allFinite()) return "goal position is not finite";
  if (!std::isfinite(yaw_goal_rad)) return "goal yaw is not finite";
  if (!std::isfinite(max_vel_mps) || !std::isfinite(max_acc_mps2))
    return "velocity/acceleration limit not finite";
  return "";
}

std::string LineTracker::SetGoal(const Eigen::Vector3d& p_goal_world, double yaw_goal_rad, double max_vel_mps,
                                 double max_acc_mps2) {
  const std::string why = ValidateGoal(p_goal_world, yaw_goal_rad, max_vel_mps, max_acc_mps2);
  if (!why.empty()) return why;
  Goal g;
  g.p_world = p_goal_world;
  g.yaw_rad = quad_core::WrapAngle(yaw_goal_rad);
  g.max_vel_mps = max_vel_mps > 0.0 ? max_vel_mps : config_.default_max_vel_mps;
  g.max_acc_mps2 = max_acc_mps2 > 0.0 ? max_acc_mps2 : config_.default_max_acc_mps2;
  pending_ = g;
  return "";
}

PositionReference LineTracker::Update(const quad_core::VehicleState& state) {
  if (pending_) {
    // Plan from the current reference (position, velocity, acceleration): no jump when a goal changes
    // mid-flight.
    const Goal g = *pending_;
    pending_.reset();
    const double t = MinJerkDuration(last_ref_.p_world, last_ref_.v_world, last_ref_.a_world, g.p_world,
                                     g.max_vel_mps, g.max_acc_mps2);
    segment_ = MinJerkSegment(last_ref_.p_world, last_ref_.v_world, last_ref_.a_world, g.p_world, t);
    yaw_start_rad_ = last_ref_.yaw_rad;
    yaw_delta_rad_ = quad_core::WrapAngle(g.yaw_rad - last_ref_.yaw_rad);
    // Rest-to-rest quintic in yaw: peak rate 15/8 |delta| / T.
    yaw_duration_s_ = std::max(t, 1.875 * std::fabs(yaw_delta_rad_) / config_.max_yaw_rate_radps);
    t_start_s_ = state.t_s;
    moving_ = true;
    completed_ = false;
  }
  if (!moving_) return last_ref_;
  const double t = state.t_s - t_start_s_;
  PositionReference r;
  r.p_world = segment_.Eval(t, 0);
  r.v_world = segment_.Eval(t, 1);
  r.a_world = segment_.Eval(t, 2);
  r.j_world = segment_.Eval(t, 3);
  const double tau = std::clamp(t / yaw_duration_s_, 0.0, 1.0);
  const double s = tau * tau * tau * (10.0 - 15.0 * tau + 6.0 * tau * tau);
  const double s_dot = 30.0 * tau * tau * (1.0 - tau) * (1.0 - tau) / yaw_duration_s_;
  r.yaw_rad = quad_core::WrapAngle(yaw_start_rad_ + yaw_delta_rad_ * s);
  r.yaw_rate_radps = yaw_delta_rad_ * s_dot;
  if (t >= std::max(segment_.duration_s(), yaw_duration_s_)) {
    moving_ = false;
    completed_ = true;
    r = PositionReference::Hold(segment_.Eval(segment_.duration_s(), 0), yaw_start_rad_ + yaw_delta_rad_);
  }
  last_ref_ = r;
  return r;
}

}  // namespace kr_tracker
