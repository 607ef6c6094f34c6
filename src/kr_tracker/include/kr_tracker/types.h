// Plain data exchanged between the trackers, the SO(3) controller and the node (ROS-free).
#pragma once

#include <Eigen/Geometry>

namespace kr_tracker {

// Odometry of the vehicle (nav_msgs/Odometry with the twist in the world frame, CONVENTIONS.md).
struct VehicleState {
  double t_s = 0.0;  // stamp of the odometry
  Eigen::Vector3d p_world_body = Eigen::Vector3d::Zero();
  Eigen::Vector3d v_world = Eigen::Vector3d::Zero();
  Eigen::Quaterniond q_world_body = Eigen::Quaterniond::Identity();
  Eigen::Vector3d w_body = Eigen::Vector3d::Zero();
  // Measured acceleration, used only when has_accel (nav_msgs/Odometry carries none; see So3Controller).
  bool has_accel = false;
  Eigen::Vector3d a_world = Eigen::Vector3d::Zero();

  bool AllFinite() const;
  double Yaw() const;  // rotation about world z, in (-pi, pi]
};

// The reference a tracker produces each control period: kr_mav_msgs/PositionCommand's fields.
struct PositionReference {
  Eigen::Vector3d p_world = Eigen::Vector3d::Zero();
  Eigen::Vector3d v_world = Eigen::Vector3d::Zero();
  Eigen::Vector3d a_world = Eigen::Vector3d::Zero();
  Eigen::Vector3d j_world = Eigen::Vector3d::Zero();
  double yaw_rad = 0.0;
  double yaw_rate_radps = 0.0;

  bool AllFinite() const;
  // Hold a pose: position and yaw, zero derivatives.
  static PositionReference Hold(const Eigen::Vector3d& p_world, double yaw_rad);
};

// The controller's output: kr_mav_msgs/SO3Command's fields (force in the world frame, desired attitude,
// desired body angular velocity, attitude gains for the onboard controller).
struct So3Command {
  Eigen::Vector3d force_world_N = Eigen::Vector3d::Zero();
  Eigen::Quaterniond q_world_des = Eigen::Quaterniond::Identity();
  Eigen::Vector3d w_body_des_radps = Eigen::Vector3d::Zero();
  Eigen::Vector3d kR = Eigen::Vector3d::Zero();
  Eigen::Vector3d kOm = Eigen::Vector3d::Zero();
  bool enable_motors = true;

  bool AllFinite() const;
};

// Wraps an angle to (-pi, pi].
double WrapAngle(double a_rad);

}  // namespace kr_tracker
