#include "kr_tracker/tracker_manager.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

namespace kr_tracker {

TrackerManager::TrackerManager(const TrackerConfig& config, double mass_kg, double gravity_mps2,
                               double max_thrust_N)
    : config_(config),
      controller_(config.gains, mass_kg, gravity_mps2, max_thrust_N),
      line_(config.line),
      bspline_(config.bspline) {
  if (!Find(config_.initial_tracker)) {
    throw std::invalid_argument("TrackerManager: initial_tracker '" + config_.initial_tracker +
                                "' is not one of hover, line, bspline");
  }
  if (!(config_.max_odom_jump_m > 0.0)) {
    throw std::invalid_argument(
        "TrackerManager: max_odom_jump_m = " + std::to_string(config_.max_odom_jump_m) + " must be > 0");
  }
  safe_command_ = controller_.HoverCommand(0.0);
}

Tracker* TrackerManager::Find(const std::string& name) {
  if (name == "hover") return &hover_;
  if (name == "line") return &line_;
  if (name == "bspline") return &bspline_;
  return nullptr;
}

ControlStep TrackerManager::OnOdometry(const quad_core::VehicleState& state) {
  ControlStep step;
  if (!state.AllFinite()) {
    // Hold: the hover command at the last good reference's yaw, and that reference's pose held (zero
    // derivatives: a reference still moving would not be what the hover command does; issue 30).
    step.command = safe_command_;
    step.ref = PositionReference::Hold(last_ref_.p_world, last_ref_.yaw_rad);
    step.status = ControlStatus::kNonFiniteInput;
    step.odometry_skipped = true;
    return step;
  }
  double dt = 0.0;
  if (!have_odom_) {
    // Start-up: hold the first odometry's position and yaw with the initial tracker.
    ReAnchor(state, "");
    reanchor_count_ = 0;
  } else if (reset_pending_ && state.t_s >= reset_start_s_) {
    step.reanchored = reset_reason_;
    ReAnchor(state, reset_reason_);
  } else if (const double jump = (state.p_world_body - last_state_.p_world_body).norm();
             jump > config_.max_odom_jump_m) {
    std::ostringstream s;
    s << "odometry jump of " << jump << " m in one step (limit " << config_.max_odom_jump_m << " m)";
    step.reanchored = s.str();
    ReAnchor(state, step.reanchored);
  } else {
    dt = std::clamp(state.t_s - last_state_.t_s, 0.0, 0.1);
  }
  // A B-spline goal takes over at the first odometry after its start_time (as BsplineTracker replaces a
  // running goal), not when it arrives: which odometry message a goal arrives before depends on message
  // timing, so switching on arrival would make a lockstepped flight depend on it.
  if (bspline_switch_at_s_ && state.t_s > *bspline_switch_at_s_) {
    bspline_switch_at_s_.reset();
    if (active_ != &bspline_) SwitchTo(&bspline_);
  }
  last_state_ = state;
  step.ref = active_->Update(state);
  const ControlOutput out = controller_.Compute(step.ref, state, dt);
  step.command = out.command;
  step.status = out.status;
  if (out.status == ControlStatus::kOk) {
    last_ref_ = step.ref;
    safe_command_ = controller_.HoverCommand(step.ref.yaw_rad);
  }
  return step;
}

std::string TrackerManager::OnEpisodeStatus(uint32_t episode_id, double start_time_s) {
  if (!episode_id_) {
    // The first status only tells which episode the tracker started in: the first odometry anchors it.
    episode_id_ = episode_id;
    return "";
  }
  if (*episode_id_ == episode_id) return "";
  episode_id_ = episode_id;
  const std::string reason = "episode reset (episode " + std::to_string(episode_id) + " started)";
  if (!have_odom_) return "";  // nothing anchored yet: the first odometry will be the new episode's
  // Without a usable start time the next odometry is taken as the new episode's first one.
  if (!std::isfinite(start_time_s) || !(start_time_s > 0.0)) {
    start_time_s = std::nextafter(last_state_.t_s, std::numeric_limits<double>::infinity());
  }
  std::ostringstream s;
  if (anchor_stamp_s_ >= start_time_s) {
    // The odometry-jump check already re-anchored on this episode's odometry; what was requested since then
    // belongs to the new episode.
    s << "episode " << episode_id << ": already re-anchored on its odometry at t = " << anchor_stamp_s_
      << " s";
    return s.str();
  }
  bspline_.AbortAll(reason);
  if (last_state_.t_s >= start_time_s) {
    ReAnchor(last_state_, reason);
    s << "episode " << episode_id << ": re-anchored at once on its odometry at t = " << last_state_.t_s
      << " s";
    return s.str();
  }
  reset_pending_ = true;
  reset_start_s_ = start_time_s;
  reset_reason_ = reason;
  deferred_.clear();  // requests queued for an earlier reset that never got its odometry are stale
  s << "episode " << episode_id
    << ": B-spline goals aborted; re-anchoring on the first odometry at t >= " << start_time_s << " s";
  return s.str();
}

void TrackerManager::ReAnchor(const quad_core::VehicleState& state, const std::string& reason) {
  bspline_.AbortAll(reason.empty() ? "re-anchored" : reason);
  bspline_switch_at_s_.reset();
  // Deactivating every tracker drops the line tracker's goal and profile and the B-spline tracker's state
  // (its direction-of-travel yaw limiter restarts from the new reference when it is activated again).
  hover_.Deactivate();
  line_.Deactivate();
  bspline_.Deactivate();
  controller_.ResetIntegral();
  have_odom_ = true;
  last_state_ = state;
  last_ref_ = PositionReference::Hold(state.p_world_body, state.Yaw());
  safe_command_ = controller_.HoverCommand(last_ref_.yaw_rad);
  active_ = Find(config_.initial_tracker);
  active_->Activate(last_ref_, state);
  anchor_stamp_s_ = state.t_s;
  reset_pending_ = false;
  ++reanchor_count_;
  std::vector<Deferred> deferred;
  deferred.swap(deferred_);
  for (const Deferred& d : deferred) {
    // Both were validated when they were queued; a switch to a known tracker and a valid goto cannot fail
    // now.
    if (d.is_goto) {
      GotoNow(d.p_world, d.yaw_rad, d.max_vel_mps, d.max_acc_mps2);
    } else {
      SwitchTo(Find(d.tracker));
    }
  }
}

std::string TrackerManager::SwitchTo(Tracker* next) {
  if (next == active_) return "";
  active_->Deactivate();
  next->Activate(last_ref_, last_state_);
  active_ = next;
  return "";
}

std::string TrackerManager::Switch(const std::string& tracker, bool* deferred) {
  if (deferred) *deferred = false;
  Tracker* next = Find(tracker);
  if (!next) return "unknown tracker '" + tracker + "' (hover, line, bspline)";
  if (!have_odom_) return "no odometry received yet";
  if (reset_pending_) {
    Deferred d;
    d.tracker = tracker;
    deferred_.push_back(d);
    if (deferred) *deferred = true;
    return "";
  }
  bspline_switch_at_s_.reset();  // an explicit switch overrides a pending auto-activation
  return SwitchTo(next);
}

std::string TrackerManager::GotoNow(const Eigen::Vector3d& p_world, double yaw_rad, double max_vel_mps,
                                    double max_acc_mps2) {
  const std::string why = line_.SetGoal(p_world, yaw_rad, max_vel_mps, max_acc_mps2);
  if (!why.empty()) return why;
  bspline_switch_at_s_.reset();  // a goto overrides a pending auto-activation
  return SwitchTo(&line_);
}

std::string TrackerManager::Goto(const Eigen::Vector3d& p_world, double yaw_rad, double max_vel_mps,
                                 double max_acc_mps2, bool* deferred) {
  if (deferred) *deferred = false;
  if (!have_odom_) return "no odometry received yet";
  const std::string why = LineTracker::ValidateGoal(p_world, yaw_rad, max_vel_mps, max_acc_mps2);
  if (!why.empty()) return why;
  if (reset_pending_) {
    Deferred d;
    d.is_goto = true;
    d.p_world = p_world;
    d.yaw_rad = yaw_rad;
    d.max_vel_mps = max_vel_mps;
    d.max_acc_mps2 = max_acc_mps2;
    deferred_.push_back(d);
    if (deferred) *deferred = true;
    return "";
  }
  return GotoNow(p_world, yaw_rad, max_vel_mps, max_acc_mps2);
}

std::string TrackerManager::AddGoal(uint64_t goal_id, const BsplineGoalSpec& spec, double now_s) {
  if (!have_odom_) return "no odometry received yet";
  if (reset_pending_) {
    return reset_reason_ +
           " in progress: the vehicle's position in the new episode is not known yet "
           "(waiting for its first odometry)";
  }
  const std::string why = bspline_.AddGoal(goal_id, spec, now_s, last_state_);
  if (!why.empty()) return why;
  if (config_.bspline_auto_activate && active_ != &bspline_) {
    bspline_switch_at_s_ =
        bspline_switch_at_s_ ? std::min(*bspline_switch_at_s_, spec.start_time_s) : spec.start_time_s;
  }
  return "";
}

bool TrackerManager::Cancel(uint64_t goal_id) { return bspline_.Cancel(goal_id); }

}  // namespace kr_tracker
