// What a value is once it has crossed ROS: the exact numbers a consumer node reads back from the messages the
// producer node sends (issue 32). The rollout engine connects the cores in one process and passes values
// through these, so that its flights and records are bit-identical to the ROS nodes'; quad_ros's conversions
// are tested against them (test_quad_ros: WireMatchesMessages).
#pragma once

#include <cmath>
#include <cstdint>

#include "quad_core/episode_key.h"
#include "quad_core/vehicle_state.h"

namespace quad_core {

// The odometry a consumer reads (quad_ros::ToVehicleState of quad_ros::ToOdometryMsg(s, stamp_ns)): the
// stamp's seconds, pose and world-frame velocity as they are, the angular velocity rotated to world axes
// (the simulator publishes it so; consumers read it into w_body: docs/CONVENTIONS.md), no acceleration.
inline VehicleState OdometryAsReceived(const VehicleState& s, uint64_t stamp_ns) {
  VehicleState r;
  r.t_s = StampSeconds(stamp_ns);
  r.p_world_body = s.p_world_body;
  r.q_world_body =
      Eigen::Quaterniond(s.q_world_body.w(), s.q_world_body.x(), s.q_world_body.y(), s.q_world_body.z());
  r.v_world = s.v_world;
  r.w_body = s.q_world_body * s.w_body;
  return r;
}

// A time in seconds after ros::Time(t).toSec(): rounded to whole nanoseconds as ros::Time::fromSec does
// (floor for the seconds, round half away from zero for the nanoseconds).
inline double RosTimeRoundTrip(double t_s) {
  uint64_t sec = static_cast<uint64_t>(std::floor(t_s));
  uint64_t nsec = static_cast<uint64_t>(std::round((t_s - static_cast<double>(sec)) * 1e9));
  sec += nsec / 1000000000ULL;
  nsec %= 1000000000ULL;
  return static_cast<double>(sec) + 1e-9 * static_cast<double>(nsec);
}

// A stamp in seconds as rospy reads it (rospy.Time.to_sec: seconds plus nanoseconds / 1e9), for decisions
// the Python nodes take (the episode manager's take-off, timeout and duration arithmetic).
inline double RospySeconds(uint64_t ns) {
  return static_cast<double>(ns / 1000000000ULL) + static_cast<double>(ns % 1000000000ULL) / 1e9;
}

}  // namespace quad_core
