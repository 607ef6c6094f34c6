// The vehicle's odometry as every component exchanges it (nav_msgs/Odometry with the twist in the world
// frame; frames and units: docs/CONVENTIONS.md). The simulator's integration state (motor speeds included) is
// quad_sim::DynamicsState; what it publishes is this.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace quad_core {

struct VehicleState {
  double t_s = 0.0;                                        // stamp of the odometry (sim time)
  Eigen::Vector3d p_world_body = Eigen::Vector3d::Zero();  // centre of mass in the world frame (m)
  Eigen::Vector3d v_world = Eigen::Vector3d::Zero();       // velocity, world frame (m/s)
  Eigen::Quaterniond q_world_body = Eigen::Quaterniond::Identity();
  Eigen::Vector3d w_body = Eigen::Vector3d::Zero();  // angular velocity in body axes (rad/s)
  // Measured acceleration, used only when has_accel (nav_msgs/Odometry carries none).
  bool has_accel = false;
  Eigen::Vector3d a_world = Eigen::Vector3d::Zero();

  // Every field finite and the quaternion not degenerate (norm > 0.5).
  bool AllFinite() const;
  // Heading of the body x axis projected on the world xy plane, in (-pi, pi].
  double Yaw() const;
};

// Wraps an angle to (-pi, pi].
double WrapAngle(double a_rad);

}  // namespace quad_core
