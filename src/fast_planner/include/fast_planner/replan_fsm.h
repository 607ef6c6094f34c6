// The replanning state machine: a small pure transition function (no clocks, no map, no I/O).
//
// The caller (Replanner) turns observations into events (a new goal, the distance travelled since the last
// plan, the current trajectory colliding with newly seen obstacles, the goal reached, ...), feeds them one at
// a time and carries out the returned action; the result of a requested plan comes back as kPlanSucceeded /
// kPlanFailed.
//
//   state           event                       -> next state      action
//   kIdle           kNewGoal                       kIdle            none (goal remembered)
//   kIdle           kOdometryReady                 kPlanning        plan from odometry   (goal pending)
//                                                  kWaitGoal        none                 (no goal)
//   kWaitGoal       kNewGoal                       kPlanning        plan from odometry
//   kPlanning       kTick                          kPlanning        plan from odometry   (retry)
//   kPlanning       kPlanSucceeded                 kExecuting       send trajectory
//   kPlanning       kPlanFailed                    kPlanning        none                 (retried on next
//   tick)
//                                                  kWaitGoal        abandon goal         (too many failures)
//   kPlanning       kNewGoal                       kPlanning        none (failures reset; planned on next
//   tick) kExecuting      kReplanDistanceTravelled       kReplanning      plan from trajectory (may fail)
//   kExecuting      kTrajectoryCollides            kReplanning      plan from trajectory (must succeed)
//   kExecuting      kTrajectoryEndingShortOfGoal   kReplanning      plan from trajectory (must succeed)
//   kExecuting      kNewGoal                       kReplanning      plan from trajectory (must succeed)
//   kExecuting      kGoalReached                   kGoalReached     none
//   kReplanning     kPlanSucceeded                 kExecuting       send trajectory
//   kReplanning     kPlanFailed                    kExecuting       none  (may fail, failures below the
//   limit:
//                                                                          keep flying the safe old
//                                                                          trajectory)
//                                                  kEmergencyStop   emergency stop (otherwise)
//   kEmergencyStop  kNewGoal                       kEmergencyStop   none (failures reset, goal remembered)
//   kEmergencyStop  kVehicleStopped                kPlanning        plan from odometry   (failures below
//   limit)
//                                                  kWaitGoal        abandon goal         (otherwise)
//   kGoalReached    kNewGoal                       kPlanning        plan from odometry
// Any other (state, event) pair leaves the state unchanged with no action.
#pragma once

#include <string>

namespace fast_planner {

enum class FsmMode { kIdle, kWaitGoal, kPlanning, kExecuting, kReplanning, kEmergencyStop, kGoalReached };

enum class FsmEvent {
  kOdometryReady,
  kNewGoal,
  kTick,
  kPlanSucceeded,
  kPlanFailed,
  kReplanDistanceTravelled,
  kTrajectoryCollides,
  kTrajectoryEndingShortOfGoal,
  kGoalReached,
  kVehicleStopped,
};

enum class FsmAction {
  kNone,
  kPlanFromOdometry,
  kPlanFromTrajectory,
  kSendTrajectory,
  kEmergencyStop,
  kAbandonGoal
};

const char* ToString(FsmMode mode);
const char* ToString(FsmEvent event);
const char* ToString(FsmAction action);

struct FsmState {
  FsmMode mode = FsmMode::kIdle;
  bool has_goal = false;
  bool replan_must_succeed =
      false;  // the replan in progress was forced (collision, new goal, trajectory ending)
  int consecutive_failures = 0;
  bool operator==(const FsmState& o) const {
    return mode == o.mode && has_goal == o.has_goal && replan_must_succeed == o.replan_must_succeed &&
           consecutive_failures == o.consecutive_failures;
  }
};

struct FsmTransition {
  FsmState next;
  FsmAction action = FsmAction::kNone;
};

// The transition function. max_consecutive_failures >= 1 (fsm.max_consecutive_failures).
FsmTransition Transition(const FsmState& state, FsmEvent event, int max_consecutive_failures);

// "kExecuting (goal, 0 failures)" for logs.
std::string Describe(const FsmState& state);

}  // namespace fast_planner
