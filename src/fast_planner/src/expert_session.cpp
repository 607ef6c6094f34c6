#include "fast_planner/expert_session.h"

namespace fast_planner {

ExpertSession::ExpertSession(const PlannerConfig& cfg, bool label_every_frame)
    : cfg_(cfg),
      label_every_frame_(label_every_frame),
      replanner_(cfg),
      labeller_(cfg.node.label_acc_window_s),
      odom_(kOdometryKept, cfg.node.odom_period_s) {}

void ExpertSession::SetCollector(std::shared_ptr<PlanCollector> collector) {
  collector_ = std::move(collector);
  replanner_.manager().SetObserver(collector_);
}

ReplannerOutput ExpertSession::OnOdometry(const quad_core::VehicleState& odom) {
  ReplannerOutput out;
  if (label_every_frame_) {
    replanner_.manager().UpdateOdometry(odom);  // validates; the label's plan sets the one it used again
  } else {
    out = replanner_.OnOdometry(odom);
  }
  odom_.Push(odom);
  return out;
}

bool ExpertSession::SetCameraPose(const CameraMount& mount, DepthFrame* frame) const {
  const quad_core::VehicleState* paired = odom_.PairedWith(frame->stamp_s);
  if (!paired) return false;
  const CameraPose pose = CameraPoseAt(*paired, frame->stamp_s, mount);
  frame->p_world_camera = pose.p_world_camera;
  frame->q_world_camera = pose.q_world_camera;
  return true;
}

ExpertSession::FrameOutput ExpertSession::OnDepth(std::shared_ptr<const DepthFrame> frame) {
  FrameOutput out;
  const double stamp_s = frame ? frame->stamp_s : 0.0;
  if (label_every_frame_) {
    out.map_update = replanner_.manager().UpdateDepth(std::move(frame));
  } else {
    out.flight = replanner_.OnDepth(std::move(frame), &out.map_update);
  }
  // In flight mode the plans of this frame were recorded with the previous frame's map update time (the
  // replanner plans inside OnDepth); a label is planned after the update and records its own.
  last_map_update_ms_ = out.map_update.total_ms;
  if (collector_) collector_->SetMapUpdateMs(last_map_update_ms_);
  if (label_every_frame_) out.label = labeller_.Label(replanner_.manager(), odom_, stamp_s);
  return out;
}

std::string ExpertSession::SetGoal(const Eigen::Vector3d& goal, double now_s, ReplannerOutput* out) {
  if (label_every_frame_) return labeller_.SetGoal(replanner_.manager(), goal);
  return replanner_.SetGoal(goal, now_s, out);
}

void ExpertSession::SetGlobalMap(std::vector<Eigen::Vector3d> occupied_points_world) {
  replanner_.manager().SetGlobalMap(occupied_points_world);
  global_points_ = std::move(occupied_points_world);
}

std::vector<std::pair<double, ReplannerOutput>> ExpertSession::StartEpisode(double t_start_s) {
  const std::vector<quad_core::VehicleState> early = odom_.Since(t_start_s);
  replanner_.Reset();
  labeller_.Reset();
  odom_.Clear();
  if (global_points_) replanner_.manager().SetGlobalMap(*global_points_);
  std::vector<std::pair<double, ReplannerOutput>> outputs;
  for (const quad_core::VehicleState& o : early) outputs.emplace_back(o.t_s, OnOdometry(o));
  return outputs;
}

}  // namespace fast_planner
