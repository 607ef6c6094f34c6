// quad_sim::Simulator: the ROS-free simulator core. Tests and benchmarks of every package drive it
// in-process; quad_sim_node wraps it with topics, services and sim time.
//
//   quad_sim::SimConfig cfg = quad_sim::LoadSimConfig("config/sim.yaml");
//   quad_sim::Simulator sim(cfg);
//   sim.Reset(quad_sim::GenerateWorld(cfg.world_gen, seed), p_start, yaw, goal);
//   while (sim.episode().active) {
//     if (sim.OdometryDue()) sim.SetSo3Command(controller.Update(sim.state()));
//     if (sim.DepthDue()) planner.OnDepth(sim.RenderDepth());
//     sim.Step();   // 1 kHz: onboard attitude control, motors, RK4 rigid body, collision check, episode
//     outcome
//   }
#pragma once

#include "quad_core/episode_key.h"
#include "quad_sim/attitude_controller.h"
#include "quad_sim/collision.h"
#include "quad_sim/commands.h"
#include "quad_sim/depth_camera.h"
#include "quad_sim/dynamics.h"
#include "quad_sim/sim_config.h"
#include "quad_sim/voxel_map.h"
#include "quad_sim/world.h"
#include "quad_sim/world_index.h"

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cstdint>
#include <memory>
#include <optional>
#include <random>
#include <string>

namespace quad_sim {

// Box ids in collision reports: a world box index, or one of these (as quad_msgs/EpisodeStatus).
constexpr int kCollisionNone = kHitNone;
constexpr int kCollisionGround = kHitGround;

struct CollisionInfo {
  bool collided = false;
  double time_s = 0.0;             // sim time (episode time) of the first penetrating contact
  int box_index = kCollisionNone;  // world box index, kCollisionGround or kCollisionNone
  Eigen::Vector3d point_world_m = Eigen::Vector3d::Zero();
  int num_collisions = 0;  // contact onsets so far (more than one only with CollisionPolicy::kContinue)
};

enum class EpisodeOutcome { kRunning, kCollided, kReachedGoal, kTimedOut, kNumericalFailure };
const char* ToString(EpisodeOutcome o);

struct EpisodeState {
  uint32_t episode_id = 0;
  EpisodeOutcome outcome = EpisodeOutcome::kRunning;
  bool active = false;  // false once the episode has ended
  bool reached_goal = false;
  double reached_goal_time_s = 0.0;
  CollisionInfo collision;
  std::string reason =
      "not started";  // "running", "collision with box 17 at t=12.340 s", "goal reached", ...
};

// The engine's spawn frame (as Unreal/AirSim's: another origin and unit) and the set_z_offset calibration.
struct SpawnFrame {
  Eigen::Vector3d origin_world_m = Eigen::Vector3d::Zero();
  double units_per_m = 1.0;
  Eigen::Vector3d ToSpawn(const Eigen::Vector3d& p_world) const {
    return (p_world - origin_world_m) * units_per_m;
  }
  Eigen::Vector3d FromSpawn(const Eigen::Vector3d& p_spawn) const {
    return p_spawn / units_per_m + origin_world_m;
  }
};

class Simulator {
 public:
  explicit Simulator(const SimConfig& config);
  ~Simulator();
  Simulator(const Simulator&) = delete;
  Simulator& operator=(const Simulator&) = delete;

  // Starts a new episode at time 0: the vehicle at rest, level, at p_start_world with the given yaw (on the
  // ground with motors off when its box touches the ground, else hovering at trim until commands arrive).
  // episode_id: the episode's id (a keyed episode's quad_core::EpisodeIdOf(index)); nullopt: the next unkeyed
  // id, counting from quad_core::kUnkeyedEpisodeIdBase, so that it never equals a keyed one. A failed reset
  // uses no id.
  // Throws std::invalid_argument with a clear message for non-finite input, a start box intersecting a world
  // box or the ground, or an invalid world.
  void Reset(const World& world, const Eigen::Vector3d& p_start_world, double yaw_start_rad,
             const Eigen::Vector3d& goal_world, std::optional<uint32_t> episode_id = std::nullopt);
  // The configured default episode: world_file or GenerateWorld(world_gen + start/goal clear zones, seed).
  void ResetDefault(uint64_t seed);

  // Commands for the onboard attitude controller; NaN/Inf or invalid values are rejected with a reason and
  // leave the state and the previous command untouched.
  CommandStatus SetSo3Command(const So3Command& cmd);
  CommandStatus SetTrpyCommand(const TrpyCommand& cmd);

