// What a reset asks for (quad_msgs/ResetEpisode without ROS) and the episode it resolves to.
#pragma once

#include "quad_sim/sim_config.h"
#include "quad_sim/world.h"

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cstdint>
#include <string>

namespace quad_sim {

struct EpisodeRequest {
  uint64_t seed = 0;       // world seed; 0: the configured world (world_file, else world_seed)
  std::string world_file;  // a world YAML to load instead ("" = none)
  // Start pose and goal; a zero start orientation (all four coefficients 0, the message default) selects the
  // configured start pose and goal.
  Eigen::Vector3d start_world_m = Eigen::Vector3d::Zero();
  Eigen::Vector4d q_start_wxyz = Eigen::Vector4d::Zero();
  Eigen::Vector3d goal_world_m = Eigen::Vector3d::Zero();
  // Keyed episode (issue 32, quad_core/episode_key.h): true -> starts at quad_core::EpisodeStartNs(index)
  // with the id EpisodeIdOf(index) (TimeKeeper::BeginEpisode); false -> one odometry period after the last
  // stamp with the simulator's next unkeyed id.
  bool keyed = false;
  uint32_t episode_index = 0;
};

struct EpisodeSetup {
  World world;
  Eigen::Vector3d start_world_m;
  double start_yaw_rad = 0.0;
  Eigen::Vector3d goal_world_m;
};

// The world (the request's file; else the configured file if the seed is 0; else generated from the seed or
// world_seed, with this episode's start and goal kept clear instead of the configured ones) and the pose.
// Throws (std::invalid_argument, ConfigError of a world file) for a non-finite start orientation or a world
// that cannot be loaded or generated.
EpisodeSetup ResolveEpisode(const SimConfig& config, const EpisodeRequest& request);

}  // namespace quad_sim
