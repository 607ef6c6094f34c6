// B-spline tracker: flies Fast-Planner-style B-spline goals (the TrackBspline action's core, ROS-free).
//
// A goal's position spline is flown with its parameter u = knots[order] at start_time, i.e. at time t the
// reference is the spline at knots[order] + (t - start_time). A newer goal replaces the running one when its
// start_time arrives (until then the running one continues); the replaced goal ends with kReplaced. Yaw
// follows the goal's yaw B-spline when it has yaw points (uniform, interval yaw_dt, same degree, parameter t
// - start_time as in Fast-Planner), otherwise the direction of travel with a rate limit.
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "kr_tracker/tracker.h"
#include "quad_core/bspline.h"

namespace kr_tracker {

struct BsplineTrackerConfig {
  double max_start_delay_s = 2.0;   // goals starting later than now + this are rejected
  double max_start_age_s = 1.0;     // goals that started earlier than now - this are rejected
  double max_start_error_m = 1.5;   // goals whose reference at now is farther from the vehicle are rejected
  double max_yaw_rate_radps = 1.5;  // direction-of-travel yaw: rate limit
  double min_speed_for_yaw_mps = 0.3;  // direction-of-travel yaw: below this horizontal speed, yaw is held
  void Validate() const;               // throws std::invalid_argument naming the field
};

// A goal as received (Bspline.msg's fields, times in seconds).
struct BsplineGoalSpec {
  int order = 3;
  int64_t traj_id = 0;
  double start_time_s = 0.0;
  std::vector<double> knots;
  Eigen::MatrixXd pos_pts;  // N x 3
  std::vector<double> yaw_pts;
  double yaw_dt_s = 0.0;
};

// Structural check of a goal: "" or the reason (B-spline structure, NaN/Inf anywhere, yaw points/interval).
std::string ValidateGoalSpec(const BsplineGoalSpec& spec);

enum class GoalEventKind { kStarted, kSucceeded, kReplaced, kCanceled, kAborted };
const char* ToString(GoalEventKind kind);

struct GoalEvent {
  uint64_t goal_id = 0;
  GoalEventKind kind = GoalEventKind::kStarted;
  double total_time_s = 0.0;          // time flown (start_time to end)
  double distance_travelled_m = 0.0;  // path length of the odometry while the goal was flown
  std::string reason;                 // empty for kStarted / kSucceeded
};

class BsplineTracker : public Tracker {
 public:
  explicit BsplineTracker(const BsplineTrackerConfig& config);
  std::string name() const override { return "bspline"; }
  void Activate(const PositionReference& last_ref, const quad_core::VehicleState& state) override;
  // Aborts the running and pending goals (events) and stops.
  void Deactivate() override;
  PositionReference Update(const quad_core::VehicleState& state) override;
  TrackerStatus status() const override;

  // Validates and queues a goal under the caller's id. now_s and state are the latest time and odometry.
  // Returns "" when accepted, else why it was rejected (nothing changes then). A goal accepted while another
  // one is pending replaces the pending one (which ends with kReplaced). Works whether or not the tracker is
  // active.
  std::string AddGoal(uint64_t goal_id, const BsplineGoalSpec& spec, double now_s,
                      const quad_core::VehicleState& state);
  // Cancels a running or pending goal (the vehicle holds the current reference). False if the id is unknown.
  bool Cancel(uint64_t goal_id);
  // Aborts the running and the pending goal (kAborted events with `reason`; the pending one's reason says it
  // had not started) and holds the current reference. Used when the vehicle is re-anchored (episode reset,
  // odometry jump). Does not change whether the tracker is active.
  void AbortAll(const std::string& reason);
  // Events since the last call, in order.
  std::vector<GoalEvent> TakeEvents();
  // The running goal's id and remaining time at t_s.
  std::optional<uint64_t> running_goal() const;
  double RemainingTime(double t_s) const;

 private:
  struct Goal {
    uint64_t id = 0;
    int64_t traj_id = 0;
    double start_time_s = 0.0;
    quad_core::NonUniformBspline pos;
    quad_core::NonUniformBspline vel;
    quad_core::NonUniformBspline acc;
    quad_core::NonUniformBspline jerk;
    std::optional<quad_core::NonUniformBspline> yaw;
    std::optional<quad_core::NonUniformBspline> yaw_rate;
    double distance_m = 0.0;
    bool started = false;
  };
  static Goal MakeGoal(uint64_t id, const BsplineGoalSpec& spec);
  void EndRunning(GoalEventKind kind, double t_s, const std::string& reason);
  PositionReference Hold() const;
  double DirectionOfTravelYaw(const Eigen::Vector3d& v_world, double dt_s, double* yaw_rate_radps);

  BsplineTrackerConfig config_;
  bool active_ = false;
  std::optional<Goal> running_;
  std::optional<Goal> pending_;
  std::vector<GoalEvent> events_;
  PositionReference last_ref_;
  bool has_last_state_ = false;
  quad_core::VehicleState last_state_;
  bool completed_ = false;
};

}  // namespace kr_tracker
