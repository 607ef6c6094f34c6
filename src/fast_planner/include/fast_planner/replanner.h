// The replanning loop (ROS-free): turns odometry, depth frames and goals into state-machine events, carries
// out the state machine's actions with the planner manager and hands back the trajectories to fly. The ROS
// node and the in-process closed-loop benchmark both drive this class.
//
// Events, checked after every depth frame (Step): the goal reached (the trajectory to the goal has ended and
// the vehicle is within fsm.goal_tolerance_m); the current trajectory entering the inflated map as updated by
// the frame; a local trajectory about to end short of the goal (less time left than needed to brake from its
// end speed; one that ends at rest short of the goal, a safe stop, once it has ended); fsm.replan_distance_m
// travelled since the last plan (local trajectories only: a trajectory that ends at the goal is replanned
// only for a collision). After an emergency stop, the vehicle counts as stopped once the stop trajectory has
// ended and its speed is below fsm.stopped_speed_mps.
#pragma once

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "fast_planner/planner_manager.h"
#include "fast_planner/replan_fsm.h"

namespace fast_planner {

struct ReplannerOutput {
  std::optional<PlanResult> trajectory;  // a new trajectory to fly (a plan or an emergency stop)
  std::vector<PlanResult> failed_plans;  // plans that failed during this call (status and reason)
  std::optional<std::string> abandoned;  // the goal was given up, with the last failure's reason
  std::vector<std::string>
      transitions;  // "executing + trajectory collides -> replanning: plan from trajectory"
};

class Replanner {
 public:
  // Throws quad_core::ConfigError on an invalid configuration.
  explicit Replanner(const PlannerConfig& cfg);

  PlannerManager& manager() { return manager_; }
  const PlannerManager& manager() const { return manager_; }

  // A new episode: forgets the map, goal, trajectory and state.
  void Reset();

  // Remembers the odometry; the first one makes the machine leave kIdle. Throws std::invalid_argument (with
  // the reason) on non-finite odometry, which is then ignored.
  ReplannerOutput OnOdometry(const quad_core::VehicleState& odom);

  // Accepts a goal (returns "") or rejects it with the reason (outside the map, in or near an obstacle), in
  // which case nothing changes.
  std::string SetGoal(const Eigen::Vector3d& goal, double now_s, ReplannerOutput* out);

  // Integrates a depth frame (throws std::invalid_argument on a malformed one) and steps at its stamp.
  ReplannerOutput OnDepth(std::shared_ptr<const DepthFrame> frame, MapUpdateResult* map_update = nullptr);

  // Checks the events at time now_s and runs the resulting transitions and actions.
  ReplannerOutput Step(double now_s);

  const FsmState& state() const { return state_; }
  const std::optional<PlanResult>& current() const { return current_; }
  const std::optional<Eigen::Vector3d>& goal() const { return goal_; }
  // The last plan attempted (successful or not), e.g. for visualisation and timing.
  const std::optional<PlanResult>& last_plan() const { return last_plan_; }

 private:
  void Feed(FsmEvent event, double now_s, ReplannerOutput* out);
  PlanRequest RequestFromOdometry(double now_s) const;
  PlanRequest RequestFromTrajectory(double now_s) const;
  void RunPlan(const PlanRequest& request, double now_s, ReplannerOutput* out);

  PlannerConfig cfg_;
  PlannerManager manager_;
  FsmState state_;
  std::optional<Eigen::Vector3d> goal_;
  std::optional<PlanResult> current_;
  std::optional<PlanResult> last_plan_;
  Eigen::Vector3d last_plan_start_ = Eigen::Vector3d::Zero();
};

}  // namespace fast_planner
