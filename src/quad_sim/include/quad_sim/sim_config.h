// The simulator's configuration (config/sim.yaml), loaded strictly into one typed struct. The vehicle's
// physical parameters come from the file named by `vehicle_file` (config/vehicle.yaml), shared with the
// controller.
#pragma once

#include "quad_core/lockstep_gate.h"
#include "quad_core/vehicle_params.h"
#include "quad_sim/depth_camera.h"
#include "quad_sim/dynamics.h"
#include "quad_sim/voxel_map.h"
#include "quad_sim/world.h"

#include <Eigen/Core>

#include <cstdint>
#include <string>
#include <vector>

namespace quad_sim {

// What happens after the vehicle hits a box (or crashes into the ground).
enum class CollisionPolicy {
  kFreeze,    // the episode ends and the vehicle is held at the contact pose
  kContinue,  // the collision is recorded, the episode goes on and the vehicle passes through
};

// What the onboard controller does when no command arrived for stale_command.timeout_s (sim time).
enum class StaleCommandAction {
  kLand,       // level attitude, current yaw, descend at descent_rate_mps, motors off once landed
  kMotorsOff,  // cut the motors at once
};

enum class TimeMode {
  kRealTime,        // sim time follows wall time
  kRealTimeFactor,  // sim time runs real_time_factor times as fast as wall time
  kAsFastAsPossible,
  kLockstep,  // as fast as possible, but waits for commands and depth acks (see docs/CONVENTIONS.md)
};

const char* ToString(CollisionPolicy p);
const char* ToString(StaleCommandAction a);
const char* ToString(TimeMode m);

struct GroundCrashConfig {
  double max_landing_speed_mps = 1.0;  // touchdown faster than this (vertical) is a crash into the ground
  double max_landing_horizontal_speed_mps = 1.0;
  double max_landing_tilt_deg = 30.0;
};

struct StaleCommandConfig {
  double timeout_s = 0.25;
  StaleCommandAction action = StaleCommandAction::kLand;
  double descent_rate_mps = 0.5;
  double vertical_gain_per_s = 2.0;  // thrust = m (g + gain (v_des - v_z)) during the landing
};

struct EpisodeConfig {
  double goal_tolerance_m = 0.5;
  double max_duration_s = 0.0;  // 0: no limit
};

// The engine's spawn frame, as Unreal/AirSim's: origin at origin_world_m, lengths in units_per_m units per
// metre. set_z_offset measures the vertical gap between it and the ROS world frame at start-up (see
// SpawnFrame).
struct SpawnFrameConfig {
  Eigen::Vector3d origin_world_m = Eigen::Vector3d::Zero();
  double units_per_m = 1.0;
};

struct TimeConfig {
  TimeMode mode = TimeMode::kRealTime;
  double real_time_factor = 1.0;  // for kRealTimeFactor
  double clock_period_s = 0.001;  // /clock publication period (sim time)
};

struct LockstepConfig {
  std::vector<std::string> depth_consumers;  // FrameAck.consumer names waited for after every depth frame
  bool wait_for_command = false;             // wait for the command stamped with each odometry stamp
  double timeout_s = 2.0;                    // wall-clock time per wait; timeouts are counted and logged

  // The lockstep gate's configuration (quad_core/lockstep_gate.h).
  quad_core::LockstepGateConfig Gate() const {
    quad_core::LockstepGateConfig g;
    g.depth_consumers = depth_consumers;
    g.wait_for_command = wait_for_command;
    g.timeout_s = timeout_s;
    return g;
  }
};

struct SimConfig {
  std::string vehicle_file;  // resolved path of the vehicle YAML
  quad_core::VehicleParams vehicle;
  double physics_dt_s = 0.001;
  double odometry_rate_hz = 200.0;
  GroundContactParams ground_contact;
  GroundCrashConfig ground_crash;
  DepthCameraConfig camera;
  CollisionPolicy collision_policy = CollisionPolicy::kFreeze;
  StaleCommandConfig stale_command;
  EpisodeConfig episode;
  // Default episode: world from world_file (if not empty) or generated with world_gen and world_seed.
  std::string world_file;
  uint64_t world_seed = 1;
  WorldGenConfig world_gen;  // its clear zones include the start and the goal (world_gen.clear_radius_m)
  Eigen::Vector3d start_m = Eigen::Vector3d(-18.0, 0.0, 0.125);
  double start_yaw_rad = 0.0;
  Eigen::Vector3d goal_m = Eigen::Vector3d(18.0, 0.0, 1.5);
  VoxelMapConfig voxel_map;
  std::string octomap_file;  // where the node writes the .bt export ("" = none)
  SpawnFrameConfig spawn_frame;
  TimeConfig time;
  LockstepConfig lockstep;
  uint64_t noise_seed = 0;  // seed of the depth noise generator (combined with the episode's world seed)

  // A config with every default (the vehicle must still be set); used by tests.
  void Validate() const;  // throws std::invalid_argument naming the field
};

// Loads config/sim.yaml (and the vehicle file it names, relative to its own directory). Throws
// quad_core::ConfigError naming the file and key for missing, unknown or out-of-range keys.
SimConfig LoadSimConfig(const std::string& yaml_path);

}  // namespace quad_sim
