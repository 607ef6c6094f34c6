#include "kr_tracker/bspline_tracker.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace kr_tracker {

void BsplineTrackerConfig::Validate() const {
  auto check = [](double v, bool ok, const char* name, const char* req) {
    if (!ok || !std::isfinite(v)) {
      std::ostringstream s;
      s << "BsplineTrackerConfig: " << name << " = " << v << " must be " << req;
      throw std::invalid_argument(s.str());
    }
  };
  check(max_start_delay_s, max_start_delay_s >= 0.0, "max_start_delay_s", ">= 0");
  check(max_start_age_s, max_start_age_s >= 0.0, "max_start_age_s", ">= 0");
  check(max_start_error_m, max_start_error_m > 0.0, "max_start_error_m", "> 0");
  check(max_yaw_rate_radps, max_yaw_rate_radps > 0.0, "max_yaw_rate_radps", "> 0");
  check(min_speed_for_yaw_mps, min_speed_for_yaw_mps >= 0.0, "min_speed_for_yaw_mps", ">= 0");
}

std::string ValidateGoalSpec(const BsplineGoalSpec& spec) {
  if (spec.pos_pts.cols() != 3) {
    return "position control points have " + std::to_string(spec.pos_pts.cols()) + " columns, expected 3";
  }
  const std::string why = quad_core::ValidateBspline(spec.order, spec.knots, spec.pos_pts);
  if (!why.empty()) return "position B-spline: " + why;
  if (!std::isfinite(spec.start_time_s)) return "start_time is not finite";
  if (!std::isfinite(spec.yaw_dt_s)) return "yaw_dt is not finite";
  if (!spec.yaw_pts.empty()) {
    for (size_t i = 0; i < spec.yaw_pts.size(); ++i) {
      if (!std::isfinite(spec.yaw_pts[i])) return "yaw point " + std::to_string(i) + " is not finite";
    }
    if (!(spec.yaw_dt_s > 0.0)) {
      return "yaw_dt = " + std::to_string(spec.yaw_dt_s) + " must be > 0 when yaw points are given";
    }
    if (static_cast<int>(spec.yaw_pts.size()) < spec.order + 1) {
      return std::to_string(spec.yaw_pts.size()) +
             " yaw points are fewer than order + 1 = " + std::to_string(spec.order + 1);
    }
  }
  return "";
}

const char* ToString(GoalEventKind kind) {
  switch (kind) {
    case GoalEventKind::kStarted:
      return "started";
    case GoalEventKind::kSucceeded:
      return "succeeded";
    case GoalEventKind::kReplaced:
      return "replaced";
    case GoalEventKind::kCanceled:
      return "canceled";
    case GoalEventKind::kAborted:
      return "aborted";
  }
  return "unknown";
}

BsplineTracker::BsplineTracker(const BsplineTrackerConfig& config) : config_(config) { config_.Validate(); }

BsplineTracker::Goal BsplineTracker::MakeGoal(uint64_t id, const BsplineGoalSpec& spec) {
  const quad_core::NonUniformBspline pos(spec.pos_pts, spec.order, spec.knots);
  // Derivatives of a degree-p spline beyond p are zero: Derivative() handles degree 0 that way.
  const quad_core::NonUniformBspline vel = pos.Derivative();
  const quad_core::NonUniformBspline acc = vel.Derivative();
  Goal g{id, spec.traj_id, spec.start_time_s, pos, vel, acc, acc.Derivative(), std::nullopt, std::nullopt};
  if (!spec.yaw_pts.empty()) {
    const Eigen::MatrixXd yaw_pts = Eigen::Map<const Eigen::VectorXd>(
        spec.yaw_pts.data(), static_cast<Eigen::Index>(spec.yaw_pts.size()));
    g.yaw = quad_core::NonUniformBspline::Uniform(yaw_pts, spec.order, spec.yaw_dt_s, 0.0);
    g.yaw_rate = g.yaw->Derivative();
  }
  return g;
}

void BsplineTracker::Activate(const PositionReference& last_ref, const quad_core::VehicleState& state) {
  last_ref_ = PositionReference::Hold(last_ref.p_world, last_ref.yaw_rad);
  active_ = true;
  completed_ = false;
  last_state_ = state;
  has_last_state_ = true;
}

void BsplineTracker::Deactivate() {
  const double t = has_last_state_ ? last_state_.t_s : 0.0;
  if (running_) EndRunning(GoalEventKind::kAborted, t, "tracker deactivated (switched to another tracker)");
  if (pending_) {
    events_.push_back({pending_->id, GoalEventKind::kAborted, 0.0, 0.0,
                       "tracker deactivated (switched to another tracker) before the goal started"});
    pending_.reset();
  }
  active_ = false;
  completed_ = false;
}

TrackerStatus BsplineTracker::status() const {
  if (!active_) return TrackerStatus::kInactive;
  if (running_ || pending_) return TrackerStatus::kTracking;
  return completed_ ? TrackerStatus::kSucceeded : TrackerStatus::kHolding;
}

