#include "fast_planner/odometry_history.h"

#include <quad_core/pairing.h>

#include <cmath>
#include <stdexcept>
#include <string>

namespace fast_planner {

OdometryHistory::OdometryHistory(std::size_t capacity, double odom_period_s)
    : capacity_(capacity), odom_period_s_(odom_period_s) {
  if (capacity_ == 0) throw std::invalid_argument("OdometryHistory: capacity must be > 0, got 0");
  if (!(std::isfinite(odom_period_s_) && odom_period_s_ > 0.0)) {
    throw std::invalid_argument("OdometryHistory: odom_period_s must be finite and > 0, got " +
                                std::to_string(odom_period_s_));
  }
}

void OdometryHistory::Push(const quad_core::VehicleState& odom) {
  samples_.push_back(odom);
  if (samples_.size() > capacity_) samples_.pop_front();
}

bool OdometryHistory::Covers(double frame_stamp_s) const {
  return !samples_.empty() &&
         quad_core::OdometryCoversFrame(samples_.back().t_s, frame_stamp_s, odom_period_s_);
}

const quad_core::VehicleState* OdometryHistory::PairedWith(double frame_stamp_s) const {
  return quad_core::PairedOdometry(samples_, frame_stamp_s,
                                   [](const quad_core::VehicleState& s) { return s.t_s; });
}

std::vector<quad_core::VehicleState> OdometryHistory::Since(double t_start_s) const {
  std::vector<quad_core::VehicleState> out;
  for (const auto& o : samples_) {
    if (o.t_s >= t_start_s) out.push_back(o);
  }
  return out;
}

Eigen::Vector3d PositionAt(const quad_core::VehicleState& paired, double t_s) {
  return paired.p_world_body + paired.v_world * (t_s - paired.t_s);
}

CameraPose CameraPoseAt(const quad_core::VehicleState& paired, double t_s, const CameraMount& mount) {
  const Eigen::Vector3d p_body = PositionAt(paired, t_s);
  const Eigen::Quaterniond q_body = paired.q_world_body.normalized();
  CameraPose pose;
  pose.p_world_camera = p_body + q_body * mount.p_body_camera;
  pose.q_world_camera = q_body * mount.q_body_camera;
  return pose;
}

}  // namespace fast_planner
