// Closed-loop evaluation in the engine (issue 32, docs/engine.md): one keyed evaluation episode of the
// simulator, the tracker and a controller as launch/infer.launch connects them: the learned policy
// (policy_node.cpp: a decision at every depth frame from the odometry paired with it, the trajectory to the
// tracker before the frame is released), driven by the evaluation runner's logic (quad_il.evaluation.runner:
// take-off, goal, end), or the expert (flight mode, as the expert's evaluation launch connects
// fast_planner_node); optionally, with the policy, the expert in labeller mode beside it (its plan from
// exactly the policy's state at every frame: DAgger labels, the Gymnasium env's info).
//
// The network is not called here: Advance() steps the episode to the next frame at which the policy decides
// and stops there with the network's inputs (preprocessed as the exported file preprocesses them); the caller
// runs the network for every episode waiting (one batched forward pass: PolicyBatch, LibTorch; or a Python
// callable) and hands each its output with Decide(), which runs the one C++ decider (quad_policy's
// PolicyDecider, at the tier the policy config sets) and sends its trajectory to the tracker.
#pragma once

#include <fast_planner/expert_session.h>
#include <kr_tracker/tracker_manager.h>
#include <quad_policy/config.h>
#include <quad_policy/policy_decider.h>
#include <quad_sim/simulator.h>

#include <array>
#include <deque>
#include <limits>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "quad_engine/episode.h"

namespace quad_engine {

class RecordBuffer;

// The evaluation's limits (quad_il.evaluation.runner).
struct EvalLimits {
  double takeoff_timeout_s = 15.0;
  double episode_timeout_s = 60.0;
};

// What the network gets for one decision, and the state it is made from.
struct DecisionRequest {
  double stamp_s = 0.0;
  std::vector<float> depth_x;  // input_height x input_width, the file's preprocessing
  quad_policy::StateVector state_x{};
  quad_core::VehicleState state;  // the odometry paired with the frame
  Eigen::Vector3d goal_world = Eigen::Vector3d::Zero();
  // Labeller: the expert's plan at this frame (its B-spline's knots and world-frame control points), none
  // when it found none (label_reason says why).
  bool has_label = false;
  std::vector<double> label_knots;
  Eigen::MatrixXd label_ctrl_pts;
  std::string label_reason;
};

// The episode's result (quad_il.evaluation.episodes.EpisodeResult's fields the engine measures).
struct PolicyEpisodeResult {
  std::string outcome = "timeout";  // goal_reached | collision | timeout | reset_failed | takeoff_failed
  std::string reason;
  double time_to_goal_s = std::numeric_limits<double>::quiet_NaN();
  double flight_time_s = 0.0;
  double path_length_m = 0.0;
  double min_clearance_m = std::numeric_limits<double>::infinity();  // exact: vehicle box to world boxes
  uint64_t decisions = 0;
  std::map<std::string, uint64_t> counts;  // decision statuses, verdicts and events (as policy/decision)
  std::vector<std::array<double, 4>> trajectory;  // [t - t_goal, x, y, z] every 0.1 s of sim time
  // Every odometry [t, x, y, z] of the episode, t as the runner reads stamps (the evaluation keeps those from
  // the goal to the end: quad_il.evaluation.metrics.summarise_flight).
  std::vector<std::array<double, 4>> points;
  double t_goal_s = 0.0, t_end_s = 0.0;  // as the runner reads stamps (rospy seconds)
  double sim_s = 0.0;
  uint64_t steps = 0;
};

class PolicyEpisode {
 public:
  // The policy as controller. meta: the exported policy's (its JSON). with_labeller: run the expert (planner
  // config of `configs`) in labeller mode beside the policy. Throws on an invalid config.
  PolicyEpisode(const Configs& configs, const quad_policy::PolicyNodeConfig& policy,
                const quad_policy::PolicyMeta& meta, bool with_labeller);
  // The expert (planner config of `configs`, flight mode) as controller: Advance() never stops for a
  // decision.
  explicit PolicyEpisode(const Configs& configs);
  ~PolicyEpisode();

  // Starts the keyed episode (index, seed, start, goal) as the evaluation runner does.
  void Reset(const EpisodeSpec& spec, const EvalLimits& limits);

  // Steps to the next frame at which the policy decides (true: request() is valid, call Decide) or to the end
  // of the episode (false: done()).
  bool Advance();
  const DecisionRequest& request() const { return request_; }

