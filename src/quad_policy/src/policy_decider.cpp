#include "quad_policy/policy_decider.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <utility>

namespace quad_policy {

const char* ToString(RefusalAction action) { return action == RefusalAction::kHover ? "hover" : "stop"; }

const UniformBspline* Decision::to_send() const {
  if (kept) return nullptr;
  if (final_approach) return &*final_approach;
  if (recovery) return &*recovery;
  if (accepted()) return &proposed;
  return stop ? &*stop : nullptr;
}

std::string RecoveryText(const Decision& d, int num_hypotheses) {
  // Hypotheses are numbered from 1 in the text (index + 1).
  if (!d.recovery) return "";
  const char* what = d.steered ? "steered" : "recovered";
  char buf[160];
  if (num_hypotheses == 1) {
    std::snprintf(buf, sizeof(buf), "; %s with the goal turned %g deg", what, d.recovery_yaw_deg);
  } else if (d.recovery_yaw_deg == 0.0) {
    std::snprintf(buf, sizeof(buf), "; %s with hypothesis %d of %d", what, d.recovery_hypothesis + 1,
                  num_hypotheses);
  } else {
    std::snprintf(buf, sizeof(buf), "; %s with the goal turned %g deg, hypothesis %d of %d", what,
                  d.recovery_yaw_deg, d.recovery_hypothesis + 1, num_hypotheses);
  }
  return buf;
}

Eigen::Vector3d TurnedGoal(const Eigen::Vector3d& p_world_body, const Eigen::Vector3d& goal_world,
                           double yaw_deg) {
  const double a = yaw_deg * M_PI / 180.0;
  const double c = std::cos(a), s = std::sin(a);
  const Eigen::Vector3d d = goal_world - p_world_body;
  return p_world_body + Eigen::Vector3d(c * d.x() - s * d.y(), s * d.x() + c * d.y(), d.z());
}

namespace {

double MsSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

void ValidateRefusal(const RefusalConfig& r) {
  if (!(std::isfinite(r.stop_max_decel_mps2) && r.stop_max_decel_mps2 > 0.0)) {
    throw std::invalid_argument("refusal.stop_max_decel_mps2 must be > 0");
  }
  if (!(std::isfinite(r.stop_min_duration_s) && r.stop_min_duration_s > 0.0)) {
    throw std::invalid_argument("refusal.stop_min_duration_s must be > 0");
  }
}

}  // namespace

void ValidateRecoveryConfig(const RecoveryConfig& r) {
  if (r.goal_yaw_offsets_deg.size() > 16) {
    throw std::invalid_argument("recovery.goal_yaw_offsets_deg has " +
                                std::to_string(r.goal_yaw_offsets_deg.size()) + " angles, at most 16");
  }
  for (double a : r.goal_yaw_offsets_deg) {
    if (!(std::isfinite(a) && a >= -180.0 && a <= 180.0 && a != 0.0)) {
      throw std::invalid_argument(
          "recovery.goal_yaw_offsets_deg: angles must be finite, non-zero and within [-180, 180] degrees, "
          "got " +
          std::to_string(a));
    }
  }
  if (!(std::isfinite(r.steer_clearance_m) && r.steer_clearance_m >= 0.0)) {
    throw std::invalid_argument("recovery.steer_clearance_m must be >= 0 (0: off), got " +
                                std::to_string(r.steer_clearance_m));
  }
  if (r.turn_after_stops < 0) {
    throw std::invalid_argument("recovery.turn_after_stops must be >= 0 (0: off), got " +
                                std::to_string(r.turn_after_stops));
  }
  if (!(std::isfinite(r.turn_clearance_m) && r.turn_clearance_m >= 0.0)) {
    throw std::invalid_argument("recovery.turn_clearance_m must be >= 0 (0: no back-off), got " +
                                std::to_string(r.turn_clearance_m));
  }
  if (!(std::isfinite(r.turn_rate_dps) && r.turn_rate_dps > 0.0 && r.turn_rate_dps <= 180.0)) {
    throw std::invalid_argument("recovery.turn_rate_dps must be within (0, 180] deg/s, got " +
                                std::to_string(r.turn_rate_dps));
  }
  if (!(std::isfinite(r.final_approach_m) && r.final_approach_m >= 0.0)) {
    throw std::invalid_argument("recovery.final_approach_m must be >= 0 (0: off), got " +
                                std::to_string(r.final_approach_m));
  }
  if (!(std::isfinite(r.final_approach_acc_mps2) && r.final_approach_acc_mps2 > 0.0)) {
    throw std::invalid_argument("recovery.final_approach_acc_mps2 must be > 0, got " +
                                std::to_string(r.final_approach_acc_mps2));
  }
}

void ValidateRecoveryConfig(const RecoveryConfig& r, const SafetyConfig& safety) {
  ValidateRecoveryConfig(r);
  if (r.steer_clearance_m == 0.0) return;
  if (!(r.steer_clearance_m > safety.vehicle_radius_m)) {
    throw std::invalid_argument("recovery.steer_clearance_m (" + std::to_string(r.steer_clearance_m) +
                                ") must be 0 (off) or greater than safety.vehicle_radius_m (" +
                                std::to_string(safety.vehicle_radius_m) + ")");
  }
  if (r.goal_yaw_offsets_deg.empty()) {
    throw std::invalid_argument(
        "recovery.steer_clearance_m is set but recovery.goal_yaw_offsets_deg is empty: no turns to steer by");
  }
}

void ValidateTurning(const RecoveryConfig& r, const RefusalConfig& refusal) {
  if (r.turn_after_stops > 0 && refusal.action != RefusalAction::kStop) {
    throw std::invalid_argument(
        "recovery.turn_after_stops is set but refusal.action is not 'stop' (the turn rides on the stopping "
        "trajectory)");
  }
}

void ValidateKeeping(const KeepingConfig& k) {
  if (!(std::isfinite(k.commit_s) && k.commit_s >= 0.0)) {
    throw std::invalid_argument("keeping.commit_s must be finite and >= 0 (0: off), got " +
                                std::to_string(k.commit_s));
  }
}

PolicyDecider::PolicyDecider(std::shared_ptr<const TorchPolicy> policy, const SafetyConfig& safety,
                             const RefusalConfig& refusal, const RecoveryConfig& recovery,
                             const KeepingConfig& keeping)
    : policy_(std::move(policy)),
      safety_(safety),
      refusal_(refusal),
      recovery_(recovery),
      keeping_(keeping),
      decoder_(policy_ ? policy_->meta() : throw std::invalid_argument("PolicyDecider needs a policy")) {
  ValidateSafetyConfig(safety_);
  ValidateRefusal(refusal_);
  ValidateRecoveryConfig(recovery_, safety_);
  ValidateTurning(recovery_, refusal_);
  ValidateKeeping(keeping_);
  memory_ = DepthMemory(safety_.memory_frames, safety_.memory_spacing_s);
}

void PolicyDecider::Reset() {
  EndStops();
  memory_.Clear();
  sent_.reset();
}

void PolicyDecider::EndStops() {
  stops_in_row_ = 0;
  turn_sign_ = 0;
}

Decision PolicyDecider::Decide(const DecisionInputs& in) {
  if (!std::isfinite(in.stamp_s)) throw std::invalid_argument("depth stamp is not finite");
  if (in.depth.data == nullptr || in.depth.width <= 0 || in.depth.height <= 0) {
    throw std::invalid_argument("depth image is empty");
  }
  const PolicyMeta& meta = policy_->meta();
  Decision d;
  auto t0 = std::chrono::steady_clock::now();
  d.depth_x = PreprocessDepth(in.depth, meta.input_height, meta.input_width, meta.max_depth_m);
  d.state_x = EncodeState(in.state, in.goal_world, meta);  // throws on non-finite odometry or goal
  d.timings.preprocess_ms = MsSince(t0);

  t0 = std::chrono::steady_clock::now();
  d.y = policy_->Run(d.depth_x, d.state_x, in.state, in.goal_world);
  d.timings.forward_ms = MsSince(t0);

  t0 = std::chrono::steady_clock::now();
  const std::vector<HypothesisPlan> plans = OrderedPlans(d.y, meta);
  d.proposed = PolicyTrajectory(decoder_.Decode(plans.front().y, in.state), meta, in.stamp_s);
  d.proposed_hypothesis = plans.front().index;
  d.timings.decode_ms = MsSince(t0);

  t0 = std::chrono::steady_clock::now();
  const std::vector<DepthFrame>& mem = memory_.frames();  // earlier frames; this one is added at the end
  d.safety = CheckTrajectory(d.proposed, in.state.p_world_body, &in.depth, in.camera, safety_, mem);
  // The rest of the plan sent before, judged at most once per decision (KeepingConfig).
  std::optional<bool> rest_clear;
  const auto rest_is_clear = [&]() {
    if (!rest_clear) {
      rest_clear =
          RestIsClear(*sent_, in.stamp_s, std::max(safety_.check_horizon_s, refusal_.stop_min_duration_s),
                      in.state.p_world_body, in.depth, in.camera, safety_, mem);
    }
    return *rest_clear;
  };
  // A committed plan is flown on while it is younger than commit_s and its rest is clear: nothing else is
  // tried (the network's plan is still computed, for the record and the timings).
  if (keeping_.commit_s > 0.0 && sent_ && in.stamp_s - sent_->start_time_s < keeping_.commit_s &&
      rest_is_clear()) {
    d.kept = sent_;
    d.committed = true;
  }
  if (!d.kept && (in.goal_world - in.state.p_world_body).norm() < recovery_.final_approach_m) {  // 0: off
    std::optional<UniformBspline> traj =
        FinalApproach(in.state.p_world_body, in.state.v_world, in.goal_world,
                      recovery_.final_approach_acc_mps2, refusal_.stop_min_duration_s, in.stamp_s);
    if (traj &&
        CheckTrajectory(*traj, in.state.p_world_body, &in.depth, in.camera, safety_, mem).accepted()) {
      d.final_approach = std::move(traj);
    }
  }
  // A refused proposal is replaced by the first other plan that the safety layer accepts and that stays in
  // view: the policy's other hypotheses (most confident first, no extra forward pass), then for each turned
  // goal its hypotheses. Steering: an accepted proposal that comes nearer than steer_clearance_m to what the
  // depth frame shows is replaced by the first such plan that, besides, keeps steer_clearance_m. (The wider
  // sphere skips the samples it holds the camera in, so it adds to the safety layer's test, never replaces
  // it.)
  SafetyConfig steer = safety_;
  steer.vehicle_radius_m = recovery_.steer_clearance_m;
  const bool steering =
      d.accepted() && recovery_.steer_clearance_m > 0.0 &&
      !CheckTrajectory(d.proposed, in.state.p_world_body, &in.depth, in.camera, steer, mem).accepted();
  if (!d.kept && !d.final_approach && (!d.accepted() || steering)) {
    // Yaw 0 (never a configured turn: those are non-zero) stands for the goal itself.
    std::vector<double> yaws{0.0};
    yaws.insert(yaws.end(), recovery_.goal_yaw_offsets_deg.begin(), recovery_.goal_yaw_offsets_deg.end());
    for (double yaw : yaws) {
      std::vector<HypothesisPlan> alternatives;
      if (yaw == 0.0) {
        alternatives.assign(plans.begin() + 1, plans.end());
      } else {
        ++d.recovery_tries;
        const Eigen::Vector3d goal = TurnedGoal(in.state.p_world_body, in.goal_world, yaw);
        alternatives =
            OrderedPlans(policy_->Run(d.depth_x, EncodeState(in.state, goal, meta), in.state, goal), meta);
      }
      for (const HypothesisPlan& plan : alternatives) {
        UniformBspline traj = PolicyTrajectory(decoder_.Decode(plan.y, in.state), meta, in.stamp_s);
        if (CheckTrajectory(traj, in.state.p_world_body, &in.depth, in.camera, safety_, mem).accepted() &&
            (!steering ||
             CheckTrajectory(traj, in.state.p_world_body, &in.depth, in.camera, steer, mem).accepted()) &&
            TrajectoryInView(traj, in.camera, safety_, mem)) {
          d.recovery = std::move(traj);
          d.recovery_yaw_deg = yaw;
          d.recovery_hypothesis = plan.index;
          d.steered = steering;
          break;
        }
      }
      if (d.recovery) break;
    }
  }
  // Keeping the plan on a refusal: not recovered, the tracker flies on along the trajectory sent before while
  // its rest from now on passes the test a recovery plan passes.
  if (keeping_.on_refusal && !d.kept && !d.accepted() && !d.recovery && !d.final_approach && sent_ &&
      rest_is_clear()) {
    d.kept = sent_;
  }
  if (!d.accepted() && !d.recovery && !d.final_approach && !d.kept &&
      refusal_.action == RefusalAction::kStop) {
    ++stops_in_row_;
    if (recovery_.turn_after_stops > 0 && stops_in_row_ >= recovery_.turn_after_stops) {
      const Eigen::Matrix3d R = in.state.q_world_body.normalized().toRotationMatrix();
      const double yaw = std::atan2(R(1, 0), R(0, 0));
      if (turn_sign_ == 0) {
        // Towards the side the goal lies on (left when straight ahead or behind).
        const Eigen::Vector3d to_goal = in.goal_world - in.state.p_world_body;
        const double bearing = std::remainder(std::atan2(to_goal.y(), to_goal.x()) - yaw, 2.0 * M_PI);
        turn_sign_ = bearing < 0.0 ? -1 : 1;
      }
      d.turn_rate_radps = turn_sign_ * recovery_.turn_rate_dps * M_PI / 180.0;
      // Room to turn: back away from a surface nearer than turn_clearance_m.
      d.turn_backoff_m = std::max(0.0, recovery_.turn_clearance_m - NearestDepth(in.depth));
      const Eigen::Vector3d backoff = -d.turn_backoff_m * Eigen::Vector3d(std::cos(yaw), std::sin(yaw), 0.0);
      d.stop = TurningStop(in.state.p_world_body, in.state.v_world, backoff, yaw, d.turn_rate_radps,
                           refusal_.stop_max_decel_mps2, refusal_.stop_min_duration_s, in.stamp_s);
    } else {
      d.stop = BrakingTrajectory(in.state.p_world_body, in.state.v_world, refusal_.stop_max_decel_mps2,
                                 refusal_.stop_min_duration_s, in.stamp_s);
    }
  } else {
    EndStops();
  }
  memory_.Add(in.stamp_s, in.depth, in.camera);
  // The plan the tracker now flies; a stopping trajectory is never kept (the next refusal stops anew).
  if (!d.kept) {
    const UniformBspline* sent = d.to_send();
    if (sent != nullptr && !(d.stop && sent == &*d.stop)) {
      sent_ = *sent;
    } else {
      sent_.reset();
    }
  }
  d.timings.safety_ms = MsSince(t0);
  counts_.Add(d.safety.verdict);
  return d;
}

}  // namespace quad_policy
