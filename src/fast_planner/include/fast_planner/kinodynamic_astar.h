// Kinodynamic A*: the front end (Zhou et al. 2019, Sec. III).
//
// A search over double-integrator motion primitives: from a state (p, v) each primitive applies a constant
// acceleration u from a discretised set (levels per axis, |u| <= a_max) for tau seconds. Edge cost
// (|u|^2 + rho) tau; heuristic the closed-form minimum time-effort cost to the goal at rest (obvp.h),
// weighted. States are pruned per position cell (hybrid-A* style). An analytic expansion ("shot"), the
// optimal cubic from a node to the goal, is tried from nodes within shot_radius of the goal and accepted only
// when it is collision free AND within the velocity and acceleration limits (Fast-Planner left the shot's
// velocity unchecked); slower shots are tried when the optimal one is too fast. Primitives and shots are
// checked against the inflated map at spacing <= collision_step_m (Fast-Planner checked a fixed number of
// points per primitive, which lets fast primitives jump through thin obstacles).
//
// Local planning: when the goal is beyond the horizon, the search ends at the first expanded node farther
// than the horizon from the start (kReachedHorizon); when the goal is within it, nodes beyond the horizon are
// not expanded and the search reaches the goal or reports that there is no path.
#pragma once

#include <Eigen/Core>

#include <string>
#include <unordered_map>
#include <vector>

#include "fast_planner/planner_config.h"
#include "fast_planner/poly_path.h"
#include "fast_planner/voxel_map.h"

namespace fast_planner {

enum class SearchStatus {
  kReachedGoal,
  kReachedHorizon,
  kReachedSafeStop,
  kNoPath,
  kNodeBudgetExhausted,
  kStartInCollision,
  kGoalInCollision,
  kOutsideMap,
  kInvalidInput,
};
const char* ToString(SearchStatus status);

struct SearchResult {
  SearchStatus status = SearchStatus::kNoPath;
  std::string reason;  // printable: the status and its circumstances
  PolyPath path;       // from the start state; non-empty exactly when ok()
  int expansions = 0;
  int nodes = 0;
  bool ends_with_shot = false;
  bool ok() const {
    return status == SearchStatus::kReachedGoal || status == SearchStatus::kReachedHorizon ||
           status == SearchStatus::kReachedSafeStop;
  }
  // The path ends at rest (at the goal, or a safe stop).
  bool ends_at_rest() const {
    return status == SearchStatus::kReachedGoal || status == SearchStatus::kReachedSafeStop;
  }
};

class KinodynamicAstar {
 public:
  // Throws quad_core::ConfigError on invalid search or limit values.
  KinodynamicAstar(const SearchConfig& search, const LimitsConfig& limits);

  // Searches from (start_p, start_v) to goal_p at rest. horizon_m <= 0 means the configured horizon. The
  // first expansion keeps the start acceleration start_a (clamped to a_max) for a fraction or all of a
  // primitive's duration, as Fast-Planner does when replanning: the path then continues the trajectory being
  // flown, and the B-spline fitted to it has no acceleration jump right after its start.
  SearchResult Search(const VoxelMap& map, const Eigen::Vector3d& start_p, const Eigen::Vector3d& start_v,
                      const Eigen::Vector3d& start_a, const Eigen::Vector3d& goal_p, double horizon_m = 0.0);

  // The heuristic (unweighted): minimum time-effort cost from (p, v) to the goal at rest.
  double Heuristic(const Eigen::Vector3d& p, const Eigen::Vector3d& v, const Eigen::Vector3d& goal) const;

  // True when the segment stays out of the inflated map (sampled at collision_step_m); samples within
  // escape_radius_m of escape_center may be inflated but not occupied (leaving an inflated start).
  bool SegmentIsFree(const VoxelMap& map, const PolySegment& seg, const Eigen::Vector3d& escape_center,
                     double escape_radius_m) const;
  // True when speed <= max_vel and |acceleration| <= max_acc along the segment (sampled like SegmentIsFree).
  bool SegmentWithinLimits(const PolySegment& seg) const;

  const std::vector<Eigen::Vector3d>& inputs() const { return inputs_; }

 private:
  struct Node {
    Eigen::Vector3d p, v, u;
    double tau = 0.0;
    double g = 0.0;
    double f = 0.0;
    int parent = -1;
    bool closed = false;
  };

  int64_t CellKey(const VoxelMap& map, const Eigen::Vector3d& p) const;
  int SampleCount(const PolySegment& seg) const;
  // The shot from (p, v) to the goal at rest that is free and within limits, trying slower ones if needed.
  bool TryShot(const VoxelMap& map, const Eigen::Vector3d& p, const Eigen::Vector3d& v,
               const Eigen::Vector3d& goal, const Eigen::Vector3d& escape_center, double escape_radius_m,
               PolySegment* shot) const;
  PolyPath Backtrack(int node) const;

  SearchConfig cfg_;
  LimitsConfig limits_;
  std::vector<Eigen::Vector3d> inputs_;
  std::vector<Node> nodes_;
  std::unordered_map<int64_t, int> cell_to_node_;
};

}  // namespace fast_planner