std::string BsplineTracker::AddGoal(uint64_t goal_id, const BsplineGoalSpec& spec, double now_s,
                                    const quad_core::VehicleState& state) {
  std::string why = ValidateGoalSpec(spec);
  if (!why.empty()) return why;
  std::ostringstream s;
  if (spec.start_time_s > now_s + config_.max_start_delay_s) {
    s << "start_time is " << spec.start_time_s - now_s << " s in the future (limit "
      << config_.max_start_delay_s << " s)";
    return s.str();
  }
  if (spec.start_time_s < now_s - config_.max_start_age_s) {
    s << "start_time is " << now_s - spec.start_time_s << " s in the past (limit " << config_.max_start_age_s
      << " s)";
    return s.str();
  }
  Goal g = MakeGoal(goal_id, spec);
  const double tau = std::max(0.0, now_s - spec.start_time_s);
  if (tau >= g.pos.duration()) {
    s << "the trajectory (duration " << g.pos.duration() << " s) ends before now";
    return s.str();
  }
  if (state.p_world_body.allFinite()) {
    const double err = (g.pos.Evaluate(g.pos.tmin() + tau) - state.p_world_body).norm();
    if (err > config_.max_start_error_m) {
      s << "the trajectory's position at its start is " << err << " m from the vehicle (limit "
        << config_.max_start_error_m << " m)";
      return s.str();
    }
  }
  if (pending_) {
    events_.push_back({pending_->id, GoalEventKind::kReplaced, 0.0, 0.0,
                       "replaced before its start by goal " + std::to_string(goal_id) + " (traj_id " +
                           std::to_string(spec.traj_id) + ")"});
  }
  pending_ = std::move(g);
  return "";
}

bool BsplineTracker::Cancel(uint64_t goal_id) {
  if (running_ && running_->id == goal_id) {
    EndRunning(GoalEventKind::kCanceled, has_last_state_ ? last_state_.t_s : 0.0, "canceled by the client");
    last_ref_ = Hold();
    return true;
  }
  if (pending_ && pending_->id == goal_id) {
    events_.push_back(
        {goal_id, GoalEventKind::kCanceled, 0.0, 0.0, "canceled by the client before its start"});
    pending_.reset();
    return true;
  }
  return false;
}

void BsplineTracker::AbortAll(const std::string& reason) {
  if (running_) {
    EndRunning(GoalEventKind::kAborted, has_last_state_ ? last_state_.t_s : 0.0, reason);
    last_ref_ = Hold();
  }
  if (pending_) {
    events_.push_back(
        {pending_->id, GoalEventKind::kAborted, 0.0, 0.0, reason + " (before the goal started)"});
    pending_.reset();
  }
  completed_ = false;
}

std::vector<GoalEvent> BsplineTracker::TakeEvents() {
  std::vector<GoalEvent> out;
  out.swap(events_);
  return out;
}

std::optional<uint64_t> BsplineTracker::running_goal() const {
  if (!running_) return std::nullopt;
  return running_->id;
}

double BsplineTracker::RemainingTime(double t_s) const {
  if (!running_) return 0.0;
  return std::max(0.0, running_->start_time_s + running_->pos.duration() - t_s);
}

void BsplineTracker::EndRunning(GoalEventKind kind, double t_s, const std::string& reason) {
  events_.push_back(
      {running_->id, kind, std::max(0.0, t_s - running_->start_time_s), running_->distance_m, reason});
  running_.reset();
}

PositionReference BsplineTracker::Hold() const {
  return PositionReference::Hold(last_ref_.p_world, last_ref_.yaw_rad);
}

double BsplineTracker::DirectionOfTravelYaw(const Eigen::Vector3d& v_world, double dt_s,
                                            double* yaw_rate_radps) {
  *yaw_rate_radps = 0.0;
  const double current = last_ref_.yaw_rad;
  if (v_world.head<2>().norm() < config_.min_speed_for_yaw_mps || !(dt_s > 0.0)) return current;
  const double desired = std::atan2(v_world.y(), v_world.x());
  const double max_step = config_.max_yaw_rate_radps * dt_s;
  const double step = std::clamp(quad_core::WrapAngle(desired - current), -max_step, max_step);
  *yaw_rate_radps = step / dt_s;
  return quad_core::WrapAngle(current + step);
}

PositionReference BsplineTracker::Update(const quad_core::VehicleState& state) {
  const double t = state.t_s;
  const double dt = has_last_state_ ? t - last_state_.t_s : 0.0;
  const Eigen::Vector3d p_prev = has_last_state_ ? last_state_.p_world_body : state.p_world_body;
  last_state_ = state;
  has_last_state_ = true;

  // Strictly after start_time: a goal starting exactly at this odometry's stamp may arrive before or after it
  // was processed; either way it takes over at the next one.
  if (pending_ && t > pending_->start_time_s) {
    if (running_) {
      EndRunning(GoalEventKind::kReplaced, t,
                 "replaced by goal " + std::to_string(pending_->id) + " (traj_id " +
                     std::to_string(pending_->traj_id) + ") at its start_time");
    }
    running_ = std::move(pending_);
    pending_.reset();
    running_->started = true;
    completed_ = false;
    events_.push_back({running_->id, GoalEventKind::kStarted, 0.0, 0.0, ""});
  }
  if (!running_) return last_ref_;

  Goal& g = *running_;
  g.distance_m += (state.p_world_body - p_prev).norm();
  const double tau = std::max(0.0, t - g.start_time_s);
  const double u = g.pos.tmin() + std::min(tau, g.pos.duration());
  PositionReference r;
  r.p_world = g.pos.Evaluate(u);
  if (tau < g.pos.duration()) {
    r.v_world = g.vel.Evaluate(u);
    r.a_world = g.acc.Evaluate(u);
    r.j_world = g.jerk.Evaluate(u);
  }
  if (g.yaw) {
    r.yaw_rad = quad_core::WrapAngle(g.yaw->Evaluate(tau)(0));
    r.yaw_rate_radps = tau < g.yaw->tmax() ? g.yaw_rate->Evaluate(tau)(0) : 0.0;
  } else {
    r.yaw_rad = DirectionOfTravelYaw(r.v_world, dt, &r.yaw_rate_radps);
  }
  if (tau >= g.pos.duration()) {
    EndRunning(GoalEventKind::kSucceeded, t, "");
    completed_ = true;
    r.yaw_rate_radps = 0.0;
  }
  last_ref_ = r;
  return r;
}

}  // namespace kr_tracker
