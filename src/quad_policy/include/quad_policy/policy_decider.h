// One decision of the learned policy: depth frame + odometry + goal -> the network's output (every
// hypothesis)
// -> world-frame B-splines -> safety layer -> the trajectory to send (docs/inference.md, "The decider"):
//   1. keeping (KeepingConfig commit_s): the plan sent before is flown on while it is younger than commit_s
//   and
//      its rest is clear;
//   2. the final approach (RecoveryConfig final_approach_m): near the goal, the trajectory straight to it;
//   3. the policy's most confident plan, when the safety layer accepts it;
//   4. the recovery: the first other plan that the safety layer accepts and that stays in view (the other
//      hypotheses, then the network asked again with the goal turned, goal_yaw_offsets_deg);
//   5. keeping on a refusal (KeepingConfig on_refusal): the plan sent before, while its rest is clear;
//   6. the refusal action: the stopping trajectory (stop) or the tracker's hover (hover, done by the node).
// ROS-free and independent of where the network runs: the C++ node, the parity replay and the benchmark call
// Decide(inputs) (LibTorch, TorchPolicy); the Python node calls Decide(inputs, y, ask) through the bindings
// (quad_policy_py) with its own torch forward pass.
#pragma once

#include <Eigen/Core>

#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "quad_policy/preprocessing.h"
#include "quad_policy/safety.h"
#include "quad_policy/torch_policy.h"
#include "quad_policy/trajectory.h"

namespace quad_policy {

// What the vehicle does when a plan is refused: `stop` sends BrakingTrajectory from the odometry; `hover`
// switches the tracker to its hover tracker (holds its last reference), done by the node.
enum class RefusalAction { kStop, kHover };
const char* ToString(RefusalAction action);

struct RefusalConfig {
  RefusalAction action = RefusalAction::kStop;
  double stop_max_decel_mps2 = 3.0;
  double stop_min_duration_s = 0.5;
};

// Keeping the plan sent before (docs/inference.md, "Keeping the plan"), as the expert flies on along its
// trajectory and replans about every metre. A kept plan's rest, from the decision's stamp on, must pass the
// test a recovery plan passes (RestIsClear, with at least max(check_horizon_s, stop_min_duration_s) of it
// left); a stopping trajectory is never kept. commit_s > 0: a sent plan is flown on until it is commit_s old
// (sim time); the network is still asked on every frame. on_refusal: a refused decision the recovery finds no
// plan for sends nothing while the plan sent before passes the test.
struct KeepingConfig {
  double commit_s = 0.0;
  bool on_refusal = false;
};

// goal_yaw_offsets_deg: on a refused plan the network is asked again with the goal turned about the vehicle's
// vertical axis by each angle in turn (degrees, +: counter-clockwise seen from above). Empty: off. Finite,
// non-zero, within [-180, 180]; at most 16. final_approach_m > 0: within this distance of the goal the
// trajectory straight to the goal, to rest there (FinalApproach, acceleration within
// final_approach_acc_mps2), is sent when the safety layer accepts it, instead of anything else, as the expert
// flies its last metre. 0: off. Neither is learned.
struct RecoveryConfig {
  std::vector<double> goal_yaw_offsets_deg;
  double final_approach_m = 0.0;
  double final_approach_acc_mps2 = 2.0;
};

// Each throws std::invalid_argument naming the key and the value.
void ValidateRefusal(const RefusalConfig& refusal);
void ValidateRecoveryConfig(const RecoveryConfig& recovery);
void ValidateKeeping(const KeepingConfig& keeping);

// The goal turned by yaw_deg about the vertical axis through the vehicle (same distance and height).
Eigen::Vector3d TurnedGoal(const Eigen::Vector3d& p_world_body, const Eigen::Vector3d& goal_world,
                           double yaw_deg);

struct DecisionInputs {
  double stamp_s = 0.0;  // the depth frame's stamp: the trajectory starts here
  DepthImageView depth;  // metres, REP 118
  CameraModel camera;    // intrinsics and the camera's pose at the frame (from the odometry below)
  VehicleState state;    // odometry used for the decision
  Eigen::Vector3d goal_world = Eigen::Vector3d::Zero();
};

struct DecisionTimings {
  double preprocess_ms = 0.0;  // depth + state encoding (Decide(inputs) only)
  double forward_ms = 0.0;     // the network (Decide(inputs) only)
  double decode_ms = 0.0;      // output decoding + trajectory
  double safety_ms = 0.0;      // the safety layer, the recovery (its forward passes too) and the stop
};

// What the decision sends, in the order of the header's steps.
enum class SentKind {
  kNothing = 0,
  kPolicy = 1,
  kStop = 2,
  kRecovery = 3,
  kFinalApproach = 5,
  kKept = 6,
  kCommitted = 7
};

struct Decision {
  SafetyResult safety;                 // the verdict on the proposal
  UniformBspline proposed;             // the policy's trajectory (world frame; the most confident hypothesis)
  int proposed_hypothesis = 0;         // index of the hypothesis `proposed` comes from
  std::optional<UniformBspline> stop;  // the stopping trajectory (refused, nothing else, action stop)
  // A refused proposal replaced by another hypothesis or a turned goal's plan: that plan, the angle (0: the
  // goal itself) and the hypothesis' index.
  std::optional<UniformBspline> recovery;
  double recovery_yaw_deg = 0.0;
  int recovery_hypothesis = -1;
  int recovery_tries = 0;  // turned goals asked (0 when no search ran)
  std::optional<UniformBspline>
      final_approach;                  // accepted by the safety layer, sent instead of anything else
  std::optional<UniformBspline> kept;  // the plan sent before, flown on (nothing is sent)
  bool committed = false;              // kept because its commitment had not ended
  std::vector<float> depth_x;          // network depth input (Decide(inputs) only)
  StateVector state_x{};               // state vector (Decide(inputs) only)
  std::vector<float> y;                // network output for the goal, every hypothesis
  DecisionTimings timings;
  bool accepted() const { return safety.accepted(); }
  SentKind sent_kind() const;
  // The trajectory to send to the tracker (none: keep the plan sent before, or hover).
  const UniformBspline* to_send() const;
};

// For policy/decision: the action ("policy", "recovery", "final_approach", "stop", "keep", "hover"), the
// reason (the safety verdict's words plus what replaced the proposal) and the events to count. Both nodes
// publish these words.
struct DecisionSummary {
  std::string action;
  std::string reason;
  std::vector<std::string> events;
};
DecisionSummary Summarize(const Decision& d, int num_hypotheses, double stamp_s);

class PolicyDecider {
 public:
  // The network's flat output (network_output_dim values) for the decision's frame with the given goal.
  using AskNetwork = std::function<std::vector<float>(const Eigen::Vector3d& goal_world)>;

