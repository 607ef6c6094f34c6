// One engine worker of the expert (issue 32, docs/engine.md): the simulator, the tracker and the expert with
// its data collector connected in one thread exactly as collect.launch connects the nodes in lockstep, and
// the episode manager's logic (EpisodeDirector). Like the nodes, one worker keeps its simulator, tracker and
// expert across episodes; every episode is keyed (quad_core/episode_key.h), so its flight and records depend
// on its key only. Per physics step at sim time t (the simulator node's loop):
//
//   odometry due: the tracker turns it into the SO(3) command applied before this step; the expert and the
//                 manager's odometry history take it;
//   frame due:    the expert integrates it and replans; a new trajectory reaches the tracker at once (the
//                 planner waits for the tracker to accept it before acknowledging the frame), so it is flown
//                 from the next odometry on; then the manager decides (take-off goto, goal, end);
//   step.
//
// Values cross between the cores as they would cross ROS (quad_core/wire.h): odometry angular velocity in
// world axes, trajectory start times rounded to nanoseconds, the manager's times as rospy reads stamps.
//
// The privileged expert (map.source global) plans on the world's voxel map, not on its frames: without depth
// noise a frame is rendered only when a plan made at it is recorded (RecordBuffer's placeholder), which gives
// the same records as rendering every frame.
#pragma once

#include <fast_planner/expert_session.h>
#include <kr_tracker/tracker_manager.h>
#include <quad_sim/simulator.h>

#include <memory>

#include "quad_engine/episode.h"

namespace quad_engine {

class RecordBuffer;

class ExpertWorker {
 public:
  // Throws std::invalid_argument / quad_core::ConfigError on an invalid config.
  explicit ExpertWorker(const Configs& configs);
  ~ExpertWorker();

  // Flies one episode to its end (as the episode manager ends it). A reset the simulator refuses is the
  // outcome "reset_failed" with the reason, as in collect.launch.
  EpisodeRun Run(const EpisodeSpec& spec, const EpisodeLimits& limits);

  const Configs& configs() const { return cfg_; }
  // Whether frames are rendered only for the records (the privileged expert without depth noise: the default
  // then); false renders every frame (what the ROS simulator does; a test compares the two).
  bool lazy_depth() const { return lazy_depth_; }
  void set_lazy_depth(bool lazy) {
    lazy_depth_ = lazy && cfg_.planner.map.source == fast_planner::MapSource::kGlobal;
  }

 private:
  Configs cfg_;
  quad_sim::Simulator sim_;
  kr_tracker::TrackerManager tracker_;
  fast_planner::ExpertSession expert_;
  std::shared_ptr<RecordBuffer> buffer_;
  fast_planner::CameraMount mount_;
  double z_offset_m_ = 0.0;
  bool z_offset_measured_ = false;
  WorldPoints world_points_;   // the privileged expert's map, once per world
  bool lazy_depth_ = false;    // frames rendered only for the records (privileged expert, no depth noise)
  uint64_t next_goal_id_ = 1;  // the tracker node's TrackBspline goal ids
};

// The command the simulator applies for the tracker's SO(3) command (quad_msgs/SO3Command on the wire: all
// gains zero means "keep the simulator's default gains").
quad_sim::So3Command ToSimCommand(const kr_tracker::So3Command& c);

// The tracker's goal for a planned trajectory (quad_msgs/Bspline on the wire: start time in nanoseconds).
kr_tracker::BsplineGoalSpec ToGoalSpec(const fast_planner::PlanResult& plan);

}  // namespace quad_engine
