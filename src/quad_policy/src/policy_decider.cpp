#include "quad_policy/policy_decider.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <utility>

namespace quad_policy {

const char* ToString(RefusalAction action) { return action == RefusalAction::kHover ? "hover" : "stop"; }

SentKind Decision::sent_kind() const {
  if (kept) return committed ? SentKind::kCommitted : SentKind::kKept;
  if (final_approach) return SentKind::kFinalApproach;
  if (recovery) return SentKind::kRecovery;
  if (accepted()) return SentKind::kPolicy;
  return stop ? SentKind::kStop : SentKind::kNothing;
}

const UniformBspline* Decision::to_send() const {
  switch (sent_kind()) {
    case SentKind::kFinalApproach:
      return &*final_approach;
    case SentKind::kRecovery:
      return &*recovery;
    case SentKind::kPolicy:
      return &proposed;
    case SentKind::kStop:
      return &*stop;
    default:
      return nullptr;
  }
}

DecisionSummary Summarize(const Decision& d, int num_hypotheses, double stamp_s) {
  DecisionSummary s;
  s.reason = d.safety.reason;
  char buf[160];
  if (d.recovery) {
    // Hypotheses are numbered from 1 in the text (index + 1).
    if (num_hypotheses == 1) {
      std::snprintf(buf, sizeof(buf), "; recovered with the goal turned %g deg", d.recovery_yaw_deg);
    } else if (d.recovery_yaw_deg == 0.0) {
      std::snprintf(buf, sizeof(buf), "; recovered with hypothesis %d of %d", d.recovery_hypothesis + 1,
                    num_hypotheses);
    } else {
      std::snprintf(buf, sizeof(buf), "; recovered with the goal turned %g deg, hypothesis %d of %d",
                    d.recovery_yaw_deg, d.recovery_hypothesis + 1, num_hypotheses);
    }
    s.reason += buf;
    s.events.push_back("recovered");
  }
  if (d.final_approach) {
    s.reason += "; final approach: straight to the goal (not the network's plan)";
    s.events.push_back("final_approach");
  }
  if (d.kept) {
    std::snprintf(buf, sizeof(buf), "; %s the plan sent %.2f s before (its rest is clear)",
                  d.committed ? "committed to" : "kept", stamp_s - d.kept->start_time_s);
    s.reason += buf;
    s.events.push_back(d.committed ? "committed" : "kept");
  }
  switch (d.sent_kind()) {
    case SentKind::kPolicy:
      s.action = "policy";
      break;
    case SentKind::kStop:
      s.action = "stop";
      break;
    case SentKind::kRecovery:
      s.action = "recovery";
      break;
    case SentKind::kFinalApproach:
      s.action = "final_approach";
      break;
    case SentKind::kKept:
    case SentKind::kCommitted:
      s.action = "keep";  // the tracker flies on along the plan sent before
      break;
    case SentKind::kNothing:
      s.action = "hover";  // refusal action hover
      break;
  }
  return s;
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

void CheckFinite(const Eigen::Vector3d& v, const char* name) {
  if (!v.allFinite()) throw std::invalid_argument(std::string(name) + " has a NaN/Inf element");
}

// The checks of EncodeState and of the depth frame, for a decision whatever runs the network.
void CheckInputs(const DecisionInputs& in) {
  if (!std::isfinite(in.stamp_s)) throw std::invalid_argument("depth stamp is not finite");
  if (in.depth.data == nullptr || in.depth.width <= 0 || in.depth.height <= 0) {
    throw std::invalid_argument("depth image is empty");
  }
  CheckFinite(in.state.p_world_body, "p_world_body");
  CheckFinite(in.state.v_world, "v_world");
  CheckFinite(in.goal_world, "goal_world");
  if (!in.state.q_world_body.coeffs().allFinite()) {
    throw std::invalid_argument("q_world_body has a NaN/Inf element");
  }
  if (in.state.q_world_body.coeffs().squaredNorm() < 1e-24)
    throw std::invalid_argument("q_world_body is zero");
}

}  // namespace

void ValidateRefusal(const RefusalConfig& r) {
  if (!(std::isfinite(r.stop_max_decel_mps2) && r.stop_max_decel_mps2 > 0.0)) {
    throw std::invalid_argument("refusal.stop_max_decel_mps2 must be > 0");
  }
  if (!(std::isfinite(r.stop_min_duration_s) && r.stop_min_duration_s > 0.0)) {
    throw std::invalid_argument("refusal.stop_min_duration_s must be > 0");
  }
}

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
  if (!(std::isfinite(r.final_approach_m) && r.final_approach_m >= 0.0)) {
    throw std::invalid_argument("recovery.final_approach_m must be >= 0 (0: off), got " +
                                std::to_string(r.final_approach_m));
  }
  if (!(std::isfinite(r.final_approach_acc_mps2) && r.final_approach_acc_mps2 > 0.0)) {
    throw std::invalid_argument("recovery.final_approach_acc_mps2 must be > 0, got " +
                                std::to_string(r.final_approach_acc_mps2));
  }
}

