// Plain data exchanged between the trackers, the SO(3) controller and the node (ROS-free).
#pragma once

#include <Eigen/Geometry>

#include "quad_core/vehicle_state.h"

namespace kr_tracker {

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

}  // namespace kr_tracker
