#include "fast_planner/replanner.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace fast_planner {

namespace {

Eigen::Vector3d Vec3(const Eigen::VectorXd& v) { return Eigen::Vector3d(v[0], v[1], v[2]); }

// Beyond this distance between the vehicle and its trajectory, a replan starts from the odometry instead of
// the trajectory (the tracker has lost it, e.g. after a disturbance).
constexpr double kReplanFromOdometryErrorM = 0.5;
// Extra time kept, on top of the braking time from its end speed, before a local trajectory runs out.
constexpr double kEndingMarginS = 0.3;

}  // namespace

Replanner::Replanner(const PlannerConfig& cfg) : cfg_(cfg), manager_(cfg) {}

void Replanner::Reset() {
  manager_.Reset();
  state_ = FsmState();
  goal_.reset();
  current_.reset();
  last_plan_.reset();
}

ReplannerOutput Replanner::OnOdometry(const quad_core::VehicleState& odom) {
  ReplannerOutput out;
  const bool first = !manager_.last_odometry().has_value();
  manager_.UpdateOdometry(odom);  // throws on bad input, leaving everything unchanged
  if (first) Feed(FsmEvent::kOdometryReady, odom.t_s, &out);
  return out;
}

std::string Replanner::SetGoal(const Eigen::Vector3d& goal, double now_s, ReplannerOutput* out) {
  const std::string problem = manager_.CheckGoal(goal);
  if (!problem.empty()) return problem;
  goal_ = goal;
  Feed(FsmEvent::kNewGoal, now_s, out);
  return "";
}

ReplannerOutput Replanner::OnDepth(std::shared_ptr<const DepthFrame> frame, MapUpdateResult* map_update) {
  if (!frame) throw std::invalid_argument("Replanner::OnDepth: null frame");
  const double stamp = frame->stamp_s;
  const MapUpdateResult r = manager_.UpdateDepth(std::move(frame));
  if (map_update) *map_update = r;
  return Step(stamp);
}

ReplannerOutput Replanner::Step(double now_s) {
  ReplannerOutput out;
  const auto& odom = manager_.last_odometry();
  if (!odom) return out;
  switch (state_.mode) {
    case FsmMode::kPlanning:
      Feed(FsmEvent::kTick, now_s, &out);
      break;
    case FsmMode::kEmergencyStop: {
      const bool ended = !current_ || now_s - current_->start_time_s >= current_->spline->tmax();
      if (ended && odom->v_world.norm() < cfg_.fsm.stopped_speed_mps)
        Feed(FsmEvent::kVehicleStopped, now_s, &out);
      break;
    }
    case FsmMode::kExecuting: {
      const PlanResult& cur = *current_;
      const quad_core::NonUniformBspline& spline = *cur.spline;
      const double t = now_s - cur.start_time_s;
      const bool ended = t >= spline.tmax();
      const double to_goal = goal_ ? (odom->p_world_body - *goal_).norm() : 0.0;
      if (cur.reaches_goal && ended && to_goal <= cfg_.fsm.goal_tolerance_m) {
        Feed(FsmEvent::kGoalReached, now_s, &out);
      } else if (manager_.FirstCollision(spline, t, odom->p_world_body)) {
        Feed(FsmEvent::kTrajectoryCollides, now_s, &out);
      } else if (cur.ends_at_rest
                     ? ended
                     : spline.tmax() - t < Vec3(spline.Derivative().Evaluate(spline.tmax())).norm() /
                                                   cfg_.limits.max_acc_mps2 +
                                               kEndingMarginS) {
        // A local trajectory running out at speed; or one ending at rest (at a safe stop, or at the goal with
        // the vehicle out of tolerance) that has ended.
        Feed(FsmEvent::kTrajectoryEndingShortOfGoal, now_s, &out);
      } else if ((!cur.reaches_goal ||
                  (cfg_.fsm.replan_final_approach && to_goal > cfg_.fsm.replan_distance_m)) &&
                 (odom->p_world_body - last_plan_start_).norm() >= cfg_.fsm.replan_distance_m) {
        Feed(FsmEvent::kReplanDistanceTravelled, now_s, &out);
      }
      break;
    }
    default:
      break;
  }
  return out;
}

PlanRequest Replanner::RequestFromOdometry(double now_s) const {
  const quad_core::VehicleState& odom = *manager_.last_odometry();
  PlanRequest r;
  r.start_p = odom.p_world_body;
  r.start_v = odom.v_world;
  r.start_a.setZero();
  r.goal = goal_ ? *goal_ : odom.p_world_body;
  r.start_time_s = now_s;
  return r;
}

PlanRequest Replanner::RequestFromTrajectory(double now_s) const {
  if (!current_) return RequestFromOdometry(now_s);
  const quad_core::NonUniformBspline& s = *current_->spline;
  const double t = std::clamp(now_s - current_->start_time_s, s.tmin(), s.tmax());
  PlanRequest r = RequestFromOdometry(now_s);
  const Eigen::Vector3d p = Vec3(s.Evaluate(t));
  if ((p - r.start_p).norm() > kReplanFromOdometryErrorM) return r;
  r.start_p = p;
  r.start_v = Vec3(s.Derivative().Evaluate(t));
  r.start_a = Vec3(s.Derivative(2).Evaluate(t));
  return r;
}

void Replanner::RunPlan(const PlanRequest& request, double now_s, ReplannerOutput* out) {
  last_plan_ = manager_.Plan(request);
  if (last_plan_->ok()) {
    last_plan_start_ = request.start_p;
    Feed(FsmEvent::kPlanSucceeded, now_s, out);
  } else {
    out->failed_plans.push_back(*last_plan_);
    Feed(FsmEvent::kPlanFailed, now_s, out);
  }
}

void Replanner::Feed(FsmEvent event, double now_s, ReplannerOutput* out) {
  const FsmTransition t = Transition(state_, event, cfg_.fsm.max_consecutive_failures);
  if (!(t.next == state_) || t.action != FsmAction::kNone) {
    std::ostringstream s;
    s << ToString(state_.mode) << " + " << ToString(event) << " -> " << ToString(t.next.mode) << ": "
      << ToString(t.action);
    out->transitions.push_back(s.str());
  }
  state_ = t.next;
  switch (t.action) {
    case FsmAction::kNone:
      break;
    case FsmAction::kPlanFromOdometry:
      // Without a map yet (before the first depth frame) the plan waits for the next tick instead of failing.
      if (manager_.MapReady()) RunPlan(RequestFromOdometry(now_s), now_s, out);
      break;
    case FsmAction::kPlanFromTrajectory:
      RunPlan(RequestFromTrajectory(now_s), now_s, out);
      break;
    case FsmAction::kSendTrajectory:
      current_ = last_plan_;
      out->trajectory = current_;
      break;
    case FsmAction::kEmergencyStop: {
      const PlanRequest from = RequestFromTrajectory(now_s);
      current_ = manager_.PlanStop(from.start_p, from.start_v, from.start_a, now_s);
      out->trajectory = current_;
      break;
    }
    case FsmAction::kAbandonGoal:
      out->abandoned = last_plan_ ? last_plan_->reason : std::string("goal abandoned");
      goal_.reset();
      break;
  }
}

}  // namespace fast_planner
