// The rollout engine's vocabulary (issue 32, docs/engine.md): configs loaded once per worker, an episode's
// key and spec, the collection's episode logic (what nodes/episode_manager.py decides at each held frame) and
// what a flown episode returns. ROS-free.
#pragma once

#include <cpp_data_collector/plan_record.h>
#include <fast_planner/expert_session.h>
#include <fast_planner/planner_config.h>
#include <fast_planner/voxel_map.h>
#include <kr_tracker/config.h>
#include <quad_core/camera.h>
#include <quad_core/vehicle_params.h>
#include <quad_sim/sim_config.h>
#include <quad_sim/simulator.h>
#include <quad_sim/world.h>

#include <Eigen/Core>

#include <cstdint>
#include <initializer_list>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace quad_engine {

// The config files of collect.launch, loaded strictly once (each loader's errors name the file and key).
struct ConfigPaths {
  std::string sim;      // config/sim.yaml
  std::string planner;  // config/planner.yaml (or an overlay merged by the caller into a file)
  std::string tracker;  // config/tracker.yaml
  std::string vehicle;  // config/vehicle.yaml (the tracker's; the simulator's comes from sim.yaml)
};

struct Configs {
  quad_sim::SimConfig sim;
  fast_planner::PlannerConfig planner;
  kr_tracker::TrackerConfig tracker;
  quad_core::VehicleParams vehicle;
};

Configs LoadConfigs(const ConfigPaths& paths);

// One episode of a run, named by (seed, index): quad_il.collection.episodes.plan_episode draws the start
// (on the ground below `start_world`), its yaw and the goal from that key.
struct EpisodeSpec {
  int64_t index = 0;
  uint64_t seed = 0;
  Eigen::Vector3d start_world = Eigen::Vector3d::Zero();  // the take-off's target (altitude included)
  double start_yaw_rad = 0.0;
  Eigen::Vector3d goal_world = Eigen::Vector3d::Zero();
};

// config/collect.yaml's limits (quad_il.collection.episodes.CollectConfig).
struct EpisodeLimits {
  double takeoff_timeout_s = 15.0;
  double episode_timeout_s = 40.0;
  uint64_t max_samples = 0;     // 0: no limit
  uint64_t samples_before = 0;  // samples the run recorded before this episode (for max_samples)
};

// What the episode manager of collect.launch does, as in nodes/episode_manager.py: the vehicle rests on the
// ground below the start; at the episode's first frame it takes off (tracker goto); at the first frame where
// it is within kTakeoffToleranceM of the start and slower than kTakeoffMaxSpeedMps the expert gets the goal;
// the episode ends at the first frame where the simulator's status says goal reached, collision or ended,
// where episode_timeout_s have passed since the goal, or where max_samples are recorded. Times are the
// frames' stamps as rospy reads them (quad_core::RospySeconds).
constexpr double kGroundZM = 0.125;  // the vehicle box's half height: the start rests on the ground
constexpr double kTakeoffToleranceM = 0.15;
constexpr double kTakeoffMaxSpeedMps = 0.3;

struct StatusView {
  bool reached_goal = false;
  bool collided = false;
  bool active = true;
  std::string reason;
};

class EpisodeDirector {
 public:
  enum class Action { kContinue, kGoto, kGiveGoal, kEnd };

  EpisodeDirector(const EpisodeSpec& spec, const EpisodeLimits& limits, double t_start_s);

  // The decision at the held frame t (odometry position and speed at or before it, the status as of the step
  // before it, records of this episode since the goal, the goal's frame included).
  Action OnFrame(double t_s, const Eigen::Vector3d& p_world, double speed_mps, const StatusView& status,
                 uint64_t records_since_goal);
  // The tracker's answer to the goto ("" accepted) / the expert's answer to the goal ("" accepted).
  void OnGotoAnswer(const std::string& why);
  void OnGoalAnswer(const std::string& why);

  bool done() const { return phase_ == Phase::kDone; }
  const std::string& outcome() const { return outcome_; }
  const std::string& reason() const { return reason_; }
  double duration_s() const { return duration_s_; }
  double t_goal_s() const { return t_goal_s_; }

 private:
  enum class Phase { kTakeoffPending, kTakingOff, kFlying, kDone };
  void End(const std::string& outcome, const std::string& reason, double t_from_s, double t_now_s);

  EpisodeSpec spec_;
  EpisodeLimits limits_;
  double t_start_s_;
  double t_goal_s_ = 0.0;
  double t_last_s_ = 0.0;
  Phase phase_ = Phase::kTakeoffPending;
  std::string outcome_, reason_;
  double duration_s_ = 0.0;
};

// The episode manager's keyed reset request for `spec` (the start on the ground below the take-off target,
// facing the goal's way), resolved and applied to `sim`. Returns "" or why the simulator rejected it.
std::string ResetKeyed(const quad_sim::SimConfig& cfg, const EpisodeSpec& spec, quad_sim::Simulator* sim);

// The simulator world's occupied voxel centres, what the privileged expert's SetGlobalMap takes (the
// simulator's /voxel_map as the planner node reads it), computed and handed over again only when the world
// changes. A world depends on the episode's start and goal (the generator keeps them clear), so collection
// episodes rarely share one; a reset to the same episode (the Gymnasium env, repeated evaluation) reuses the
// points, and the planner its ESDF.
class WorldPoints {
 public:
  // Hands `sim`'s current world to the sessions (null entries skipped) if it differs from the previous
  // call's. If a session throws, the exception propagates and the next call hands the world over again (the
  // session still holds the previous world's points).
  void Give(const quad_sim::Simulator& sim, std::initializer_list<fast_planner::ExpertSession*> sessions);

 private:
  std::optional<quad_sim::World> world_;
  std::vector<Eigen::Vector3d> points_;
};

// One recorded plan, owning what the writer's record views (the depth frame, the status text).
struct OwnedRecord {
  cpp_data_collector::PlanRecord record;
  std::shared_ptr<const fast_planner::DepthFrame> frame;
  std::string status_text;
  // Points record.depth and record.status.text at the owned frame and text (after a copy or a move).
  void Rebind();
};

// A flown episode: its outcome as episodes.csv holds it and its records in the order the expert made them.
struct EpisodeRun {
  EpisodeSpec spec;
  std::string outcome;  // goal_reached | collision | timeout | goal_rejected | reset_failed | ended | stopped
  std::string reason;
  double sim_duration_s = 0.0;  // from the goal (from the start for a take-off that failed)
  uint64_t samples = 0;         // records since the goal
  std::vector<OwnedRecord> records;
  quad_core::CameraIntrinsics intrinsics;
  // Statistics: physics steps, depth frames, successful and failed plans, sim seconds from the reset, wall
  // seconds of the episode.
  uint64_t steps = 0, frames = 0, plans = 0, plan_failures = 0;
  double sim_s = 0.0, wall_s = 0.0;
};

}  // namespace quad_engine
