// One decision of the learned policy: depth frame + odometry + goal -> preprocessing -> network ->
// world-frame B-spline -> safety layer -> the trajectory to send: the policy's; when refused, the first
// accepted plan of the recovery (the network asked again with the goal turned about the vehicle,
// RecoveryConfig); else, with KeepingConfig, the plan sent before flown on; else the stopping trajectory
// (refusal action stop). ROS-free; policy_node, the parity replay tool and the benchmark all call Decide().
// The Python twin is quad_il/inference/decider.py.
#pragma once

#include <Eigen/Core>

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
// trajectory and replans about every metre or when it sees a collision on it. A kept plan's rest, from the
// decision's stamp on, must pass the test a recovery plan passes (RestIsClear, with at least
// max(check_horizon_s, stop_min_duration_s) of it left); a stopping trajectory is never kept.
// commit_s > 0: a plan the node sent is flown on, whatever the new decision, until it is commit_s old (sim
// time); the network is asked on every frame, but its plan is sent only once the commitment ends or the rest
// of the committed plan fails the test. on_refusal: a refused decision the recovery finds no plan for sends
// nothing while the plan sent before passes the test; only when it fails too does the refusal action apply.
struct KeepingConfig {
  double commit_s = 0.0;
  bool on_refusal = false;
};
// Throws std::invalid_argument naming the key and the value.
void ValidateKeeping(const KeepingConfig& keeping);

// On a refused plan the network is asked again with the goal direction turned about the vehicle's vertical
// axis by each angle in turn (degrees, +: counter-clockwise seen from above); the first plan the safety
// layer accepts and that stays in view (TrajectoryInView) is sent. Empty: off. Angles must be finite,
// non-zero and within [-180, 180]; at most 16.
// Steering (steer_clearance_m > 0, greater than the safety layer's vehicle_radius_m): an accepted plan that
// passes nearer than steer_clearance_m to what the depth frame shows (CheckTrajectory with this radius) makes
// the decider try the same turned goals; the first plan that keeps steer_clearance_m and stays in view is
// sent instead. The vehicle turns away from a box while it is still far enough for the turn to stay in view,
// instead of stopping in front of it. 0: off.
// Turning in place (turn_after_stops > 0, refusal action stop): from the turn_after_stops-th stopping
// trajectory in a row (refused, not recovered) on, the stopping trajectory also turns the heading at
// turn_rate_dps, towards the side the goal lies on (chosen when the turning starts, kept until a plan is
// sent again). The camera then sweeps the surroundings and the network, asked every decision, sees the
// space beside the box that blocks it; the first plan the safety layer accepts (or the recovery finds) ends
// the turning. Room to turn: while the depth frame shows a surface nearer than turn_clearance_m
// (NearestDepth), the turning stop also backs away along the heading by the missing distance (TurningStop);
// turning a box-shaped vehicle on the spot right in front of a box would touch it. Not learned: a fixed
// behaviour of the node, off by default. turn_after_stops 0: off; turn_clearance_m 0: no back-off.
// Final approach (final_approach_m > 0): within this distance of the goal the decider sends the trajectory
// straight to the goal, to rest there (FinalApproach, acceleration within final_approach_acc_mps2, at least
// the refusal's stop_min_duration_s long), when the safety layer accepts it, instead of anything else; else
// the decision goes on as without it. The expert flies its last metre the same way (it stops replanning
// within fsm.replan_distance_m). Not learned: a fixed behaviour of the node, off by default.
struct RecoveryConfig {
  std::vector<double> goal_yaw_offsets_deg;
  double steer_clearance_m = 0.0;
  int turn_after_stops = 0;
  double turn_rate_dps = 45.0;
  double turn_clearance_m = 0.0;
  double final_approach_m = 0.0;
  double final_approach_acc_mps2 = 2.0;
};
// Throws std::invalid_argument naming the key and the value. With a safety config, also checks that a
// non-zero steer_clearance_m exceeds safety.vehicle_radius_m and has turns to try.
void ValidateRecoveryConfig(const RecoveryConfig& recovery);
void ValidateRecoveryConfig(const RecoveryConfig& recovery, const SafetyConfig& safety);
// Turning in place rides on the stopping trajectory: throws std::invalid_argument when turn_after_stops is
// set and the refusal action is not kStop.
void ValidateTurning(const RecoveryConfig& recovery, const RefusalConfig& refusal);

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
  double preprocess_ms = 0.0;  // depth + state encoding
  double forward_ms = 0.0;     // the network
  double decode_ms = 0.0;      // output decoding + trajectory
  double safety_ms = 0.0;      // the safety layer (and the recovery's plans or the stopping trajectory)
};

