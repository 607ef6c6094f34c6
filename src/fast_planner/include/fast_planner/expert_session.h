// The expert as fast_planner_node drives it, ROS-free: flight mode (the Replanner) or labeller mode (the
// Labeller), the odometry history depth frames are paired with (OdometryHistory), the embedded data
// collector (PlanCollector, optional) and episode resets. The node converts messages, calls these methods
// and publishes what they return; everything here can be driven from a test without a ROS master.
#pragma once

#include <Eigen/Core>

#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "fast_planner/labeller.h"
#include "fast_planner/odometry_history.h"
#include "fast_planner/plan_collector.h"
#include "fast_planner/replanner.h"

namespace fast_planner {

class ExpertSession {
 public:
  // Odometry kept to pair depth frames with (a second at 200 Hz).
  static constexpr std::size_t kOdometryKept = 200;

  // Throws quad_core::ConfigError / std::invalid_argument on an invalid configuration.
  ExpertSession(const PlannerConfig& cfg, bool label_every_frame);

  // Records every successful plan from now on (the collector is the manager's observer).
  void SetCollector(std::shared_ptr<PlanCollector> collector);
  // Any other observer of the successful plans instead (the rollout engine's per-episode record buffer); the
  // collector's map update time is then not set.
  void SetPlanObserver(std::shared_ptr<PlanObserver> observer) {
    collector_.reset();
    replanner_.manager().SetObserver(std::move(observer));
  }

  bool labeller_mode() const { return label_every_frame_; }
  const PlannerConfig& config() const { return cfg_; }
  const Replanner& replanner() const { return replanner_; }
  const OdometryHistory& odometry() const { return odom_; }
  const Labeller& labeller() const { return labeller_; }
  double last_map_update_ms() const { return last_map_update_ms_; }

  // Validates and keeps the odometry; in flight mode also steps the replanner and returns its output.
  // Throws std::invalid_argument on non-finite odometry, which is then ignored.
  ReplannerOutput OnOdometry(const quad_core::VehicleState& odom);

  // True once the odometry of the frame's control period has arrived (OdometryHistory::Covers).
  bool FrameCovered(double frame_stamp_s) const { return odom_.Covers(frame_stamp_s); }

  // Sets the frame's camera pose from the odometry paired with its stamp; false without such odometry.
  bool SetCameraPose(const CameraMount& mount, DepthFrame* frame) const;

  struct FrameOutput {
    MapUpdateResult map_update;
    ReplannerOutput flight;           // flight mode: what the replanner decided at this frame
    std::optional<PlanResult> label;  // labeller mode: the plan attempt (none without goal or odometry)
  };
  // Integrates the frame, then plans its label (labeller mode) or steps the replanner (flight mode). Throws
  // std::invalid_argument on a malformed frame, which then changes nothing.
  FrameOutput OnDepth(std::shared_ptr<const DepthFrame> frame);

  // Accepts a goal ("") or returns why not. Flight mode: the replanner plans at now_s (output in *out).
  // Labeller mode: the goal of the labels from the next frame on (*out stays empty).
  std::string SetGoal(const Eigen::Vector3d& goal, double now_s, ReplannerOutput* out);

  // The simulator's voxel map (map.source global); kept for the resets.
  void SetGlobalMap(std::vector<Eigen::Vector3d> occupied_points_world);

  // A new episode starting at t_start_s: forgets map, goal, trajectory and odometry, except the new episode's
  // odometry that arrived before its status (another connection), which is fed again. Returns the
  // replanner's outputs of that replay with each odometry's stamp (flight mode).
  std::vector<std::pair<double, ReplannerOutput>> StartEpisode(double t_start_s);

 private:
  PlannerConfig cfg_;
  bool label_every_frame_;
  Replanner replanner_;
  Labeller labeller_;
  OdometryHistory odom_;
  std::shared_ptr<PlanCollector> collector_;
  std::optional<std::vector<Eigen::Vector3d>> global_points_;
  double last_map_update_ms_ = 0.0;
};

}  // namespace fast_planner