void ValidateKeeping(const KeepingConfig& k) {
  if (!(std::isfinite(k.commit_s) && k.commit_s >= 0.0)) {
    throw std::invalid_argument("keeping.commit_s must be finite and >= 0 (0: off), got " +
                                std::to_string(k.commit_s));
  }
}

PolicyDecider::PolicyDecider(const PolicyMeta& meta, const SafetyConfig& safety, const RefusalConfig& refusal,
                             const RecoveryConfig& recovery, const KeepingConfig& keeping)
    : meta_(meta),
      safety_(safety),
      refusal_(refusal),
      recovery_(recovery),
      keeping_(keeping),
      decoder_(meta) {
  ValidateSafetyConfig(safety_);
  ValidateRefusal(refusal_);
  ValidateRecoveryConfig(recovery_);
  ValidateKeeping(keeping_);
}

PolicyDecider::PolicyDecider(std::shared_ptr<const TorchPolicy> policy, const SafetyConfig& safety,
                             const RefusalConfig& refusal, const RecoveryConfig& recovery,
                             const KeepingConfig& keeping)
    : PolicyDecider(policy ? policy->meta() : throw std::invalid_argument("PolicyDecider needs a policy"),
                    safety, refusal, recovery, keeping) {
  policy_ = std::move(policy);
}

const TorchPolicy& PolicyDecider::policy() const {
  if (!policy_) throw std::logic_error("this PolicyDecider has no TorchPolicy (its network runs elsewhere)");
  return *policy_;
}

Decision PolicyDecider::Decide(const DecisionInputs& in) {
  const TorchPolicy& net = policy();
  if (!std::isfinite(in.stamp_s)) throw std::invalid_argument("depth stamp is not finite");
  if (in.depth.data == nullptr || in.depth.width <= 0 || in.depth.height <= 0) {
    throw std::invalid_argument("depth image is empty");
  }
  auto t0 = std::chrono::steady_clock::now();
  std::vector<float> depth_x =
      PreprocessDepth(in.depth, meta_.input_height, meta_.input_width, meta_.max_depth_m);
  const StateVector state_x = EncodeState(in.state, in.goal_world, meta_);  // throws on non-finite input
  const double preprocess_ms = MsSince(t0);
  t0 = std::chrono::steady_clock::now();
  std::vector<float> y = net.Run(depth_x, state_x, in.state, in.goal_world);
  const double forward_ms = MsSince(t0);
  Decision d = Decide(in, std::move(y), [&](const Eigen::Vector3d& goal) {
    return net.Run(depth_x, EncodeState(in.state, goal, meta_), in.state, goal);
  });
  d.depth_x = std::move(depth_x);
  d.state_x = state_x;
  d.timings.preprocess_ms = preprocess_ms;
  d.timings.forward_ms = forward_ms;
  return d;
}

