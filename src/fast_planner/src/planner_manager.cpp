#include "fast_planner/planner_manager.h"

#include <time.h>
#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include "fast_planner/time_reallocation.h"
#include "quad_core/pairing.h"

namespace fast_planner {

namespace {

// Timings are the calling thread's CPU time: on a shared machine, wall time also counts the time other
// processes held the core, which says nothing about the planner.
double NowMs() {
  timespec ts;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return 1e3 * static_cast<double>(ts.tv_sec) + 1e-6 * static_cast<double>(ts.tv_nsec);
}

Eigen::Vector3d Vec3(const Eigen::VectorXd& v) { return Eigen::Vector3d(v[0], v[1], v[2]); }

// Optimisation attempts before the fitted (unoptimised) trajectory is tried: the first with the configured
// distance weight, the next with it multiplied by optimizer.collision_retry_factor.
constexpr int kOptimizationAttempts = 2;
// A vehicle slower than this is considered at rest when an emergency stop is planned.
constexpr double kAtRestSpeedMps = 1e-3;
// Duration of the "stop" trajectory of a vehicle already at rest.
constexpr double kHoldDurationS = 0.5;
// Time over which an emergency stop ramps the acceleration to full braking.
constexpr double kStopRampS = 0.3;

}  // namespace

std::string ValidateOdometry(const quad_core::VehicleState& o) {
  if (!std::isfinite(o.t_s)) return "odometry stamp is not finite";
  if (!o.p_world_body.allFinite()) return "odometry position is not finite";
  if (!o.v_world.allFinite()) return "odometry velocity is not finite";
  if (!o.w_body.allFinite()) return "odometry angular velocity is not finite";
  if (!o.q_world_body.coeffs().allFinite() || o.q_world_body.norm() < 1e-6) {
    return "odometry orientation is not a finite non-zero quaternion";
  }
  return "";
}

Eigen::Vector3d AccelerationFromOdometry(const std::deque<quad_core::VehicleState>& history, double t_s,
                                         double window_s, double max_acc_mps2) {
  if (!(window_s > 0.0)) return Eigen::Vector3d::Zero();
  auto newest = history.end();
  for (auto it = history.begin(); it != history.end(); ++it) {
    if (quad_core::OdometryNotNewerThanFrame(it->t_s, t_s)) newest = it;  // the pairing rule
  }
  if (newest == history.end()) return Eigen::Vector3d::Zero();
  auto older = history.end();
  for (auto it = history.begin(); it != newest; ++it) {
    if (it->t_s <= newest->t_s - window_s + 1e-9) older = it;
  }
  if (older == history.end()) return Eigen::Vector3d::Zero();
  const double dt = newest->t_s - older->t_s;
  Eigen::Vector3d a = (newest->v_world - older->v_world) / dt;
  if (!a.allFinite()) return Eigen::Vector3d::Zero();
  const double n = a.norm();
  if (n > max_acc_mps2) a *= max_acc_mps2 / n;
  return a;
}

const char* ToString(PlanStatus status) {
  switch (status) {
    case PlanStatus::kSuccess:
      return "success";
    case PlanStatus::kMapNotReady:
      return "map not ready";
    case PlanStatus::kInvalidStart:
      return "invalid start";
    case PlanStatus::kInvalidGoal:
      return "invalid goal";
    case PlanStatus::kFrontEndFailed:
      return "front end failed";
    case PlanStatus::kTrajectoryInCollision:
      return "trajectory in collision";
  }
  return "unknown";
}

PlannerManager::PlannerManager(const PlannerConfig& cfg)
    : cfg_((ValidatePlannerConfig(cfg), cfg)),
      map_(cfg.map),
      esdf_(cfg.map.esdf_max_distance_m),
      search_(cfg.search, cfg.limits),
      optimizer_(cfg.optimizer, cfg.limits) {}

void PlannerManager::Reset() {
  // The global source's map only changes in SetGlobalMap(): it stays, with its ESDF, for the next episode's
  // SetGlobalMap() to reuse when the world is the same.
  if (cfg_.map.source != MapSource::kGlobal) {
    map_.Reset();
    esdf_ = Esdf(cfg_.map.esdf_max_distance_m);
  }
  esdf_pending_.reset();
  global_map_set_ = false;
  last_depth_.reset();
  last_odom_.reset();
  next_traj_id_ = 1;
}

MapUpdateResult PlannerManager::UpdateDepth(std::shared_ptr<const DepthFrame> frame) {
  if (!frame) throw std::invalid_argument("PlannerManager::UpdateDepth: null frame");
  const std::string why = ValidateDepthFrame(*frame);
  if (!why.empty()) throw std::invalid_argument("PlannerManager::UpdateDepth: " + why);
  MapUpdateResult r;
  last_depth_ = std::move(frame);
  if (cfg_.map.source != MapSource::kDepth) return r;
  const double t0 = NowMs();
  r.stats = map_.IntegrateDepth(*last_depth_);
  const double t1 = NowMs();
  Eigen::Vector3i lo, hi;
  map_.LocalWindow(last_depth_->p_world_camera, &lo, &hi);
  if ((lo.array() <= hi.array()).all()) {
    if (cfg_.map.esdf_on_demand) {
      esdf_pending_ = std::make_pair(lo, hi);
    } else {
      UpdateEsdf(lo, hi);
      r.esdf_computed = true;
    }
  }
  const double t2 = NowMs();
  r.integrate_ms = t1 - t0;
  r.esdf_ms = t2 - t1;
  r.total_ms = t2 - t0;
  return r;
}

void PlannerManager::UpdateOdometry(const quad_core::VehicleState& odom) {
  const std::string why = ValidateOdometry(odom);
  if (!why.empty()) throw std::invalid_argument("PlannerManager::UpdateOdometry: " + why);
  last_odom_ = odom;
}

void PlannerManager::UpdateEsdf(const Eigen::Vector3i& min_idx, const Eigen::Vector3i& max_idx) {
  esdf_.Update(map_, min_idx, max_idx);
  ++esdf_updates_;
}

double PlannerManager::SetGlobalMap(const std::vector<Eigen::Vector3d>& occupied_points_world) {
  const double t0 = NowMs();
  esdf_pending_.reset();
  global_map_set_ = true;
  if (global_points_ && *global_points_ == occupied_points_world) return NowMs() - t0;
  global_points_.reset();  // until the map and the ESDF are rebuilt (Esdf::Update may throw)
  map_.Reset();
  map_.SetOccupied(occupied_points_world);
  // The x-y box of the observed obstacles between ground and ceiling, widened by the ESDF's truncation
  // distance and a voxel: outside it every distance is the truncation or the ground/ceiling distance, which
  // depends on z only, so the Esdf's clamping of positions into its window returns the whole map's field
  // there (equal up to the rounding of the interpolation weights: test_planner_manager.cpp).
  const Eigen::Vector3i size = map_.size_voxels();
  const int z_lo = std::max(0, map_.ground_layer() + 1);
  const int z_hi = std::min(size.z() - 1, map_.ceiling_layer() - 1);
  Eigen::Vector3i lo(size.x(), size.y(), 0), hi(-1, -1, size.z() - 1);
  for (const Eigen::Vector3d& p : occupied_points_world) {
    if (!p.allFinite() || !map_.InMap(p)) continue;
    const Eigen::Vector3i idx = map_.ToIndex(p);
    if (idx.z() < z_lo || idx.z() > z_hi) continue;
    lo = lo.cwiseMin(idx);
    hi = hi.cwiseMax(idx);
  }
  if (hi.x() < 0) {
    lo.head<2>().setZero();  // no obstacle: the field depends on z only; one x-y column holds it
    hi.head<2>().setZero();
  }
  const int margin = static_cast<int>(std::ceil(cfg_.map.esdf_max_distance_m / map_.resolution())) + 1;
  lo.head<2>() = (lo.head<2>().array() - margin).max(0);
  hi.head<2>() = (hi.head<2>().array() + margin).min(size.head<2>().array() - 1);
  lo.z() = 0;
  if (z_lo <= z_hi) {
    UpdateEsdf(lo, hi);
    esdf_.ReleaseScratch();
  } else {
    esdf_ = Esdf(cfg_.map.esdf_max_distance_m);  // the map lies entirely in the ground or the ceiling
  }
  global_points_ = occupied_points_world;
  return NowMs() - t0;
}

bool PlannerManager::MapReady() const {
  return cfg_.map.source == MapSource::kGlobal ? global_map_set_ : last_depth_ != nullptr;
}

std::string PlannerManager::CheckGoal(const Eigen::Vector3d& goal) const {
  if (!goal.allFinite()) return "goal is not finite";
  if (!map_.InMap(goal)) {
    std::ostringstream s;
    s << "goal (" << goal.transpose() << ") is outside the map [" << map_.origin().transpose() << "] - ["
      << map_.max_corner().transpose() << "]";
    return s.str();
  }
  if (map_.IsOccupied(goal))
    return "goal is inside an obstacle (or at/below the ground or at/above the ceiling)";
  if (map_.IsInflated(goal)) {
    std::ostringstream s;
    s << "goal is within " << map_.inflation_m() << " m of an obstacle (or the ground/ceiling)";
    return s.str();
  }
  return "";
}

double PlannerManager::EscapeRadius(const Eigen::Vector3d& start) const {
  return map_.IsInflated(start) ? map_.inflation_m() + map_.resolution() : 0.0;
}

PlanResult PlannerManager::Fail(PlanStatus status, const std::string& reason, const PlanRequest& request,
                                double t0_ms) const {
  PlanResult r;
  r.status = status;
  r.reason = std::string(ToString(status)) + ": " + reason;
  r.start_time_s = request.start_time_s;
  r.timings.total_ms = NowMs() - t0_ms;
  return r;
}

std::optional<double> PlannerManager::FirstCollision(const quad_core::NonUniformBspline& spline,
                                                     double t_from,
                                                     const Eigen::Vector3d& escape_center) const {
  const double t_end = spline.tmax();
  t_from = std::max(t_from, spline.tmin());
  if (t_from >= t_end) return std::nullopt;
  const double speed_bound = std::max(spline.Derivative().MaxCtrlPtNorm(), 1e-3);
  const double dt = cfg_.optimizer.check_step_m / speed_bound;
  const int n = std::max(1, static_cast<int>(std::ceil((t_end - t_from) / dt)));
  const double step = (t_end - t_from) / n;
  const double escape = EscapeRadius(escape_center);
  for (int i = 0; i <= n; ++i) {
    const double t = t_from + i * step;
    const Eigen::Vector3d p = Vec3(spline.Evaluate(t));
    const Eigen::Vector3i idx = map_.ToIndex(p);
    if (!map_.IsInflated(idx)) continue;
    if (escape > 0.0 && (p - escape_center).norm() <= escape && map_.InMap(idx) && !map_.IsOccupied(idx))
      continue;
    return t;
  }
  return std::nullopt;
}

PlanResult PlannerManager::Plan(const PlanRequest& request) {
  // Map preparation, not planning: outside total_ms (as a depth frame's ESDF update is), in map_prep_ms.
  // (The global source's ESDF was computed once by SetGlobalMap.)
  const double t_prep = NowMs();
  if (esdf_pending_) {
    UpdateEsdf(esdf_pending_->first, esdf_pending_->second);
    esdf_pending_.reset();
  }
  const double map_prep_ms = NowMs() - t_prep;
  PlanResult r = PlanOnPreparedMap(request);
  r.timings.map_prep_ms = map_prep_ms;
  return r;
}

PlanResult PlannerManager::PlanOnPreparedMap(const PlanRequest& request) {
  const double t0 = NowMs();
  if (!MapReady()) {
    // Planning blind would be planning through unseen space (and record a plan without its observation).
    return Fail(
        PlanStatus::kMapNotReady,
        cfg_.map.source == MapSource::kGlobal ? "no global map received yet" : "no depth frame received yet",
        request, t0);
  }
  if (!request.start_p.allFinite() || !request.start_v.allFinite() || !request.start_a.allFinite() ||
      !std::isfinite(request.start_time_s)) {
    return Fail(PlanStatus::kInvalidStart, "start state is not finite", request, t0);
  }
  if (!map_.InMap(request.start_p))
    return Fail(PlanStatus::kInvalidStart, "start is outside the map", request, t0);
  if (map_.IsOccupied(request.start_p)) {
    return Fail(PlanStatus::kInvalidStart, "start is inside an obstacle", request, t0);
  }
  const std::string goal_problem = CheckGoal(request.goal);
  if (!goal_problem.empty()) return Fail(PlanStatus::kInvalidGoal, goal_problem, request, t0);

  const double horizon =
      cfg_.map.source == MapSource::kGlobal ? (map_.max_corner() - map_.origin()).norm() : 0.0;
  SearchResult search =
      search_.Search(map_, request.start_p, request.start_v, request.start_a, request.goal, horizon);
  const double t_front = NowMs();
  if (!search.ok()) {
    PlanResult r = Fail(PlanStatus::kFrontEndFailed, search.reason, request, t0);
    r.search_status = search.status;
    r.timings.frontend_ms = t_front - t0;
    return r;
  }

  PlanResult result;
  result.search_status = search.status;
  result.reaches_goal = search.status == SearchStatus::kReachedGoal;
  result.start_time_s = request.start_time_s;
  result.timings.frontend_ms = t_front - t0;
  result.ends_at_rest = search.ends_at_rest();
  const bool fix_end = result.ends_at_rest;
  const Eigen::Vector3d end_target = search.path.Position(search.path.duration_s());
  double ts = 0.0;
  double t = NowMs();
  const Eigen::MatrixXd fitted = FitUniformBspline(
      search.path, cfg_.optimizer.ctrl_pt_dist_m / cfg_.limits.max_vel_mps, request.start_a, fix_end, &ts);
  result.timings.optimization_ms += NowMs() - t;
  result.initial_ctrl_pts = fitted;
  result.frontend_path = std::move(search.path);

  double weight_scale = 1.0;
  std::string last_problem;
  for (int attempt = 0; attempt <= kOptimizationAttempts; ++attempt) {
    ++result.attempts;
    Eigen::MatrixXd q;
    t = NowMs();
    if (attempt < kOptimizationAttempts) {
      const OptimizationResult opt =
          optimizer_.Optimize(fitted, ts, esdf_, fix_end, end_target, weight_scale);
      q = opt.ctrl_pts;
      result.optimizer_evaluations += opt.evaluations;
      weight_scale *= cfg_.optimizer.collision_retry_factor;
    } else {
      q = fitted;  // the front end's path is collision free; its fit usually is too
    }
    result.timings.optimization_ms += NowMs() - t;
    if (!q.allFinite()) {
      last_problem = "optimisation produced non-finite control points";
      continue;
    }
    t = NowMs();
    const ReallocationResult realloc = ReallocateTime(
        quad_core::NonUniformBspline::Uniform(q, kSplineDegree, ts), cfg_.limits,
        cfg_.optimizer.realloc_max_iterations, cfg_.optimizer.realloc_margin, StartPolicy::kKeep);
    result.timings.reallocation_ms += NowMs() - t;
    t = NowMs();
    const std::optional<double> hit = FirstCollision(realloc.spline, 0.0, request.start_p);
    result.timings.check_ms += NowMs() - t;
    if (hit) {
      std::ostringstream s;
      s << "attempt " << attempt + 1 << " enters the inflated map at t = " << *hit << " s ("
        << Vec3(realloc.spline.Evaluate(*hit)).transpose() << ")";
      last_problem = s.str();
      continue;
    }
    result.spline = realloc.spline;
    result.start_state_kept = realloc.start_kept;
    break;
  }
  result.timings.total_ms = NowMs() - t0;
  if (!result.spline) {
    result.status = PlanStatus::kTrajectoryInCollision;
    result.reason = std::string(ToString(result.status)) + ": " + last_problem;
    return result;
  }
  result.status = PlanStatus::kSuccess;
  result.traj_id = next_traj_id_++;
  std::ostringstream s;
  s << "success: " << ToString(search.status) << ", " << result.spline->duration() << " s, attempt "
    << result.attempts;
  result.reason = s.str();
  if (observer_) {
    PlanRecord record;
    record.depth = last_depth_;
    record.odometry = last_odom_;
    record.goal = request.goal;
    record.request = request;
    record.result = &result;
    observer_->OnPlan(record);
  }
  return result;
}

PlanResult PlannerManager::PlanStop(const Eigen::Vector3d& p, const Eigen::Vector3d& v,
                                    const Eigen::Vector3d& a, double start_time_s) {
  const double t0 = NowMs();
  // Ramp the acceleration from the current one to full braking at constant jerk (so the trajectory continues
  // the one being flown), then brake along the direction of motion to rest.
  PolyPath path;
  const double speed = v.norm();
  if (speed < kAtRestSpeedMps) {
    path.Append(PolySegment::Primitive(p, Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero(), kHoldDurationS));
  } else {
    const Eigen::Vector3d a_brake = -v / speed * cfg_.limits.max_acc_mps2;
    PolySegment ramp = PolySegment::Primitive(p, v, a, kStopRampS);
    ramp.coeffs.col(3) = (a_brake - a) / (6.0 * kStopRampS);
    path.Append(ramp);
    const Eigen::Vector3d p1 = ramp.Position(kStopRampS), v1 = ramp.Velocity(kStopRampS);
    const double speed1 = v1.norm();
    if (speed1 > kAtRestSpeedMps) {
      path.Append(PolySegment::Primitive(p1, v1, -v1 / speed1 * cfg_.limits.max_acc_mps2,
                                         speed1 / cfg_.limits.max_acc_mps2));
    }
  }
  double ts = 0.0;
  const Eigen::MatrixXd q =
      FitUniformBspline(path, cfg_.optimizer.ctrl_pt_dist_m / cfg_.limits.max_vel_mps, a, true, &ts);
  const ReallocationResult realloc = ReallocateTime(
      quad_core::NonUniformBspline::Uniform(q, kSplineDegree, ts), cfg_.limits,
      cfg_.optimizer.realloc_max_iterations, cfg_.optimizer.realloc_margin, StartPolicy::kKeep);
  PlanResult r;
  r.status = PlanStatus::kSuccess;
  r.reason = "emergency stop";
  r.ends_at_rest = true;
  r.traj_id = next_traj_id_++;
  r.start_time_s = start_time_s;
  r.spline = realloc.spline;
  r.frontend_path = path;
  r.initial_ctrl_pts = q;
  r.timings.total_ms = NowMs() - t0;
  return r;
}

}  // namespace fast_planner
