// The odometry the expert keeps to find the vehicle's state at a depth frame's stamp (ROS-free). The pairing
// rule itself is quad_core/pairing.h; this class holds the buffer it is applied to, and the camera pose and
// start state derived from the paired odometry.
//
// Odometry and depth arrive on separate connections, so a frame may overtake the odometry it belongs to. In
// lockstep the simulator publishes nothing newer until the frame is acknowledged, so waiting until the
// odometry of the frame's control period has arrived (Covers) makes what every frame is planned from, and so
// every record, independent of message timing.
#pragma once

#include <quad_core/vehicle_state.h>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cstddef>
#include <deque>
#include <vector>

namespace fast_planner {

// The camera optical frame in the body frame (the base_link -> camera transform).
struct CameraMount {
  Eigen::Vector3d p_body_camera = Eigen::Vector3d::Zero();
  Eigen::Quaterniond q_body_camera = Eigen::Quaterniond::Identity();
};

struct CameraPose {
  Eigen::Vector3d p_world_camera = Eigen::Vector3d::Zero();
  Eigen::Quaterniond q_world_camera = Eigen::Quaterniond::Identity();
};

class OdometryHistory {
 public:
  // Keeps the newest `capacity` messages (> 0); `odom_period_s` (> 0) is the simulator's odometry period.
  // Throws std::invalid_argument naming the bad value.
  OdometryHistory(std::size_t capacity, double odom_period_s);

  // Appends (the caller validates); the oldest message is dropped beyond the capacity.
  void Push(const quad_core::VehicleState& odom);
  void Clear() { samples_.clear(); }

  // True once the newest odometry covers a frame stamped frame_stamp_s (quad_core::OdometryCoversFrame).
  bool Covers(double frame_stamp_s) const;
  // The newest odometry not newer than the frame (quad_core::PairedOdometry), or nullptr.
  const quad_core::VehicleState* PairedWith(double frame_stamp_s) const;
  // The messages stamped at or after t_start_s, oldest first (a new episode's odometry that arrived before
  // its status).
  std::vector<quad_core::VehicleState> Since(double t_start_s) const;

  bool empty() const { return samples_.empty(); }
  const quad_core::VehicleState& newest() const { return samples_.back(); }
  const std::deque<quad_core::VehicleState>& samples() const { return samples_; }
  double odom_period_s() const { return odom_period_s_; }

 private:
  std::size_t capacity_;
  double odom_period_s_;
  std::deque<quad_core::VehicleState> samples_;
};

// The position at t_s of the paired odometry moved on at its velocity (in lockstep the odometry after a frame
// is only published once the frame is acknowledged, so the paired one is up to one period older).
Eigen::Vector3d PositionAt(const quad_core::VehicleState& paired, double t_s);

// The camera pose at t_s: PositionAt with the odometry's (normalised) attitude, times the mount.
CameraPose CameraPoseAt(const quad_core::VehicleState& paired, double t_s, const CameraMount& mount);

}  // namespace fast_planner