Decision PolicyDecider::Decide(const DecisionInputs& in, std::vector<float> y, const AskNetwork& ask) {
  CheckInputs(in);
  Decision d;
  d.y = std::move(y);
  auto t0 = std::chrono::steady_clock::now();
  const std::vector<HypothesisPlan> plans = OrderedPlans(d.y, meta_);  // throws on a wrong length
  d.proposed = PolicyTrajectory(decoder_.Decode(plans.front().y, in.state), meta_, in.stamp_s);
  d.proposed_hypothesis = plans.front().index;
  d.timings.decode_ms = MsSince(t0);

  t0 = std::chrono::steady_clock::now();
  const auto check = [&](const UniformBspline& traj) {
    return CheckTrajectory(traj, in.state.p_world_body, &in.depth, in.camera, safety_);
  };
  d.safety = check(d.proposed);
  // The rest of the plan sent before, judged at most once per decision (KeepingConfig).
  std::optional<bool> rest_clear;
  const auto rest_is_clear = [&]() {
    if (!rest_clear) {
      rest_clear =
          RestIsClear(*sent_, in.stamp_s, std::max(safety_.check_horizon_s, refusal_.stop_min_duration_s),
                      in.state.p_world_body, in.depth, in.camera, safety_);
    }
    return *rest_clear;
  };
  // 1. A committed plan is flown on while it is younger than commit_s and its rest is clear.
  if (keeping_.commit_s > 0.0 && sent_ && in.stamp_s - sent_->start_time_s < keeping_.commit_s &&
      rest_is_clear()) {
    d.kept = sent_;
    d.committed = true;
  }
  // 2. The final approach (final_approach_m 0: off).
  if (!d.kept && (in.goal_world - in.state.p_world_body).norm() < recovery_.final_approach_m) {
    std::optional<UniformBspline> traj =
        FinalApproach(in.state.p_world_body, in.state.v_world, in.goal_world,
                      recovery_.final_approach_acc_mps2, refusal_.stop_min_duration_s, in.stamp_s);
    if (traj && check(*traj).accepted()) d.final_approach = std::move(traj);
  }
  // 4. A refused proposal is replaced by the first other plan that the safety layer accepts and that stays in
  // view: the policy's other hypotheses (most confident first, no extra forward pass), then for each turned
  // goal its hypotheses.
  if (!d.kept && !d.final_approach && !d.accepted()) {
    std::vector<double> yaws{0.0};  // 0 (never a configured turn) stands for the goal itself
    yaws.insert(yaws.end(), recovery_.goal_yaw_offsets_deg.begin(), recovery_.goal_yaw_offsets_deg.end());
    for (double yaw : yaws) {
      std::vector<HypothesisPlan> alternatives;
      if (yaw == 0.0) {
        alternatives.assign(plans.begin() + 1, plans.end());
      } else if (!ask) {
        break;  // no network to ask (the engine's Gymnasium environments answer one goal per frame)
      } else {
        ++d.recovery_tries;
        alternatives = OrderedPlans(ask(TurnedGoal(in.state.p_world_body, in.goal_world, yaw)), meta_);
      }
      for (const HypothesisPlan& plan : alternatives) {
        UniformBspline traj = PolicyTrajectory(decoder_.Decode(plan.y, in.state), meta_, in.stamp_s);
        if (check(traj).accepted() && TrajectoryInView(traj, in.camera, safety_)) {
          d.recovery = std::move(traj);
          d.recovery_yaw_deg = yaw;
          d.recovery_hypothesis = plan.index;
          break;
        }
      }
      if (d.recovery) break;
    }
  }
  // 5. Keeping the plan on a refusal the recovery could not mend, while its rest passes the test.
  if (keeping_.on_refusal && !d.kept && !d.accepted() && !d.recovery && !d.final_approach && sent_ &&
      rest_is_clear()) {
    d.kept = sent_;
  }
  // 6. The refusal action stop.
  if (!d.accepted() && !d.recovery && !d.final_approach && !d.kept &&
      refusal_.action == RefusalAction::kStop) {
    d.stop = BrakingTrajectory(in.state.p_world_body, in.state.v_world, refusal_.stop_max_decel_mps2,
                               refusal_.stop_min_duration_s, in.stamp_s);
  }
  // The plan the tracker now flies; a stopping trajectory is never kept (the next refusal stops anew).
  if (!d.kept) {
    const SentKind kind = d.sent_kind();
    if (kind == SentKind::kNothing || kind == SentKind::kStop) {
      sent_.reset();
    } else {
      sent_ = *d.to_send();
    }
  }
  d.timings.safety_ms = MsSince(t0);
  counts_.Add(d.safety.verdict);
  return d;
}

}  // namespace quad_policy
