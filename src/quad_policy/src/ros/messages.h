// Message conversion of the C++ policy node, in one place (ROS side only: not part of the ROS-free core). The
// benchmark (quad_bench's policy_bench) times ToBsplineMessage as part of the decision latency. The Python
// node's conversions are quad_il/inference/messages.py.
#pragma once

#include <geometry_msgs/TransformStamped.h>
#include <nav_msgs/Odometry.h>
#include <quad_msgs/Bspline.h>
#include <quad_ros/vocabulary.h>
#include <ros/time.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <visualization_msgs/Marker.h>

#include <quad_policy/input_checks.h>
#include <quad_policy/safety.h>
#include <quad_policy/trajectory.h>

#include <Eigen/Geometry>

#include <algorithm>
#include <string>

namespace quad_policy {

// start_time: the depth frame's exact stamp (the trajectory's start_time_s is that stamp as a double). No yaw
// points: the tracker yaws along the direction of travel.
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
  m.yaw_dt = 0.0;
  return m;
}

// The trajectory sent, as a line strip sampled every 0.05 s in the world frame (config/rviz/sim.rviz).
inline visualization_msgs::Marker PlanMarker(const UniformBspline& s, const std_msgs::Header& header,
                                             const std::string& ns) {
  visualization_msgs::Marker m;
  m.header = header;
  m.header.frame_id = "world";
  m.ns = ns;
  m.type = visualization_msgs::Marker::LINE_STRIP;
  m.action = visualization_msgs::Marker::ADD;
  m.pose.orientation.w = 1.0;
  m.scale.x = 0.05;
  m.color.r = 0.1;
  m.color.g = 0.6;
  m.color.b = 1.0;
  m.color.a = 1.0;
  for (double t = 0.0;; t = std::min(t + 0.05, s.duration_s())) {
    const Eigen::Vector3d p = s.Position(t);
    geometry_msgs::Point q;
    q.x = p.x();
    q.y = p.y();
    q.z = p.z();
    m.points.push_back(q);
    if (t >= s.duration_s()) break;
  }
  return m;
}

inline Eigen::Isometry3d ToIsometry(const geometry_msgs::Transform& t) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::Quaterniond(t.rotation.w, t.rotation.x, t.rotation.y, t.rotation.z)
                   .normalized()
                   .toRotationMatrix();
  T.translation() = Eigen::Vector3d(t.translation.x, t.translation.y, t.translation.z);
  return T;
}

// The frame's camera: CameraInfo's intrinsics and the pose T_world_body(odometry) T_body_camera.
inline CameraModel ToCameraModel(const sensor_msgs::CameraInfo& info, const VehicleState& state,
                                 const Eigen::Isometry3d& T_body_camera) {
  CameraModel c;
  c.intrinsics.width = static_cast<int>(info.width);
  c.intrinsics.height = static_cast<int>(info.height);
  c.intrinsics.fx = info.K[0];
  c.intrinsics.fy = info.K[4];
  c.intrinsics.cx = info.K[2];
  c.intrinsics.cy = info.K[5];
  Eigen::Isometry3d T_world_body = Eigen::Isometry3d::Identity();
  T_world_body.linear() = state.q_world_body.normalized().toRotationMatrix();
  T_world_body.translation() = state.p_world_body;
  c.T_world_camera = T_world_body * T_body_camera;
  return c;
}

// A view of a 32FC1 little-endian depth image's data; "" in *problem when usable, else the reason
// (DepthLayoutProblem), and the view is empty.
inline DepthImageView DepthView(const sensor_msgs::Image& img, std::string* problem) {
  *problem = DepthLayoutProblem(
      {img.encoding, img.is_bigendian != 0, img.width, img.height, img.step, img.data.size()});
  if (!problem->empty()) return DepthImageView{};
  return quad_ros::DepthViewOf(img);
}

}  // namespace quad_policy
