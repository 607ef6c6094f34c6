#include "fast_planner/labeller.h"

#include <cmath>
#include <stdexcept>

namespace fast_planner {

Labeller::Labeller(double acc_window_s) : acc_window_s_(acc_window_s) {
  if (!(std::isfinite(acc_window_s_) && acc_window_s_ >= 0.0)) {
    throw std::invalid_argument("Labeller: node.label_acc_window_s must be finite and >= 0, got " +
                                std::to_string(acc_window_s_));
  }
}

std::string Labeller::SetGoal(const PlannerManager& manager, const Eigen::Vector3d& goal) {
  const std::string why = manager.CheckGoal(goal);
  if (why.empty()) goal_ = goal;
  return why;
}

std::optional<Labeller::Request> Labeller::RequestAt(const OdometryHistory& history, double t_s,
                                                     double max_acc_mps2) const {
  if (!goal_) return std::nullopt;
  const quad_core::VehicleState* paired = history.PairedWith(t_s);
  if (!paired) return std::nullopt;
  Request r;
  r.odometry = *paired;
  r.request.start_p = PositionAt(*paired, t_s);
  r.request.start_v = paired->v_world;
  r.request.start_a = AccelerationFromOdometry(history.samples(), t_s, acc_window_s_, max_acc_mps2);
  r.request.goal = *goal_;
  r.request.start_time_s = t_s;
  return r;
}

std::optional<PlanResult> Labeller::Label(PlannerManager& manager, const OdometryHistory& history,
                                          double t_s) const {
  const std::optional<Request> r = RequestAt(history, t_s, manager.config().limits.max_acc_mps2);
  if (!r) return std::nullopt;
  manager.UpdateOdometry(r->odometry);
  return manager.Plan(r->request);
}

}  // namespace fast_planner
