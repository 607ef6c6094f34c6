#include <gtest/gtest.h>

#include <set>
#include <utility>
#include <vector>

#include "fast_planner/replan_fsm.h"

namespace fast_planner {
namespace {

using A = FsmAction;
using E = FsmEvent;
using M = FsmMode;

constexpr int kMax = 3;

FsmState S(M mode, bool goal = true, int failures = 0, bool must = false) {
  FsmState s;
  s.mode = mode;
  s.has_goal = goal;
  s.consecutive_failures = failures;
  s.replan_must_succeed = must;
  return s;
}

struct Case {
  FsmState from;
  FsmEvent event;
  FsmState to;
  FsmAction action;
};

// The transition table of replan_fsm.h, row by row (with the variants of each conditional row).
const std::vector<Case>& Table() {
  static const std::vector<Case> cases = {
      {S(M::kIdle, false), E::kNewGoal, S(M::kIdle, true), A::kNone},
      {S(M::kIdle, true), E::kOdometryReady, S(M::kPlanning, true), A::kPlanFromOdometry},
      {S(M::kIdle, false), E::kOdometryReady, S(M::kWaitGoal, false), A::kNone},
      {S(M::kWaitGoal, false), E::kNewGoal, S(M::kPlanning, true), A::kPlanFromOdometry},
      {S(M::kPlanning), E::kTick, S(M::kPlanning), A::kPlanFromOdometry},
      {S(M::kPlanning, true, 2), E::kPlanSucceeded, S(M::kExecuting), A::kSendTrajectory},
      {S(M::kPlanning, true, 1), E::kPlanFailed, S(M::kPlanning, true, 2), A::kNone},
      {S(M::kPlanning, true, kMax - 1), E::kPlanFailed, S(M::kWaitGoal, false, 0), A::kAbandonGoal},
      {S(M::kPlanning, true, 2), E::kNewGoal, S(M::kPlanning, true, 0), A::kNone},
      {S(M::kExecuting), E::kReplanDistanceTravelled, S(M::kReplanning, true, 0, false),
       A::kPlanFromTrajectory},
      {S(M::kExecuting), E::kTrajectoryCollides, S(M::kReplanning, true, 0, true), A::kPlanFromTrajectory},
      {S(M::kExecuting), E::kTrajectoryEndingShortOfGoal, S(M::kReplanning, true, 0, true),
       A::kPlanFromTrajectory},
      {S(M::kExecuting, true, 2), E::kNewGoal, S(M::kReplanning, true, 0, true), A::kPlanFromTrajectory},
      {S(M::kExecuting, true, 1), E::kGoalReached, S(M::kGoalReached, false, 0), A::kNone},
      {S(M::kReplanning, true, 1, true), E::kPlanSucceeded, S(M::kExecuting, true, 0, false),
       A::kSendTrajectory},
      {S(M::kReplanning, true, 0, false), E::kPlanFailed, S(M::kExecuting, true, 1, false), A::kNone},
      {S(M::kReplanning, true, kMax - 1, false), E::kPlanFailed, S(M::kEmergencyStop, true, kMax, false),
       A::kEmergencyStop},
      {S(M::kReplanning, true, 0, true), E::kPlanFailed, S(M::kEmergencyStop, true, 1, false),
       A::kEmergencyStop},
      {S(M::kEmergencyStop, false, 2), E::kNewGoal, S(M::kEmergencyStop, true, 0), A::kNone},
      {S(M::kEmergencyStop, true, 1), E::kVehicleStopped, S(M::kPlanning, true, 1), A::kPlanFromOdometry},
      {S(M::kEmergencyStop, true, kMax), E::kVehicleStopped, S(M::kWaitGoal, false, 0), A::kAbandonGoal},
      {S(M::kEmergencyStop, false, 0), E::kVehicleStopped, S(M::kWaitGoal, false, 0), A::kAbandonGoal},
      {S(M::kGoalReached, false), E::kNewGoal, S(M::kPlanning, true), A::kPlanFromOdometry},
  };
  return cases;
}

class FsmTableTest : public ::testing::TestWithParam<size_t> {};

TEST_P(FsmTableTest, TransitionMatchesTheTableRow) {
  const Case& c = Table()[GetParam()];
  const FsmTransition t = Transition(c.from, c.event, kMax);
  EXPECT_EQ(t.next, c.to) << Describe(c.from) << " + " << ToString(c.event) << " -> " << Describe(t.next)
                          << ", expected " << Describe(c.to);
  EXPECT_EQ(t.action, c.action) << ToString(t.action) << ", expected " << ToString(c.action);
}

INSTANTIATE_TEST_SUITE_P(Rows, FsmTableTest, ::testing::Range<size_t>(0, Table().size()));

TEST(FsmTest, EveryPairNotInTheTableChangesNothing) {
  const std::vector<M> modes = {M::kIdle,       M::kWaitGoal,      M::kPlanning,   M::kExecuting,
                                M::kReplanning, M::kEmergencyStop, M::kGoalReached};
  const std::vector<E> events = {E::kOdometryReady,
                                 E::kNewGoal,
                                 E::kTick,
                                 E::kPlanSucceeded,
                                 E::kPlanFailed,
                                 E::kReplanDistanceTravelled,
                                 E::kTrajectoryCollides,
                                 E::kTrajectoryEndingShortOfGoal,
                                 E::kGoalReached,
                                 E::kVehicleStopped};
  std::set<std::pair<M, E>> listed;
  for (const Case& c : Table()) listed.emplace(c.from.mode, c.event);
  int unlisted = 0;
  for (const M m : modes) {
    for (const E e : events) {
      if (listed.count({m, e})) continue;
      ++unlisted;
      for (const bool goal : {false, true}) {
        const FsmState s = S(m, goal, 1, false);
        const FsmTransition t = Transition(s, e, kMax);
        EXPECT_EQ(t.next, s) << ToString(m) << " + " << ToString(e);
        EXPECT_EQ(t.action, A::kNone) << ToString(m) << " + " << ToString(e);
      }
    }
  }
  EXPECT_EQ(unlisted, 70 - 17);
}

TEST(FsmTest, AFlightFromGoalToGoalReachedFollowsTheExpectedSequence) {
  FsmState s;
  const std::vector<std::pair<E, A>> script = {
      {E::kNewGoal, A::kNone},
      {E::kOdometryReady, A::kPlanFromOdometry},
      {E::kPlanSucceeded, A::kSendTrajectory},
      {E::kReplanDistanceTravelled, A::kPlanFromTrajectory},
      {E::kPlanFailed, A::kNone},  // keeps flying the old trajectory
      {E::kReplanDistanceTravelled, A::kPlanFromTrajectory},
      {E::kPlanSucceeded, A::kSendTrajectory},
      {E::kTrajectoryCollides, A::kPlanFromTrajectory},
      {E::kPlanFailed, A::kEmergencyStop},
      {E::kVehicleStopped, A::kPlanFromOdometry},
      {E::kPlanSucceeded, A::kSendTrajectory},
      {E::kGoalReached, A::kNone},
  };
  for (const auto& [event, action] : script) {
    const FsmTransition t = Transition(s, event, kMax);
    ASSERT_EQ(t.action, action) << Describe(s) << " + " << ToString(event);
    s = t.next;
  }
  EXPECT_EQ(s.mode, M::kGoalReached);
  EXPECT_FALSE(s.has_goal);
}

TEST(FsmTest, NamesArePrintable) {
  EXPECT_STREQ(ToString(M::kEmergencyStop), "emergency stop");
  EXPECT_STREQ(ToString(E::kTrajectoryCollides), "trajectory collides");
  EXPECT_STREQ(ToString(A::kPlanFromTrajectory), "plan from trajectory");
  EXPECT_EQ(Describe(S(M::kReplanning, true, 2, true)), "replanning (goal, 2 failures, forced replan)");
}

}  // namespace
}  // namespace fast_planner
