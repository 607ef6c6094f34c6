#include "fast_planner/replan_fsm.h"

#include <sstream>

namespace fast_planner {

const char* ToString(FsmMode mode) {
  switch (mode) {
    case FsmMode::kIdle:
      return "idle";
    case FsmMode::kWaitGoal:
      return "waiting for goal";
    case FsmMode::kPlanning:
      return "planning";
    case FsmMode::kExecuting:
      return "executing";
    case FsmMode::kReplanning:
      return "replanning";
    case FsmMode::kEmergencyStop:
      return "emergency stop";
    case FsmMode::kGoalReached:
      return "goal reached";
  }
  return "unknown";
}

const char* ToString(FsmEvent event) {
  switch (event) {
    case FsmEvent::kOdometryReady:
      return "odometry ready";
    case FsmEvent::kNewGoal:
      return "new goal";
    case FsmEvent::kTick:
      return "tick";
    case FsmEvent::kPlanSucceeded:
      return "plan succeeded";
    case FsmEvent::kPlanFailed:
      return "plan failed";
    case FsmEvent::kReplanDistanceTravelled:
      return "replan distance travelled";
    case FsmEvent::kTrajectoryCollides:
      return "trajectory collides";
    case FsmEvent::kTrajectoryEndingShortOfGoal:
      return "trajectory ending short of goal";
    case FsmEvent::kGoalReached:
      return "goal reached";
    case FsmEvent::kVehicleStopped:
      return "vehicle stopped";
  }
  return "unknown";
}

const char* ToString(FsmAction action) {
  switch (action) {
    case FsmAction::kNone:
      return "none";
    case FsmAction::kPlanFromOdometry:
      return "plan from odometry";
    case FsmAction::kPlanFromTrajectory:
      return "plan from trajectory";
    case FsmAction::kSendTrajectory:
      return "send trajectory";
    case FsmAction::kEmergencyStop:
      return "emergency stop";
    case FsmAction::kAbandonGoal:
      return "abandon goal";
  }
  return "unknown";
}

std::string Describe(const FsmState& s) {
  std::ostringstream o;
  o << ToString(s.mode) << " (" << (s.has_goal ? "goal" : "no goal") << ", " << s.consecutive_failures
    << " failures" << (s.replan_must_succeed ? ", forced replan" : "") << ")";
  return o.str();
}

FsmTransition Transition(const FsmState& s, FsmEvent e, int max_failures) {
  FsmTransition t{s, FsmAction::kNone};
  FsmState& n = t.next;
  auto go = [&](FsmMode mode, FsmAction action) {
    n.mode = mode;
    t.action = action;
  };
  auto replan = [&](bool must_succeed) {
    n.replan_must_succeed = must_succeed;
    go(FsmMode::kReplanning, FsmAction::kPlanFromTrajectory);
  };
  auto abandon = [&]() {
    n.has_goal = false;
    n.consecutive_failures = 0;
    go(FsmMode::kWaitGoal, FsmAction::kAbandonGoal);
  };

  switch (s.mode) {
    case FsmMode::kIdle:
      if (e == FsmEvent::kNewGoal) {
        n.has_goal = true;
      } else if (e == FsmEvent::kOdometryReady) {
        if (s.has_goal) {
          go(FsmMode::kPlanning, FsmAction::kPlanFromOdometry);
        } else {
          go(FsmMode::kWaitGoal, FsmAction::kNone);
        }
      }
      break;
    case FsmMode::kWaitGoal:
    case FsmMode::kGoalReached:
      if (e == FsmEvent::kNewGoal) {
        n.has_goal = true;
        n.consecutive_failures = 0;
        go(FsmMode::kPlanning, FsmAction::kPlanFromOdometry);
      }
      break;
    case FsmMode::kPlanning:
      if (e == FsmEvent::kTick) {
        t.action = FsmAction::kPlanFromOdometry;
      } else if (e == FsmEvent::kPlanSucceeded) {
        n.consecutive_failures = 0;
        go(FsmMode::kExecuting, FsmAction::kSendTrajectory);
      } else if (e == FsmEvent::kPlanFailed) {
        ++n.consecutive_failures;
        if (n.consecutive_failures >= max_failures) abandon();
      } else if (e == FsmEvent::kNewGoal) {
        n.consecutive_failures = 0;
      }
      break;
    case FsmMode::kExecuting:
      switch (e) {
        case FsmEvent::kReplanDistanceTravelled:
          replan(false);
          break;
        case FsmEvent::kTrajectoryCollides:
        case FsmEvent::kTrajectoryEndingShortOfGoal:
          replan(true);
          break;
        case FsmEvent::kNewGoal:
          n.consecutive_failures = 0;
          replan(true);
          break;
        case FsmEvent::kGoalReached:
          n.has_goal = false;
          n.consecutive_failures = 0;
          go(FsmMode::kGoalReached, FsmAction::kNone);
          break;
        default:
          break;
      }
      break;
    case FsmMode::kReplanning:
      if (e == FsmEvent::kPlanSucceeded) {
        n.consecutive_failures = 0;
        n.replan_must_succeed = false;
        go(FsmMode::kExecuting, FsmAction::kSendTrajectory);
      } else if (e == FsmEvent::kPlanFailed) {
        ++n.consecutive_failures;
        const bool stop = s.replan_must_succeed || n.consecutive_failures >= max_failures;
        n.replan_must_succeed = false;
        go(stop ? FsmMode::kEmergencyStop : FsmMode::kExecuting,
           stop ? FsmAction::kEmergencyStop : FsmAction::kNone);
      }
      break;
    case FsmMode::kEmergencyStop:
      if (e == FsmEvent::kNewGoal) {
        n.has_goal = true;
        n.consecutive_failures = 0;
      } else if (e == FsmEvent::kVehicleStopped) {
        if (s.has_goal && s.consecutive_failures < max_failures) {
          go(FsmMode::kPlanning, FsmAction::kPlanFromOdometry);
        } else {
          abandon();
        }
      }
      break;
  }
  return t;
}

}  // namespace fast_planner
