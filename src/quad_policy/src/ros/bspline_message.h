// quad_policy::UniformBspline -> quad_msgs/Bspline, shared by policy_node and the benchmark (which times it
// as part of the decision latency). ROS side only: not part of the ROS-free core.
#pragma once

#include <quad_msgs/Bspline.h>
#include <ros/time.h>

#include <quad_policy/trajectory.h>

namespace quad_policy {

// start_time: the depth frame's exact stamp (the trajectory's start_time_s is that stamp as a double).
inline quad_msgs::Bspline ToBsplineMessage(const UniformBspline& s, int64_t traj_id,
                                           const ros::Time& start_time) {
  quad_msgs::Bspline m;
  m.order = 3;
  m.traj_id = traj_id;
  m.start_time = start_time;
  m.knots = s.Knots();
  m.pos_pts.resize(s.ctrl_world.rows());
  for (int i = 0; i < s.ctrl_world.rows(); ++i) {
    m.pos_pts[i].x = s.ctrl_world(i, 0);
    m.pos_pts[i].y = s.ctrl_world(i, 1);
    m.pos_pts[i].z = s.ctrl_world(i, 2);
  }
  // No yaw points: the tracker yaws along the direction of travel. Else the heading on the same knots.
  m.yaw_pts = s.yaw_ctrl;
  m.yaw_dt = s.yaw_ctrl.empty() ? 0.0 : s.knot_dt_s;
  return m;
}

}  // namespace quad_policy
