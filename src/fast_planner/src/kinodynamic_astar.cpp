#include "fast_planner/kinodynamic_astar.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <queue>
#include <sstream>

#include "fast_planner/obvp.h"

namespace fast_planner {

const char* ToString(SearchStatus status) {
  switch (status) {
    case SearchStatus::kReachedGoal:
      return "reached goal";
    case SearchStatus::kReachedHorizon:
      return "reached horizon";
    case SearchStatus::kReachedSafeStop:
      return "reached safe stop";
    case SearchStatus::kNoPath:
      return "no path";
    case SearchStatus::kNodeBudgetExhausted:
      return "node budget exhausted";
    case SearchStatus::kStartInCollision:
      return "start in collision";
    case SearchStatus::kGoalInCollision:
      return "goal in collision";
    case SearchStatus::kOutsideMap:
      return "outside the map";
    case SearchStatus::kInvalidInput:
      return "invalid input";
  }
  return "unknown";
}

namespace {

constexpr double kLimitSlack = 1e-6;
constexpr int kMaxSamplesPerSegment = 20000;
constexpr int kSlowerShots = 3;
constexpr double kSlowerShotFactor = 1.3;
constexpr double kMinShotDurationS = 0.1;
// A start slower than this is at rest: stopping safely there is hovering, not a plan.
constexpr double kMovingStartMps = 0.3;
// Durations (fractions of a primitive's) of the first expansion, which keeps the start acceleration.
constexpr int kStartDurations = 3;

SearchResult Fail(SearchStatus status, const std::string& detail) {
  SearchResult r;
  r.status = status;
  r.reason = std::string(ToString(status)) + (detail.empty() ? "" : ": " + detail);
  return r;
}

}  // namespace

KinodynamicAstar::KinodynamicAstar(const SearchConfig& search, const LimitsConfig& limits)
    : cfg_(search), limits_(limits) {
  ValidateSearchConfig(search);
  ValidateLimitsConfig(limits);

  const int half = cfg_.acc_levels_per_axis / 2;
  const double step = limits_.max_acc_mps2 / half;
  for (int i = -half; i <= half; ++i) {
    for (int j = -half; j <= half; ++j) {
      for (int k = -half; k <= half; ++k) {
        const Eigen::Vector3d u(i * step, j * step, k * step);
        if (u.norm() <= limits_.max_acc_mps2 * (1.0 + kLimitSlack)) inputs_.push_back(u);
      }
    }
  }
  nodes_.reserve(cfg_.max_nodes);
  cell_to_node_.reserve(2 * cfg_.max_nodes);
}

int64_t KinodynamicAstar::CellKey(const VoxelMap& map, const Eigen::Vector3d& p) const {
  const Eigen::Vector3d rel = (p - map.origin()) / cfg_.resolution_m;
  // 21 bits per axis: +-1e6 cells, far beyond any map.
  const int64_t x = static_cast<int64_t>(std::floor(rel.x())) + (1 << 20);
  const int64_t y = static_cast<int64_t>(std::floor(rel.y())) + (1 << 20);
  const int64_t z = static_cast<int64_t>(std::floor(rel.z())) + (1 << 20);
  return (x << 42) | (y << 21) | z;
}

double KinodynamicAstar::Heuristic(const Eigen::Vector3d& p, const Eigen::Vector3d& v,
                                   const Eigen::Vector3d& goal) const {
  const double t_min = (goal - p).cwiseAbs().maxCoeff() / limits_.max_vel_mps;
  return SolveObvp(p, v, goal, Eigen::Vector3d::Zero(), cfg_.time_weight, t_min).cost;
}

int KinodynamicAstar::SampleCount(const PolySegment& seg) const {
  const double T = seg.duration_s;
  const double speed_bound =
      seg.coeffs.col(1).norm() + 2.0 * seg.coeffs.col(2).norm() * T + 3.0 * seg.coeffs.col(3).norm() * T * T;
  const double n = std::ceil(speed_bound * T / cfg_.collision_step_m);
  return static_cast<int>(std::clamp(n, 1.0, static_cast<double>(kMaxSamplesPerSegment)));
}

bool KinodynamicAstar::SegmentIsFree(const VoxelMap& map, const PolySegment& seg,
                                     const Eigen::Vector3d& escape_center, double escape_radius_m) const {
  const int n = SampleCount(seg);
  const double dt = seg.duration_s / n;
  const double r2 = escape_radius_m * escape_radius_m;
  for (int i = 1; i <= n; ++i) {
    const Eigen::Vector3d p = seg.Position(i * dt);
    const Eigen::Vector3i idx = map.ToIndex(p);
    if (!map.IsInflated(idx)) continue;
    if (r2 > 0.0 && (p - escape_center).squaredNorm() <= r2 && map.InMap(idx) && !map.IsOccupied(idx))
      continue;
    return false;
  }
  return true;
}

bool KinodynamicAstar::SegmentWithinLimits(const PolySegment& seg) const {
  const double v2 = limits_.max_vel_mps * limits_.max_vel_mps * (1.0 + kLimitSlack);
  const double a2 = limits_.max_acc_mps2 * limits_.max_acc_mps2 * (1.0 + kLimitSlack);
  const int n = SampleCount(seg);
  const double dt = seg.duration_s / n;
  for (int i = 0; i <= n; ++i) {
    const double t = i * dt;
    if (seg.Velocity(t).squaredNorm() > v2 || seg.Acceleration(t).squaredNorm() > a2) return false;
  }
  return true;
}

bool KinodynamicAstar::TryShot(const VoxelMap& map, const Eigen::Vector3d& p, const Eigen::Vector3d& v,
                               const Eigen::Vector3d& goal, const Eigen::Vector3d& escape_center,
                               double escape_radius_m, PolySegment* shot) const {
  const double t_min = (goal - p).cwiseAbs().maxCoeff() / limits_.max_vel_mps;
  const ObvpSolution sol = SolveObvp(p, v, goal, Eigen::Vector3d::Zero(), cfg_.time_weight, t_min);
  if (!std::isfinite(sol.duration_s)) return false;
  // At (or next to) the goal at rest the optimal duration tends to zero: fly a short, slow shot instead.
  double T = std::max(sol.duration_s, kMinShotDurationS);
  for (int k = 0; k <= kSlowerShots; ++k, T *= kSlowerShotFactor) {
    const PolySegment seg = ObvpSegment(p, v, goal, Eigen::Vector3d::Zero(), T);
    if (!SegmentWithinLimits(seg)) continue;
    // Slower shots bulge differently but a collision does not go away by flying slower along a similar curve;
    // checking every candidate keeps the rule simple: the accepted shot is free and feasible.
    if (!SegmentIsFree(map, seg, escape_center, escape_radius_m)) continue;
    *shot = seg;
    return true;
  }
  return false;
}

PolyPath KinodynamicAstar::Backtrack(int node) const {
  std::vector<int> chain;
  for (int i = node; nodes_[i].parent >= 0; i = nodes_[i].parent) chain.push_back(i);
  PolyPath path;
  for (auto it = chain.rbegin(); it != chain.rend(); ++it) {
    const Node& n = nodes_[*it];
    const Node& parent = nodes_[n.parent];
    path.Append(PolySegment::Primitive(parent.p, parent.v, n.u, n.tau));
  }
  return path;
}

SearchResult KinodynamicAstar::Search(const VoxelMap& map, const Eigen::Vector3d& start_p,
                                      const Eigen::Vector3d& start_v, const Eigen::Vector3d& start_a,
                                      const Eigen::Vector3d& goal_p, double horizon_m) {
  if (!start_p.allFinite() || !start_v.allFinite() || !start_a.allFinite() || !goal_p.allFinite()) {
    return Fail(SearchStatus::kInvalidInput, "start or goal is not finite");
  }
  if (!map.InMap(start_p)) return Fail(SearchStatus::kOutsideMap, "start is outside the map");
  if (!map.InMap(goal_p)) return Fail(SearchStatus::kOutsideMap, "goal is outside the map");
  if (map.IsOccupied(start_p)) return Fail(SearchStatus::kStartInCollision, "start voxel is occupied");
  if (map.IsOccupied(goal_p)) return Fail(SearchStatus::kGoalInCollision, "goal voxel is occupied");
  if (map.IsInflated(goal_p)) {
    return Fail(SearchStatus::kGoalInCollision, "goal is within the inflation radius of an obstacle");
  }
  const double horizon = horizon_m > 0.0 ? horizon_m : cfg_.horizon_m;
  const bool goal_beyond_horizon = (goal_p - start_p).norm() > horizon;
  // Leaving an inflated (but free) start is allowed within the inflation radius of it.
  const double escape_radius = map.IsInflated(start_p) ? map.inflation_m() + map.resolution() : 0.0;
  const double v_start = start_v.norm();
  const double v_limit = std::max(limits_.max_vel_mps, v_start) * (1.0 + kLimitSlack);

  nodes_.clear();
  cell_to_node_.clear();
  using Entry = std::pair<double, int>;
  std::priority_queue<Entry, std::vector<Entry>, std::greater<Entry>> open;

  Node start;
  start.p = start_p;
  start.v = start_v;
  start.u.setZero();
  start.g = 0.0;
  start.f = cfg_.heuristic_weight * Heuristic(start_p, start_v, goal_p);
  nodes_.push_back(start);
  cell_to_node_[CellKey(map, start_p)] = 0;
  open.emplace(start.f, 0);

  SearchResult result;
  // The best node (by heuristic) from which full braking is collision free, and its braking segment.
  const bool track_stops = v_start > kMovingStartMps;
  int best_stop = -1;
  double best_stop_h = std::numeric_limits<double>::infinity();
  PolySegment best_brake;
  while (!open.empty()) {
    const auto [f, id] = open.top();
    open.pop();
    if (nodes_[id].closed || f != nodes_[id].f) continue;  // stale entry
    nodes_[id].closed = true;
    const Node cur = nodes_[id];
    ++result.expansions;

    const double dist_from_start = (cur.p - start_p).norm();
    if (dist_from_start >= horizon) {
      if (goal_beyond_horizon) {
        result.status = SearchStatus::kReachedHorizon;
        result.path = Backtrack(id);
        break;
      }
      continue;  // the goal is within the horizon: do not wander beyond it
    }
    if (track_stops) {
      const double h = cur.f - cur.g;  // the weighted heuristic of the node
      if (h < best_stop_h) {
        const double speed = cur.v.norm();
        const PolySegment brake = PolySegment::Primitive(
            cur.p, cur.v,
            speed > 0.0 ? Eigen::Vector3d(-cur.v / speed * limits_.max_acc_mps2) : Eigen::Vector3d::Zero(),
            std::max(speed / limits_.max_acc_mps2, 1e-3));
        if (SegmentIsFree(map, brake, start_p, escape_radius)) {
          best_stop = id;
          best_stop_h = h;
          best_brake = brake;
        }
      }
    }
    if ((cur.p - goal_p).norm() <= cfg_.shot_radius_m) {
      PolySegment shot;
      if (TryShot(map, cur.p, cur.v, goal_p, start_p, escape_radius, &shot)) {
        result.status = SearchStatus::kReachedGoal;
        result.path = Backtrack(id);
        result.path.Append(shot);
        result.ends_with_shot = true;
        break;
      }
    }

    const int64_t cur_key = CellKey(map, cur.p);
    // From the start: first the start acceleration for 1/3, 2/3 and all of a primitive's duration; only if
    // that leads nowhere (e.g. at rest), the regular inputs.
    const double a_norm = start_a.norm();
    const Eigen::Vector3d u_start =
        a_norm > limits_.max_acc_mps2 ? Eigen::Vector3d(start_a * (limits_.max_acc_mps2 / a_norm)) : start_a;
    int children = 0;
    for (int pass = id == 0 ? 0 : 1; pass < 2 && children == 0; ++pass) {
      const bool keep_start_acc = pass == 0;
      const int num_expansions = keep_start_acc ? kStartDurations : static_cast<int>(inputs_.size());
      for (int e = 0; e < num_expansions; ++e) {
        const Eigen::Vector3d& u = keep_start_acc ? u_start : inputs_[e];
        const double tau = keep_start_acc ? cfg_.primitive_duration_s * (e + 1) / kStartDurations
                                          : cfg_.primitive_duration_s;
        const Eigen::Vector3d v1 = cur.v + u * tau;
        if (v1.norm() > v_limit) continue;
        const Eigen::Vector3d p1 = cur.p + cur.v * tau + 0.5 * u * tau * tau;
        const int64_t key = CellKey(map, p1);
        if (key == cur_key) continue;
        const double g = cur.g + (u.squaredNorm() + cfg_.time_weight) * tau;
        const auto it = cell_to_node_.find(key);
        if (it != cell_to_node_.end()) {
          const Node& other = nodes_[it->second];
          if (other.closed || other.g <= g) continue;
        }
        const PolySegment prim = PolySegment::Primitive(cur.p, cur.v, u, tau);
        if (!SegmentIsFree(map, prim, start_p, escape_radius)) continue;
        const double h = Heuristic(p1, v1, goal_p);
        Node child;
        child.p = p1;
        child.v = v1;
        child.u = u;
        child.tau = tau;
        child.g = g;
        child.f = g + cfg_.heuristic_weight * h;
        child.parent = id;
        ++children;
        if (it != cell_to_node_.end()) {
          nodes_[it->second] = child;  // a cheaper way into the same cell replaces the open node
          open.emplace(child.f, it->second);
        } else {
          if (static_cast<int>(nodes_.size()) >= cfg_.max_nodes) {
            result.status = SearchStatus::kNodeBudgetExhausted;
            break;
          }
          nodes_.push_back(child);
          const int child_id = static_cast<int>(nodes_.size()) - 1;
          cell_to_node_.emplace(key, child_id);
          open.emplace(child.f, child_id);
        }
      }
      if (result.status == SearchStatus::kNodeBudgetExhausted) break;
    }
    if (result.status == SearchStatus::kNodeBudgetExhausted) break;
  }

  std::string failure;
  if ((result.status == SearchStatus::kNoPath || result.status == SearchStatus::kNodeBudgetExhausted) &&
      best_stop >= 0) {
    failure = std::string(" after ") + ToString(result.status);
    result.status = SearchStatus::kReachedSafeStop;
    result.path = Backtrack(best_stop);
    result.path.Append(best_brake);
  }
  result.nodes = static_cast<int>(nodes_.size());
  std::ostringstream detail;
  if (result.status == SearchStatus::kNoPath) {
    detail << "every reachable state within " << horizon << " m was expanded (" << result.expansions
           << " expansions)";
  } else if (result.status == SearchStatus::kNodeBudgetExhausted) {
    detail << "more than " << cfg_.max_nodes << " nodes (" << result.expansions << " expansions)";
  } else {
    detail << result.expansions << " expansions, " << result.path.segments().size() << " segments, "
           << result.path.duration_s() << " s" << failure;
  }
  result.reason = std::string(ToString(result.status)) + ": " + detail.str();
  return result;
}

}  // namespace fast_planner
