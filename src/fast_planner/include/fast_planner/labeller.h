// Labeller mode of the expert (issue 9, docs/fast_planner.md "Labeller mode", docs/imitation_learning.md),
// ROS-free: the expert does not fly; on every depth frame (after the map update) it plans from the vehicle's
// state at that frame to the episode's goal. The state is the newest odometry not after the frame's stamp
// (quad_core/pairing.h), moved on at its velocity to the stamp, with the acceleration of the odometry's last
// label_acc_window_s (AccelerationFromOdometry; 0: zero acceleration), capped at limits.max_acc_mps2: a plan
// from zero acceleration, flown for one frame and replaced, would never let the vehicle speed up (the learner
// trained on such labels crept). The replanning state machine is not used.
#pragma once

#include <Eigen/Core>

#include <optional>
#include <string>

#include "fast_planner/odometry_history.h"
#include "fast_planner/planner_manager.h"

namespace fast_planner {

class Labeller {
 public:
  // Throws std::invalid_argument unless acc_window_s is finite and >= 0.
  explicit Labeller(double acc_window_s);

  // Accepts the episode's goal ("") or returns why it cannot be planned to (PlannerManager::CheckGoal), in
  // which case the previous goal stays.
  std::string SetGoal(const PlannerManager& manager, const Eigen::Vector3d& goal);
  // A new episode: no goal until the next one arrives.
  void Reset() { goal_.reset(); }
  const std::optional<Eigen::Vector3d>& goal() const { return goal_; }

  // The request of the frame stamped t_s, with the odometry it starts from; nullopt without a goal or
  // without odometry at or before t_s.
  struct Request {
    PlanRequest request;
    quad_core::VehicleState odometry;
  };
  std::optional<Request> RequestAt(const OdometryHistory& history, double t_s, double max_acc_mps2) const;

  // Plans the label of the frame stamped t_s (the map already holds the frame): hands the paired odometry to
  // the manager (so the collector records exactly the odometry the plan starts from) and plans. nullopt as
  // RequestAt; otherwise the plan, successful or not.
  std::optional<PlanResult> Label(PlannerManager& manager, const OdometryHistory& history, double t_s) const;

 private:
  double acc_window_s_;
  std::optional<Eigen::Vector3d> goal_;
};

}  // namespace fast_planner
