// The small interface every tracker implements (after kr_mav_control's trackers): activate from the last
// command, update(odometry) -> reference, status. The node owns one tracker of each kind and switches between
// them; trackers are ROS-free.
#pragma once

#include <string>

#include "kr_tracker/types.h"

namespace kr_tracker {

enum class TrackerStatus {
  kInactive,   // not the active tracker
  kHolding,    // active, holding a fixed reference (nothing to track)
  kTracking,   // active, following a trajectory
  kSucceeded,  // active, the last trajectory was completed; holding its end point
};
const char* ToString(TrackerStatus status);

class Tracker {
 public:
  virtual ~Tracker() = default;
  virtual std::string name() const = 0;
  // Starts from the reference the previous tracker produced last (continuity of position, velocity, yaw), or,
  // at start-up, PositionReference::Hold of the odometry.
  virtual void Activate(const PositionReference& last_ref, const quad_core::VehicleState& state) = 0;
  virtual void Deactivate() = 0;
  // The reference for the odometry `state` (state.t_s is the time). Only called while active.
  virtual PositionReference Update(const quad_core::VehicleState& state) = 0;
  virtual TrackerStatus status() const = 0;
};

// Hover / null tracker: holds the position and yaw of the reference it was activated from.
class HoverTracker : public Tracker {
 public:
  std::string name() const override { return "hover"; }
  void Activate(const PositionReference& last_ref, const quad_core::VehicleState& state) override;
  void Deactivate() override { active_ = false; }
  PositionReference Update(const quad_core::VehicleState& state) override;
  TrackerStatus status() const override {
    return active_ ? TrackerStatus::kHolding : TrackerStatus::kInactive;
  }

 private:
  bool active_ = false;
  PositionReference hold_;
};

}  // namespace kr_tracker