  // Throws std::invalid_argument on an invalid safety, refusal, recovery or keeping configuration.
  PolicyDecider(const PolicyMeta& meta, const SafetyConfig& safety, const RefusalConfig& refusal,
                const RecoveryConfig& recovery = {}, const KeepingConfig& keeping = {});
  // With the LibTorch policy: Decide(inputs) preprocesses and runs it.
  PolicyDecider(std::shared_ptr<const TorchPolicy> policy, const SafetyConfig& safety,
                const RefusalConfig& refusal, const RecoveryConfig& recovery = {},
                const KeepingConfig& keeping = {});

  // y: the network's output for in.goal_world; ask: the network for a turned goal (the recovery; empty: the
  // turned goals are not tried, e.g. in the engine's Gymnasium environments). Throws
  // std::invalid_argument on invalid inputs (non-finite stamp, odometry or goal, empty depth, wrong output
  // length). Decisions depend on the ones before through the trajectory sent last (KeepingConfig); Reset()
  // forgets it.
  Decision Decide(const DecisionInputs& in, std::vector<float> y, const AskNetwork& ask);
  // Preprocessing and forward pass with the TorchPolicy (throws std::logic_error without one).
  Decision Decide(const DecisionInputs& in);
  void Reset() { sent_.reset(); }

  const VerdictCounts& counts() const { return counts_; }
  const PolicyMeta& meta() const { return meta_; }
  const TorchPolicy& policy() const;

 private:
  PolicyMeta meta_;
  std::shared_ptr<const TorchPolicy> policy_;  // null: the network runs elsewhere (Python)
  SafetyConfig safety_;
  RefusalConfig refusal_;
  RecoveryConfig recovery_;
  KeepingConfig keeping_;
  OutputDecoder decoder_;
  VerdictCounts counts_;
  std::optional<UniformBspline> sent_;  // the plan the tracker flies (KeepingConfig); never a stop
};

}  // namespace quad_policy
