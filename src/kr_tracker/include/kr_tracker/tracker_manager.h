// TrackerManager: the node's logic without ROS. Owns the hover, line and B-spline trackers and the SO(3)
// controller, turns every odometry message into one command, switches trackers, and re-anchors everything
// when the simulator starts a new episode (or the odometry jumps), so that no reference of the previous
// episode survives a reset (docs/kr_tracker.md, "Episode resets").
//
// Episode resets. quad_sim publishes the new episode's EpisodeStatus (latched, new episode_id, sim_time = the
// stamp of the new episode's first odometry) before that odometry; sim time keeps increasing across resets.
// OnEpisodeStatus therefore aborts the B-spline goals at once and re-anchors on the first odometry stamped at
// or after the episode's start (the latest odometry may still be the old episode's). Between the status and
// that odometry, gotos and switches are deferred and applied right after the re-anchor, and B-spline goals
// are rejected (their start cannot be checked against a position that is not known yet). The odometry-jump
// check catches resets whose status is missed or arrives after the odometry.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "kr_tracker/bspline_tracker.h"
#include "kr_tracker/config.h"
#include "kr_tracker/line_tracker.h"
#include "kr_tracker/so3_controller.h"

namespace kr_tracker {

// The answer to one odometry message.
struct ControlStep {
  So3Command command;
  PositionReference ref;
  // kOk, or why the command is the safe hover command (non-finite odometry counts as kNonFiniteInput).
  ControlStatus status = ControlStatus::kOk;
  bool odometry_skipped = false;  // non-finite odometry: safe command, nothing updated
  std::string reanchored;         // non-empty: this odometry re-anchored the trackers, with the reason
};

class TrackerManager {
 public:
  // Throws std::invalid_argument for invalid gains / tracker configs / vehicle values (So3Controller).
  TrackerManager(const TrackerConfig& config, double mass_kg, double gravity_mps2, double max_thrust_N);

  // One odometry message -> one command. The first valid odometry anchors the initial tracker on its pose
  // (start-up); a pending episode reset or an odometry jump re-anchors before the update.
  ControlStep OnOdometry(const quad_core::VehicleState& state);

  // /sim/status: the episode id and its start time (EpisodeStatus.sim_time of the first status of an
  // episode). The first status seen only records the id. A different id aborts the B-spline goals ("episode
  // reset ...") and re-anchors on the first odometry stamped >= start_time_s (at once if that odometry was
  // already seen, not at all if an odometry jump already re-anchored on it). Returns what was done ("" when
  // nothing).
  std::string OnEpisodeStatus(uint32_t episode_id, double start_time_s);

  // Aborts all B-spline goals with `reason`, stops the line tracker, resets the controller's integral, makes
  // `state`'s position and yaw the reference (zero derivatives) and activates the initial tracker from it,
  // exactly as at start-up; then applies the deferred gotos/switches. `state` must be finite.
  void ReAnchor(const quad_core::VehicleState& state, const std::string& reason);

  // Requests; "" on success, else the reason for refusing. `deferred` (optional) tells whether a goto or
  // switch was queued until the new episode's first odometry.
  std::string Switch(const std::string& tracker, bool* deferred = nullptr);
  std::string Goto(const Eigen::Vector3d& p_world, double yaw_rad, double max_vel_mps, double max_acc_mps2,
                   bool* deferred = nullptr);
  std::string AddGoal(uint64_t goal_id, const BsplineGoalSpec& spec, double now_s);
  bool Cancel(uint64_t goal_id);
  std::vector<GoalEvent> TakeEvents() { return bspline_.TakeEvents(); }

  bool have_odom() const { return have_odom_; }
  const quad_core::VehicleState& last_state() const { return last_state_; }
  const PositionReference& last_ref() const { return last_ref_; }
  // Weight-compensating, level, at the last reference's yaw: what the node holds while odometry is stale.
  const So3Command& safe_command() const { return safe_command_; }
  std::string active_tracker() const { return active_ ? active_->name() : ""; }
  bool reset_pending() const { return reset_pending_; }
  std::optional<uint32_t> episode_id() const { return episode_id_; }
  int reanchor_count() const { return reanchor_count_; }
  const BsplineTracker& bspline() const { return bspline_; }
  const LineTracker& line() const { return line_; }
  const So3Controller& controller() const { return controller_; }

 private:
  struct Deferred {
    bool is_goto = false;
    std::string tracker;  // switch target
    Eigen::Vector3d p_world = Eigen::Vector3d::Zero();
    double yaw_rad = 0.0, max_vel_mps = 0.0, max_acc_mps2 = 0.0;
  };
  Tracker* Find(const std::string& name);
  std::string SwitchTo(Tracker* next);
  std::string GotoNow(const Eigen::Vector3d& p_world, double yaw_rad, double max_vel_mps,
                      double max_acc_mps2);

  TrackerConfig config_;
  So3Controller controller_;
  HoverTracker hover_;
  LineTracker line_;
  BsplineTracker bspline_;
  Tracker* active_ = nullptr;

  bool have_odom_ = false;
  quad_core::VehicleState last_state_;
  PositionReference last_ref_;
  So3Command safe_command_;
  double anchor_stamp_s_ = 0.0;  // stamp of the odometry the trackers were last anchored on

  std::optional<uint32_t> episode_id_;
  bool reset_pending_ = false;
  // Auto-activation of the B-spline tracker at the first odometry after this time (AddGoal).
  std::optional<double> bspline_switch_at_s_;
  double reset_start_s_ = 0.0;
  std::string reset_reason_;
  std::vector<Deferred> deferred_;
  int reanchor_count_ = 0;
};

}  // namespace kr_tracker
