// Message conversion and visualisation of fast_planner_node, in one place (the ROS side only: the planner's
// core, include/fast_planner, is ROS-free). Frames and units: docs/CONVENTIONS.md.
#pragma once

#include <geometry_msgs/TransformStamped.h>
#include <nav_msgs/Odometry.h>
#include <quad_core/camera.h>
#include <quad_core/vehicle_state.h>
#include <quad_msgs/Bspline.h>
#include <quad_msgs/PlanTiming.h>
#include <ros/time.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/PointCloud2.h>
#include <visualization_msgs/MarkerArray.h>

#include <Eigen/Core>

#include <memory>
#include <string>
#include <vector>

#include "fast_planner/odometry_history.h"
#include "fast_planner/planner_manager.h"
#include "fast_planner/voxel_map.h"

namespace fast_planner::ros_conv {

// The base_link -> camera transform as the camera's mount on the body.
CameraMount ToCameraMount(const geometry_msgs::TransformStamped& t);

// Why the depth image cannot be integrated ("" if it can): not 32FC1, no camera_info yet (k null), or a
// layout or size that does not match the camera_info (little-endian, dense rows). The text starts with
// "skipping depth frame".
std::string DepthFrameProblem(const sensor_msgs::Image& msg, const quad_core::CameraIntrinsics* k);
// The frame of an image without a problem: stamp, seq, intrinsics and a copy of the pixels (the pose is set
// by the caller).
std::shared_ptr<DepthFrame> ToDepthFrame(const sensor_msgs::Image& msg, const quad_core::CameraIntrinsics& k);

// The occupied voxel centres of the simulator's voxel map. Throws std::runtime_error if the cloud has no
// float x/y/z fields.
std::vector<Eigen::Vector3d> ToPoints(const sensor_msgs::PointCloud2& msg);

// A trajectory as quad_msgs/Bspline (order 3, knots, control points; no yaw points: the tracker faces the
// direction of travel, and so does the camera).
quad_msgs::Bspline ToBsplineMessage(const PlanResult& plan, const ros::Time& start_time);
// The labeller's answer to a frame without a plan: order 3, no knots or points.
quad_msgs::Bspline EmptyBsplineMessage(const ros::Time& start_time);
// One plan attempt's timing; map_update_ms is the frame's map update plus the ESDF computed on demand for
// this plan (map work too). status = the plan's reason.
quad_msgs::PlanTiming ToPlanTiming(const PlanResult& plan, const ros::Time& stamp,
                                   double frame_map_update_ms);

// rviz (config/rviz/sim.rviz, planner/markers): the front end's path, the trajectory sampled every 0.05 s and
// its control points.
visualization_msgs::MarkerArray PlanMarkers(const PlanResult& plan);
// The occupied and inflated voxels of the local window in a thin horizontal slice at the vehicle's height.
visualization_msgs::MarkerArray MapSliceMarkers(const VoxelMap& map, const Eigen::Vector3d& p_world_body);

}  // namespace fast_planner::ros_conv
