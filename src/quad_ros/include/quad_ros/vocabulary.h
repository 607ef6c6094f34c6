// ROS messages <-> quad_core's vocabulary, written once for every node (docs/CONVENTIONS.md, Layers):
// odometry, camera intrinsics, depth images. Each node package's src/ros/ module converts only its own
// component's messages and calls these for the shared ones. Header-only; ROS message headers and quad_core
// only.
#pragma once

#include <nav_msgs/Odometry.h>
#include <ros/time.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <std_msgs/Header.h>

#include <cstdint>
#include <cstring>

#include "quad_core/camera.h"
#include "quad_core/depth_image.h"
#include "quad_core/vehicle_state.h"

namespace quad_ros {

// nav_msgs/Odometry -> VehicleState: stamp, pose, the world-frame linear velocity (CONVENTIONS: the twist is
// in the world frame) and the message's angular velocity taken as it is into w_body. Note: the simulator
// publishes the angular velocity in the world frame (ToOdometryMsg), so w_body holds world axes here, as it
// always has (recorded in the shards' w_body); no consumer's decision uses it.
inline quad_core::VehicleState ToVehicleState(const nav_msgs::Odometry& msg) {
  quad_core::VehicleState s;
  s.t_s = msg.header.stamp.toSec();
  const auto& p = msg.pose.pose.position;
  const auto& q = msg.pose.pose.orientation;
  const auto& v = msg.twist.twist.linear;
  const auto& w = msg.twist.twist.angular;
  s.p_world_body = Eigen::Vector3d(p.x, p.y, p.z);
  s.q_world_body = Eigen::Quaterniond(q.w, q.x, q.y, q.z);
  s.v_world = Eigen::Vector3d(v.x, v.y, v.z);
  s.w_body = Eigen::Vector3d(w.x, w.y, w.z);
  return s;
}

// VehicleState -> nav_msgs/Odometry (frame `world`, child `base_link`): the twist in the world frame, the
// angular velocity rotated from body to world axes.
inline nav_msgs::Odometry ToOdometryMsg(const quad_core::VehicleState& s, const ros::Time& stamp) {
  nav_msgs::Odometry o;
  o.header.stamp = stamp;
  o.header.frame_id = "world";
  o.child_frame_id = "base_link";
  o.pose.pose.position.x = s.p_world_body.x();
  o.pose.pose.position.y = s.p_world_body.y();
  o.pose.pose.position.z = s.p_world_body.z();
  o.pose.pose.orientation.x = s.q_world_body.x();
  o.pose.pose.orientation.y = s.q_world_body.y();
  o.pose.pose.orientation.z = s.q_world_body.z();
  o.pose.pose.orientation.w = s.q_world_body.w();
  const Eigen::Vector3d w_world = s.q_world_body * s.w_body;
  o.twist.twist.linear.x = s.v_world.x();
  o.twist.twist.linear.y = s.v_world.y();
  o.twist.twist.linear.z = s.v_world.z();
  o.twist.twist.angular.x = w_world.x();
  o.twist.twist.angular.y = w_world.y();
  o.twist.twist.angular.z = w_world.z();
  return o;
}

// sensor_msgs/CameraInfo's K -> intrinsics (no validation: see CameraIntrinsics::Validate).
inline quad_core::CameraIntrinsics ToIntrinsics(const sensor_msgs::CameraInfo& msg) {
  return quad_core::CameraIntrinsics{
      static_cast<int>(msg.width), static_cast<int>(msg.height), msg.K[0], msg.K[4], msg.K[2], msg.K[5]};
}

// Intrinsics -> sensor_msgs/CameraInfo of an undistorted pinhole camera.
inline sensor_msgs::CameraInfo ToCameraInfo(const quad_core::CameraIntrinsics& k,
                                            const std_msgs::Header& header) {
  sensor_msgs::CameraInfo c;
  c.header = header;
  c.width = k.width;
  c.height = k.height;
  c.distortion_model = "plumb_bob";
  c.D.assign(5, 0.0);
  c.K = {k.fx, 0, k.cx, 0, k.fy, k.cy, 0, 0, 1};
  c.R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  c.P = {k.fx, 0, k.cx, 0, 0, k.fy, k.cy, 0, 0, 0, 1, 0};
  return c;
}

// A depth image -> sensor_msgs/Image 32FC1 little-endian in the `camera` frame.
inline sensor_msgs::Image ToImageMsg(const quad_core::DepthImage& img, const ros::Time& stamp, uint32_t seq) {
  sensor_msgs::Image m;
  m.header.stamp = stamp;
  m.header.frame_id = "camera";
  m.header.seq = seq;
  m.width = img.width;
  m.height = img.height;
  m.encoding = "32FC1";
  m.is_bigendian = 0;
  m.step = img.width * sizeof(float);
  m.data.resize(img.depth_m.size() * sizeof(float));
  std::memcpy(m.data.data(), img.depth_m.data(), m.data.size());
  return m;
}

// A view of a 32FC1 little-endian image's pixels (rows `step` bytes apart). The caller has checked the layout
// (encoding, endianness, step a multiple of 4 and >= width * 4, data.size() >= step * height): the nodes
// report a bad layout with their own message first.
inline quad_core::DepthImageView DepthViewOf(const sensor_msgs::Image& msg) {
  return quad_core::DepthImageView{static_cast<int>(msg.width), static_cast<int>(msg.height),
                                   static_cast<std::size_t>(msg.step / sizeof(float)),
                                   reinterpret_cast<const float*>(msg.data.data())};
}

}  // namespace quad_ros