struct Decision {
  SafetyResult safety;
  UniformBspline proposed;             // the policy's trajectory (world frame; the most confident hypothesis)
  int proposed_hypothesis = 0;         // index of the hypothesis `proposed` comes from
  std::optional<UniformBspline> stop;  // the stopping trajectory when refused, not recovered, action kStop
  // When the policy's plan was refused (or, steering, came nearer than steer_clearance_m) and another
  // hypothesis or a turned goal gave a plan that passed: that plan, the angle (0: the goal itself) and the
  // hypothesis' index.
  std::optional<UniformBspline> recovery;
  double recovery_yaw_deg = 0.0;
  int recovery_hypothesis = -1;
  int recovery_tries = 0;        // turned goals asked (0 when no search ran)
  bool steered = false;          // the recovery replaces an accepted plan (steering), not a refused one
  double turn_rate_radps = 0.0;  // non-zero: the stopping trajectory turns in place at this rate
  double turn_backoff_m = 0.0;   // and backs away along the heading by this much
  // Within recovery.final_approach_m of the goal: the trajectory straight to the goal, when the safety layer
  // accepted it (it is then sent instead of anything else).
  std::optional<UniformBspline> final_approach;
  // KeepingConfig: the plan sent before, flown on (nothing is sent): committed (younger than commit_s) or, on
  // a refusal the recovery could not mend (on_refusal), with its rest still clear.
  std::optional<UniformBspline> kept;
  bool committed = false;      // kept because its commitment had not ended (else kept on a refusal)
  std::vector<float> depth_x;  // network depth input (input_height x input_width)
  StateVector state_x{};       // state vector (EncodeState)
  std::vector<float> y;        // network output (training representation), every hypothesis
  DecisionTimings timings;
  bool accepted() const { return safety.accepted(); }
  // The trajectory to send to the tracker: none when the plan sent before is kept, else the final approach if
  // there is one, else the recovery's plan if there is one, else the proposal if accepted, else the stopping
  // trajectory (or none).
  const UniformBspline* to_send() const;
};

// "; recovered with ..." for the decision's reason ("" without a recovery); the Python node writes the same
// words (Decision.recovery_text).
std::string RecoveryText(const Decision& d, int num_hypotheses);

class PolicyDecider {
 public:
  // Throws std::invalid_argument on an invalid safety, refusal, recovery or keeping configuration.
  PolicyDecider(std::shared_ptr<const TorchPolicy> policy, const SafetyConfig& safety,
                const RefusalConfig& refusal, const RecoveryConfig& recovery = {},
                const KeepingConfig& keeping = {});

  // Throws std::invalid_argument on invalid inputs (non-finite odometry or goal, empty depth). Decisions
  // depend on the ones before through the turning's count of stops in a row, the depth memory and the
  // trajectory sent last (KeepingConfig); Reset() clears them.
  Decision Decide(const DecisionInputs& in);
  // A new episode: forgets the stops in a row, the turning direction, the depth memory and the trajectory
  // sent last.
  void Reset();

  const VerdictCounts& counts() const { return counts_; }
  const TorchPolicy& policy() const { return *policy_; }
  const SafetyConfig& safety_config() const { return safety_; }
  const RefusalConfig& refusal_config() const { return refusal_; }
  const RecoveryConfig& recovery_config() const { return recovery_; }
  const KeepingConfig& keeping_config() const { return keeping_; }
  const DepthMemory& memory() const { return memory_; }

 private:
  void EndStops();
  std::shared_ptr<const TorchPolicy> policy_;
  SafetyConfig safety_;
  RefusalConfig refusal_;
  RecoveryConfig recovery_;
  KeepingConfig keeping_;
  OutputDecoder decoder_;
  VerdictCounts counts_;
  int stops_in_row_ = 0;                // consecutive decisions that sent the stopping trajectory
  int turn_sign_ = 0;                   // +1 left, -1 right, 0: not turning
  DepthMemory memory_;                  // earlier decision frames (SafetyConfig memory_frames), newest first
  std::optional<UniformBspline> sent_;  // the plan the tracker flies (KeepingConfig); never a stop
};

}  // namespace quad_policy