  // One physics step (config.physics_dt_s, 1 kHz by default): command staleness, attitude control, motors,
  // RK4, collision check, goal and timeout.
  void Step();

  double time_s() const { return static_cast<double>(step_count_) * config_.physics_dt_s; }
  uint64_t step_count() const { return step_count_; }
  // Whether the current time is an odometry / depth frame time (odometry every 1/rate; depth frame k at the
  // first step at or after k / rate).
  bool OdometryDue() const;
  bool DepthDue() const;

  const DynamicsState& state() const { return state_; }
  // Rotor speed commands applied during the last step.
  const Eigen::Vector4d& motor_commands_radps() const { return motor_cmd_; }
  bool command_stale() const { return command_stale_; }
  bool on_ground() const { return in_ground_contact_; }
  int num_rejected_commands() const { return num_rejected_commands_; }

  // Depth image from the current pose (plus the optional noise).
  quad_core::DepthImage RenderDepth();
  const quad_core::CameraIntrinsics& camera_intrinsics() const { return config_.camera.intrinsics; }
  // Camera optical frame in the world at the current state.
  void CameraPoseWorld(Eigen::Vector3d* p_world_camera, Eigen::Quaterniond* q_world_camera) const;

  const CollisionInfo& collision() const { return episode_.collision; }
  const EpisodeState& episode() const { return episode_; }

  // Exact minimum distance between the vehicle's collision box and any world box at the current state (the
  // ground is excluded: resting on it is not a near miss). +Inf in an empty world.
  double ClearanceToObstacles() const;
  // The same for any box (e.g. the vehicle box at another pose).
  ClearanceResult Clearance(const OrientedBox& box) const { return index_.Clearance(box); }
  // The vehicle's collision box at the current state.
  OrientedBox VehicleBox() const;

  const World& world() const { return world_; }
  const WorldIndex& world_index() const { return index_; }
  const Eigen::Vector3d& goal_world() const { return goal_world_; }
  const SimConfig& config() const { return config_; }
  // The global voxel map of the current world (config.voxel_map), computed on request.
  VoxelMap ComputeVoxelMap() const { return VoxelMap::FromWorld(world_, config_.voxel_map); }

  // Engine view for set_z_offset: the vehicle position and the ground height under it, as the engine reports
  // them in its spawn frame (config.spawn_frame).
  const SpawnFrame& spawn_frame() const { return spawn_frame_; }
  Eigen::Vector3d VehiclePositionInSpawnFrame() const { return spawn_frame_.ToSpawn(state_.p_world_body); }
  // Casts a ray straight down from the vehicle to the ground plane and returns the hit's z in the spawn
  // frame.
  double GroundHeightInSpawnFrame() const;
  // The set_z_offset calibration (thesis section 3.3): the vertical gap between the engine's spawn frame and
  // the world frame, measured from the engine's own ground query.
  double MeasureZOffset() const { return -GroundHeightInSpawnFrame() / config_.spawn_frame.units_per_m; }
  // What the simulator publishes as odometry at sim time t_s: the dynamics state, with the position read
  // through the engine's spawn frame and mapped to `world` with the measured z offset (as a ROS bridge of an
  // engine does), so the calibration is exercised on every message.
  quad_core::VehicleState Odometry(double z_offset_m, double t_s) const;

 private:
  AttitudeTarget StaleTarget() const;
  void CheckCollisions();
  void EndEpisode(EpisodeOutcome outcome, const std::string& reason);

  SimConfig config_;
  QuadrotorDynamics dynamics_;
  AttitudeController attitude_;
  DepthRenderer renderer_;
  CollisionChecker collision_checker_;
  WorldIndex index_;
  World world_;
  SpawnFrame spawn_frame_;
  Eigen::Vector3d goal_world_ = Eigen::Vector3d::Zero();

  DynamicsState state_;
  AttitudeTarget target_;
  Eigen::Vector4d motor_cmd_ = Eigen::Vector4d::Zero();
  uint64_t step_count_ = 0;
  uint64_t last_command_step_ = 0;
  bool command_stale_ = false;
  bool frozen_ = false;
  bool in_ground_contact_ = false;
  double landed_since_s_ = -1.0;
  int num_rejected_commands_ = 0;
  std::vector<int> boxes_in_contact_;
  EpisodeState episode_;
  uint32_t next_episode_id_ = quad_core::kUnkeyedEpisodeIdBase;
  std::mt19937_64 noise_rng_;
};

}  // namespace quad_sim