  // The pending decision with the network's output y for it; ask: the network for a turned goal (recovery;
  // may be empty when the config asks for none). Returns what the decision did (as policy/decision: the
  // action "policy", "recovery", "stop", "keep", "hover", ...; the reason: the safety verdict's words), with
  // the verdict; a decision refused as bad input has the action "none".
  struct Outcome {
    std::string action = "none";
    std::string reason;
    std::string verdict;
    bool accepted = false;
  };
  Outcome Decide(std::vector<float> y, const quad_policy::PolicyDecider::AskNetwork& ask);

  bool done() const { return done_; }
  const PolicyEpisodeResult& result() const { return result_; }
  // The labeller's records of this episode (the expert's plans at the policy's states; DAgger datasets).
  std::vector<OwnedRecord> TakeLabelRecords();
  // Keep the labeller's records of every n-th frame only (1: every frame; the labeller still sees every
  // frame, its map needs them). Throws std::invalid_argument for n < 1.
  void set_label_stride(int n);
  const quad_core::CameraIntrinsics& intrinsics() const { return sim_.camera_intrinsics(); }
  const quad_policy::PolicyMeta& meta() const { return meta_; }
  const quad_sim::World& world() const { return sim_.world(); }
  // The recovery's turned goals (the policy config's goal_yaw_offsets_deg), in the decider's order.
  const std::vector<double>& recovery_yaws_deg() const { return policy_cfg_.recovery.goal_yaw_offsets_deg; }

 private:
  enum class Phase { kTakeoff, kTakingOff, kFlying };
  void StepOnce();
  void OnFrame();      // the frame at the current step: labeller, then the policy's checks
  void DirectFrame();  // the evaluation runner's decision at the current frame
  void Finish(const std::string& outcome, const std::string& reason, double t_end_s);
  void Skip(const std::string& status) { ++result_.counts[status]; }
  void Fly(const fast_planner::ReplannerOutput& out, double clock_s);  // the expert's trajectories
  double NowS() const;

  Configs cfg_;
  quad_policy::PolicyNodeConfig policy_cfg_;
  quad_policy::PolicyMeta meta_;
  quad_sim::Simulator sim_;
  kr_tracker::TrackerManager tracker_;
  std::unique_ptr<quad_policy::PolicyDecider> decider_;  // the policy controller
  std::unique_ptr<fast_planner::ExpertSession> expert_;  // the expert controller (flight mode)
  std::unique_ptr<fast_planner::ExpertSession> labeller_;
  std::shared_ptr<RecordBuffer> label_records_;
  fast_planner::CameraMount mount_;
  Eigen::Isometry3d T_body_camera_ = Eigen::Isometry3d::Identity();

  EpisodeSpec spec_;
  EvalLimits limits_;
  uint64_t t0_ns_ = 0, dt_ns_ = 0, step_ = 0;
  double z_offset_m_ = 0.0;
  bool z_offset_measured_ = false;
  WorldPoints world_points_;  // the privileged labeller's or expert's map, once per world
  Phase phase_ = Phase::kTakeoff;
  int gotos_ = 0;
  double t_takeoff_s_ = 0.0, t_goal_s_ = 0.0;
  double status_end_s_ = 0.0;
  double last_depth_s_ = 0.0;  // the expert controller's newest frame (its goal's plan time)
  int label_stride_ = 1;
  uint64_t label_frames_ = 0;  // frames the labeller saw in this episode  // the status's sim time when the
                               // simulator ended the episode (rospy seconds)
  std::optional<Eigen::Vector3d> goal_;
  std::deque<quad_core::VehicleState> odom_;
  std::optional<uint64_t> last_decision_ns_;
  bool frame_open_ = false;  // the current step's frame still needs the runner's decision and the step
  bool pending_ = false;     // a decision request waits for Decide()
  std::optional<quad_sim::So3Command> command_;
  bool done_ = true;
  bool hovering_ = false;
  int64_t traj_id_ = 0;
  uint64_t goal_ids_ = 1;
  Eigen::Vector3d p_prev_ = Eigen::Vector3d::Zero();
  double next_traj_sample_s_ = 0.0;
  DecisionRequest request_;
  quad_policy::DecisionInputs inputs_;
  std::shared_ptr<const fast_planner::DepthFrame> frame_;
  PolicyEpisodeResult result_;
};

}  // namespace quad_engine
