// Message conversion of quad_sim_node, in one place: simulator state to ROS messages (odometry, TF, depth
// image and camera info, episode status, statistics, world markers, voxel map) and ROS messages to the
// simulator's inputs (commands, reset requests). No ROS communication here: the node publishes and
// subscribes.
#pragma once

#include "quad_core/camera.h"
#include "quad_core/depth_image.h"
#include "quad_core/vehicle_state.h"
#include "quad_sim/commands.h"
#include "quad_sim/episode_request.h"
#include "quad_sim/sim_config.h"
#include "quad_sim/simulator.h"

#include <geometry_msgs/Point.h>
#include <nav_msgs/Odometry.h>
#include <quad_msgs/EpisodeStatus.h>
#include <quad_msgs/ResetEpisode.h>
#include <quad_msgs/SO3Command.h>
#include <quad_msgs/SimStats.h>
#include <quad_msgs/TRPYCommand.h>
#include <ros/time.h>
#include <rosgraph_msgs/Clock.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/PointCloud2.h>
#include <std_msgs/Float64.h>
#include <tf2_msgs/TFMessage.h>
#include <visualization_msgs/MarkerArray.h>
#include <Eigen/Core>

#include <cstdint>
#include <vector>

namespace quad_sim_ros {

ros::Time StampOf(uint64_t stamp_ns);
geometry_msgs::Point ToPoint(const Eigen::Vector3d& v);
rosgraph_msgs::Clock ToClock(const ros::Time& now);
std_msgs::Float64 ToFloat64(double value);

// Odometry, depth images and camera info: quad_ros/vocabulary.h (shared by every node).
// The world -> base_link transform of an odometry message.
tf2_msgs::TFMessage ToTf(const nav_msgs::Odometry& odom);
// The simulator's only static transform: base_link -> camera (the camera mount).
tf2_msgs::TFMessage CameraMountTf(const quad_sim::DepthCameraConfig& camera, const ros::Time& stamp);

// The episode's status; lockstep timeouts so far are appended to the reason when there are any.
quad_msgs::EpisodeStatus ToEpisodeStatus(const quad_sim::Simulator& sim, const ros::Time& now,
                                         const ros::Time& episode_start, uint64_t command_timeouts,
                                         uint64_t ack_timeouts);

struct SimCounts {
  double real_time_factor = 0.0;
  uint64_t command_timeouts = 0;
  uint64_t ack_timeouts = 0;
  uint64_t rejected_commands = 0;
  uint64_t odometry = 0;
  uint64_t depth_frames = 0;
};
quad_msgs::SimStats ToSimStats(const quad_sim::Simulator& sim, const ros::Time& now, const SimCounts& counts);

// The world's boxes (coloured by height), the ground, the goal sphere and the vehicle box (frame_locked to
// base_link), after a DELETEALL.
visualization_msgs::MarkerArray WorldMarkers(const quad_sim::Simulator& sim, const ros::Time& stamp);
// Occupied voxel centres as an xyz PointCloud2 in `world`.
sensor_msgs::PointCloud2 ToCloud(const std::vector<Eigen::Vector3f>& points, const ros::Time& stamp);

// Commands in. All-zero attitude gains (the message default, never a usable attitude loop) keep the onboard
// defaults of kr_mav_control (kR 1.5/1.5/1.0, kOm 0.13/0.13/0.1), as an autopilot keeps its own gains.
quad_sim::So3Command FromMsg(const quad_msgs::SO3Command& msg);
quad_sim::TrpyCommand FromMsg(const quad_msgs::TRPYCommand& msg);
quad_sim::EpisodeRequest FromMsg(const quad_msgs::ResetEpisode::Request& req);

}  // namespace quad_sim_ros
