// Closed-loop runs of the tracker + SO(3) controller against the simulator core in-process (ROS-free; library
// kr_tracker_sim, which links quad_sim_core). Used by the closed-loop gtests, the benchmark and zn_tune.
//
// The loop is the node's: at every odometry time of the simulator (200 Hz by default) the tracker produces a
// reference from the state, the controller turns it into an SO(3) command, and the simulator flies that
// command through its onboard attitude controller at 1 kHz until the next odometry time.
#pragma once

#include <quad_sim/simulator.h>

#include <array>
#include <functional>
#include <string>
#include <vector>

#include "kr_tracker/bspline_tracker.h"
#include "kr_tracker/config.h"
#include "kr_tracker/response_metrics.h"
#include "kr_tracker/so3_controller.h"
#include "kr_tracker/tracker.h"

namespace quad_bench {

// The harness is written in the tracker's vocabulary.
using namespace kr_tracker;  // NOLINT(google-build-using-namespace)

quad_sim::So3Command ToSim(const So3Command& c);

struct LoopSample {
  double t_s = 0.0;
  Eigen::Vector3d p_world = Eigen::Vector3d::Zero();
  Eigen::Vector3d p_ref_world = Eigen::Vector3d::Zero();
  Eigen::Vector3d v_world = Eigen::Vector3d::Zero();
  Eigen::Vector3d v_ref_world = Eigen::Vector3d::Zero();
  double yaw_rad = 0.0;
  double yaw_ref_rad = 0.0;
};

struct LoopRun {
  std::vector<LoopSample> samples;  // one per odometry tick
  int rejected_commands = 0;        // commands the simulator refused (should be 0)
  int controller_fallbacks = 0;     // non-ok controller statuses (should be 0)
  bool collided = false;
  std::string episode_reason;
};

// A tracker whose reference is a function of time (step and excitation experiments).
class FunctionTracker : public Tracker {
 public:
  explicit FunctionTracker(std::function<PositionReference(double t_s)> ref) : ref_(std::move(ref)) {}
  std::string name() const override { return "function"; }
  void Activate(const PositionReference&, const quad_core::VehicleState&) override { active_ = true; }
  void Deactivate() override { active_ = false; }
  PositionReference Update(const quad_core::VehicleState& state) override { return ref_(state.t_s); }
  TrackerStatus status() const override {
    return active_ ? TrackerStatus::kTracking : TrackerStatus::kInactive;
  }

 private:
  std::function<PositionReference(double)> ref_;
  bool active_ = false;
};

// Flies `tracker` (already activated) with `controller` for duration_s of sim time from the simulator's
// current state. on_tick, if set, is called after every odometry tick (e.g. to feed goals to a tracker).
LoopRun RunClosedLoop(quad_sim::Simulator* sim, So3Controller* controller, Tracker* tracker,
                      double duration_s, const std::function<void(const LoopSample&)>& on_tick = nullptr);

// The simulator configuration for in-process experiments: config/sim.yaml when sim_yaml is not empty,
// otherwise quad_sim's defaults with the vehicle from vehicle_yaml. Either way the vehicle file is the one
// the node uses.
quad_sim::SimConfig MakeSimConfig(const std::string& sim_yaml, const std::string& vehicle_yaml);

// An empty world (ground plane only) with the vehicle hovering at p_start_world, yaw 0; the goal is placed
// far away so that the episode never ends by reaching it.
void ResetEmptyWorld(quad_sim::Simulator* sim, const Eigen::Vector3d& p_start_world);

// The thesis's step test: hover at p0 for t_step_s, then a step reference p0 + step_m, flown for 10 s more.
// The simulator's ground plane is at z = 0, so "hover at the origin" is hover at p0 = (0, 0, 1).
struct StepExperiment {
  Eigen::Vector3d p0_world = Eigen::Vector3d(0.0, 0.0, 1.0);
  Eigen::Vector3d step_m = Eigen::Vector3d(3.0, 3.0, 3.0);
  double t_step_s = 1.0;
  double after_step_s = 10.0;
};

struct StepResult {
  StepMetrics worst;   // largest overshoot, rise and settling time over the axes
  double sse_m = 0.0;  // |mean position error vector| over the final second
  std::array<StepMetrics, 3> axes;
  LoopRun run;
};

StepResult RunStepExperiment(const quad_sim::SimConfig& sim_config, const So3Gains& gains,
                             const StepExperiment& experiment = StepExperiment{});

// The figure eight (MakeFigureEight with its defaults: 8 x 4 m, 2 laps, 2 m/s peak) sent as a goal to the
// B-spline tracker, starting 1 s after a hover at its centre. The error is taken while the goal runs.
struct Fig8Result {
  TrackingError error;
  double duration_s = 0.0;
  double length_m = 0.0;
  std::vector<GoalEvent> events;
  LoopRun run;
};

Fig8Result RunFigureEightExperiment(const quad_sim::SimConfig& sim_config,
                                    const TrackerConfig& tracker_config);

}  // namespace quad_bench
