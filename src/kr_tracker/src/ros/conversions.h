// Message conversion of kr_tracker_node, in one place (the ROS side only: kr_tracker_core is ROS-free).
// Frames and units: docs/CONVENTIONS.md.
#pragma once

#include <nav_msgs/Odometry.h>
#include <quad_core/vehicle_state.h>
#include <quad_msgs/Bspline.h>
#include <quad_msgs/PositionCommand.h>
#include <quad_msgs/SO3Command.h>

#include "kr_tracker/bspline_tracker.h"
#include "kr_tracker/config.h"
#include "kr_tracker/so3_controller.h"
#include "kr_tracker/types.h"

namespace kr_tracker::ros_conv {

inline void ToVector3(const Eigen::Vector3d& v, geometry_msgs::Vector3* m) {
  m->x = v.x();
  m->y = v.y();
  m->z = v.z();
}

// A TrackBspline goal's B-spline as the tracker takes it (validated by the tracker).
inline BsplineGoalSpec ToGoalSpec(const quad_msgs::Bspline& b) {
  BsplineGoalSpec s;
  s.order = b.order;
  s.traj_id = b.traj_id;
  s.start_time_s = b.start_time.toSec();
  s.knots = b.knots;
  s.pos_pts.resize(static_cast<Eigen::Index>(b.pos_pts.size()), 3);
  for (size_t i = 0; i < b.pos_pts.size(); ++i) {
    s.pos_pts.row(static_cast<Eigen::Index>(i)) << b.pos_pts[i].x, b.pos_pts[i].y, b.pos_pts[i].z;
  }
  s.yaw_pts = b.yaw_pts;
  s.yaw_dt_s = b.yaw_dt;
  return s;
}

// The controller's command (frame world), with the vehicle's current yaw in aux.
inline quad_msgs::SO3Command ToSo3Command(const So3Command& c, const ros::Time& stamp,
                                          double current_yaw_rad) {
  quad_msgs::SO3Command m;
  m.header.stamp = stamp;
  m.header.frame_id = "world";
  ToVector3(c.force_world_N, &m.force);
  m.orientation.w = c.q_world_des.w();
  m.orientation.x = c.q_world_des.x();
  m.orientation.y = c.q_world_des.y();
  m.orientation.z = c.q_world_des.z();
  ToVector3(c.w_body_des_radps, &m.angular_velocity);
  for (int i = 0; i < 3; ++i) {
    m.kR[i] = c.kR[i];
    m.kOm[i] = c.kOm[i];
  }
  m.aux.current_yaw = current_yaw_rad;
  m.aux.kf_correction = 0.0;
  m.aux.enable_motors = c.enable_motors;
  m.aux.use_external_yaw = false;
  return m;
}

// The reference the command was computed for, with the position and velocity gains used.
inline quad_msgs::PositionCommand ToPositionCommand(const PositionReference& ref,
                                                    const std_msgs::Header& header, const So3Gains& gains) {
  quad_msgs::PositionCommand p;
  p.header = header;
  p.position.x = ref.p_world.x();
  p.position.y = ref.p_world.y();
  p.position.z = ref.p_world.z();
  ToVector3(ref.v_world, &p.velocity);
  ToVector3(ref.a_world, &p.acceleration);
  ToVector3(ref.j_world, &p.jerk);
  p.yaw = ref.yaw_rad;
  p.yaw_dot = ref.yaw_rate_radps;
  for (int i = 0; i < 3; ++i) {
    p.kx[i] = gains.kx[i];
    p.kv[i] = gains.kv[i];
  }
  p.use_msg_gains_flags = quad_msgs::PositionCommand::USE_MSG_GAINS_NONE;
  return p;
}

}  // namespace kr_tracker::ros_conv
