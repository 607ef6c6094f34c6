#include "fast_planner/planner_config.h"

#include <quad_core/strict_yaml.h>

#include <cmath>
#include <sstream>
#include <vector>

namespace fast_planner {

using quad_core::AtLeast;
using quad_core::ConfigError;
using quad_core::InRange;
using quad_core::NonNegative;
using quad_core::Positive;
using quad_core::StrictYaml;

const char* ToString(MapSource source) {
  switch (source) {
    case MapSource::kDepth:
      return "depth";
    case MapSource::kGlobal:
      return "global";
  }
  return "unknown";
}

namespace {

Eigen::Vector3d GetVec3(StrictYaml& y, const std::string& key, const quad_core::Check& check = nullptr) {
  const auto v = y.Get<std::vector<double>>(key, check);
  if (v.size() != 3) {
    throw ConfigError(y.source() + ": key '" + key + "' must be a list of 3 numbers, got " +
                      std::to_string(v.size()));
  }
  return {v[0], v[1], v[2]};
}

[[noreturn]] void Fail(const std::string& key, double value, const std::string& why) {
  std::ostringstream s;
  s << "PlannerConfig: key '" << key << "' has value " << value << " which " << why;
  throw ConfigError(s.str());
}

void CheckPositive(const std::string& key, double v) {
  if (!(std::isfinite(v) && v > 0.0)) Fail(key, v, "must be > 0");
}

void CheckRange(const std::string& key, double v, double lo, double hi) {
  if (!(std::isfinite(v) && v >= lo && v <= hi)) {
    std::ostringstream s;
    s << "must be in [" << lo << ", " << hi << "]";
    Fail(key, v, s.str());
  }
}

}  // namespace

PlannerConfig ReadPlannerConfig(StrictYaml& y) {
  PlannerConfig c;
  c.limits.max_vel_mps = y.Get<double>("limits.max_vel_mps", Positive());
  c.limits.max_acc_mps2 = y.Get<double>("limits.max_acc_mps2", Positive());

  const std::string source = y.Get<std::string>("map.source");
  if (source == "depth") {
    c.map.source = MapSource::kDepth;
  } else if (source == "global") {
    c.map.source = MapSource::kGlobal;
  } else {
    throw ConfigError(y.source() + ": key 'map.source' has value '" + source +
                      "' which must be 'depth' or 'global'");
  }
  c.map.resolution_m = y.Get<double>("map.resolution_m", Positive());
  c.map.origin_m = GetVec3(y, "map.origin_m");
  c.map.size_m = GetVec3(y, "map.size_m", Positive());
  c.map.ground_z_m = y.Get<double>("map.ground_z_m");
  c.map.ceiling_z_m = y.Get<double>("map.ceiling_z_m");
  c.map.local_update_range_m = GetVec3(y, "map.local_update_range_m", Positive());
  c.map.inflation_m = y.Get<double>("map.inflation_m", NonNegative());
  c.map.esdf_max_distance_m = y.Get<double>("map.esdf_max_distance_m", Positive());
  c.map.esdf_on_demand = y.Get<bool>("map.esdf_on_demand");
  auto& d = c.map.depth;
  d.min_ray_length_m = y.Get<double>("map.depth.min_ray_length_m", NonNegative());
  d.max_ray_length_m = y.Get<double>("map.depth.max_ray_length_m", Positive());
  d.skip_pixel = y.Get<int>("map.depth.skip_pixel", AtLeast(1));
  d.prob_hit = y.Get<double>("map.depth.prob_hit", InRange(0.5, 0.999));
  d.prob_miss = y.Get<double>("map.depth.prob_miss", InRange(0.001, 0.5));
  d.prob_min = y.Get<double>("map.depth.prob_min", InRange(0.001, 0.5));
  d.prob_max = y.Get<double>("map.depth.prob_max", InRange(0.5, 0.999));
  d.prob_occupied = y.Get<double>("map.depth.prob_occupied", InRange(0.5, 0.999));

  auto& s = c.search;
  s.primitive_duration_s = y.Get<double>("search.primitive_duration_s", Positive());
  s.acc_levels_per_axis = y.Get<int>("search.acc_levels_per_axis", AtLeast(3));
  s.time_weight = y.Get<double>("search.time_weight", Positive());
  s.heuristic_weight = y.Get<double>("search.heuristic_weight", AtLeast(1.0));
  s.resolution_m = y.Get<double>("search.resolution_m", Positive());
  s.horizon_m = y.Get<double>("search.horizon_m", Positive());
  s.max_nodes = y.Get<int>("search.max_nodes", AtLeast(10));
  s.collision_step_m = y.Get<double>("search.collision_step_m", Positive());
  s.shot_radius_m = y.Get<double>("search.shot_radius_m", Positive());

  auto& o = c.optimizer;
  o.ctrl_pt_dist_m = y.Get<double>("optimizer.ctrl_pt_dist_m", Positive());
  o.w_smooth = y.Get<double>("optimizer.w_smooth", NonNegative());
  o.w_distance = y.Get<double>("optimizer.w_distance", NonNegative());
  o.w_feasibility = y.Get<double>("optimizer.w_feasibility", NonNegative());
  o.w_endpoint = y.Get<double>("optimizer.w_endpoint", NonNegative());
  o.safe_distance_m = y.Get<double>("optimizer.safe_distance_m", Positive());
  o.max_iterations = y.Get<int>("optimizer.max_iterations", AtLeast(1));
  o.realloc_max_iterations = y.Get<int>("optimizer.realloc_max_iterations", AtLeast(1));
  o.realloc_margin = y.Get<double>("optimizer.realloc_margin", InRange(1.0, 2.0));
  o.check_step_m = y.Get<double>("optimizer.check_step_m", Positive());
  o.collision_retry_factor = y.Get<double>("optimizer.collision_retry_factor", AtLeast(1.0));

  auto& f = c.fsm;
  f.replan_distance_m = y.Get<double>("fsm.replan_distance_m", Positive());
  f.goal_tolerance_m = y.Get<double>("fsm.goal_tolerance_m", Positive());
  f.stopped_speed_mps = y.Get<double>("fsm.stopped_speed_mps", Positive());
  f.max_consecutive_failures = y.Get<int>("fsm.max_consecutive_failures", AtLeast(1));
  f.replan_final_approach = y.Get<bool>("fsm.replan_final_approach");

  auto& n = c.node;
  n.odom_period_s = y.Get<double>("node.odom_period_s", Positive());
  n.tracker_accept_timeout_s = y.Get<double>("node.tracker_accept_timeout_s", NonNegative());
  n.label_acc_window_s = y.Get<double>("node.label_acc_window_s", NonNegative());
  n.collector_stats_period_s = y.Get<double>("node.collector_stats_period_s", NonNegative());

  y.CheckAllKeysUsed();
  ValidatePlannerConfig(c);
  return c;
}

PlannerConfig LoadPlannerConfig(const std::string& yaml_path) {
  StrictYaml y = StrictYaml::FromFile(yaml_path);
  return ReadPlannerConfig(y);
}

void ValidateMapConfig(const MapConfig& m) {
  CheckRange("map.resolution_m", m.resolution_m, 0.01, 1.0);
  for (int i = 0; i < 3; ++i) {
    const std::string axis = std::string(".") + "xyz"[i];
    if (!std::isfinite(m.origin_m[i])) Fail("map.origin_m" + axis, m.origin_m[i], "must be finite");
    CheckPositive("map.size_m" + axis, m.size_m[i]);
    if (m.size_m[i] < 4.0 * m.resolution_m) Fail("map.size_m" + axis, m.size_m[i], "must span >= 4 voxels");
    CheckPositive("map.local_update_range_m" + axis, m.local_update_range_m[i]);
  }
  const double voxels = (m.size_m.array() / m.resolution_m).prod();
  if (voxels > 4.0e8) Fail("map.size_m", voxels, "gives too many voxels (> 4e8) at this resolution");
  if (!(m.ceiling_z_m > m.ground_z_m + 2.0 * m.inflation_m + m.resolution_m)) {
    Fail("map.ceiling_z_m", m.ceiling_z_m, "must exceed map.ground_z_m + 2 inflation + 1 voxel");
  }
  if (m.ground_z_m < m.origin_m.z() || m.ground_z_m >= m.origin_m.z() + m.size_m.z()) {
    Fail("map.ground_z_m", m.ground_z_m, "must lie inside the map's z range");
  }
  CheckRange("map.inflation_m", m.inflation_m, 0.0, 2.0);
  if (m.inflation_m > 20.0 * m.resolution_m) Fail("map.inflation_m", m.inflation_m, "must be <= 20 voxels");
  if (!(m.esdf_max_distance_m >= m.resolution_m)) {
    Fail("map.esdf_max_distance_m", m.esdf_max_distance_m, "must be >= map.resolution_m");
  }
  const auto& d = m.depth;
  if (!(d.max_ray_length_m > d.min_ray_length_m)) {
    Fail("map.depth.max_ray_length_m", d.max_ray_length_m, "must exceed map.depth.min_ray_length_m");
  }
  if (d.skip_pixel < 1) Fail("map.depth.skip_pixel", d.skip_pixel, "must be >= 1");
  CheckRange("map.depth.prob_hit", d.prob_hit, 0.5, 0.999);
  CheckRange("map.depth.prob_miss", d.prob_miss, 0.001, 0.5);
  CheckRange("map.depth.prob_min", d.prob_min, 0.001, 0.5);
  CheckRange("map.depth.prob_max", d.prob_max, 0.5, 0.999);
  if (!(d.prob_occupied > d.prob_min && d.prob_occupied < d.prob_max)) {
    Fail("map.depth.prob_occupied", d.prob_occupied, "must lie strictly between prob_min and prob_max");
  }
}

void ValidateLimitsConfig(const LimitsConfig& l) {
  CheckPositive("limits.max_vel_mps", l.max_vel_mps);
  CheckPositive("limits.max_acc_mps2", l.max_acc_mps2);
}

void ValidateSearchConfig(const SearchConfig& s) {
  CheckRange("search.primitive_duration_s", s.primitive_duration_s, 0.05, 5.0);
  if (s.acc_levels_per_axis < 3 || s.acc_levels_per_axis % 2 == 0 || s.acc_levels_per_axis > 15) {
    Fail("search.acc_levels_per_axis", s.acc_levels_per_axis, "must be odd and in [3, 15]");
  }
  CheckPositive("search.time_weight", s.time_weight);
  if (!(s.heuristic_weight >= 1.0)) Fail("search.heuristic_weight", s.heuristic_weight, "must be >= 1");
  CheckRange("search.resolution_m", s.resolution_m, 0.01, 2.0);
  CheckPositive("search.horizon_m", s.horizon_m);
  if (s.max_nodes < 10) Fail("search.max_nodes", s.max_nodes, "must be >= 10");
  CheckRange("search.collision_step_m", s.collision_step_m, 1e-3, 1.0);
  CheckPositive("search.shot_radius_m", s.shot_radius_m);
}

void ValidateOptimizerConfig(const OptimizerConfig& o) {
  CheckRange("optimizer.ctrl_pt_dist_m", o.ctrl_pt_dist_m, 0.05, 5.0);
  for (const auto& [key, v] : {std::pair<const char*, double>{"optimizer.w_smooth", o.w_smooth},
                               {"optimizer.w_distance", o.w_distance},
                               {"optimizer.w_feasibility", o.w_feasibility},
                               {"optimizer.w_endpoint", o.w_endpoint}}) {
    if (!(std::isfinite(v) && v >= 0.0)) Fail(key, v, "must be >= 0");
  }
  CheckPositive("optimizer.safe_distance_m", o.safe_distance_m);
  if (o.max_iterations < 1) Fail("optimizer.max_iterations", o.max_iterations, "must be >= 1");
  if (o.realloc_max_iterations < 1) {
    Fail("optimizer.realloc_max_iterations", o.realloc_max_iterations, "must be >= 1");
  }
  CheckRange("optimizer.realloc_margin", o.realloc_margin, 1.0, 2.0);
  CheckRange("optimizer.check_step_m", o.check_step_m, 1e-3, 1.0);
  if (!(o.collision_retry_factor >= 1.0)) {
    Fail("optimizer.collision_retry_factor", o.collision_retry_factor, "must be >= 1");
  }
}

void ValidateFsmConfig(const FsmConfig& f) {
  CheckPositive("fsm.replan_distance_m", f.replan_distance_m);
  CheckPositive("fsm.goal_tolerance_m", f.goal_tolerance_m);
  CheckPositive("fsm.stopped_speed_mps", f.stopped_speed_mps);
  if (f.max_consecutive_failures < 1) {
    Fail("fsm.max_consecutive_failures", f.max_consecutive_failures, "must be >= 1");
  }
}

void ValidateNodeConfig(const NodeConfig& n) {
  CheckRange("node.odom_period_s", n.odom_period_s, 1e-4, 1.0);
  CheckRange("node.tracker_accept_timeout_s", n.tracker_accept_timeout_s, 0.0, 60.0);
  CheckRange("node.label_acc_window_s", n.label_acc_window_s, 0.0, 1.0);
  CheckRange("node.collector_stats_period_s", n.collector_stats_period_s, 0.0, 86400.0);
}

void ValidatePlannerConfig(const PlannerConfig& c) {
  ValidateLimitsConfig(c.limits);
  ValidateMapConfig(c.map);
  ValidateSearchConfig(c.search);
  ValidateOptimizerConfig(c.optimizer);
  ValidateFsmConfig(c.fsm);
  ValidateNodeConfig(c.node);
  // Cross-field constraints.
  const auto& m = c.map;
  // Samples coarser than a voxel could step over a thin obstacle.
  CheckRange("search.collision_step_m", c.search.collision_step_m, 1e-3, m.resolution_m);
  CheckRange("optimizer.check_step_m", c.optimizer.check_step_m, 1e-3, m.resolution_m);
  if (!(m.esdf_max_distance_m > c.optimizer.safe_distance_m)) {
    Fail("map.esdf_max_distance_m", m.esdf_max_distance_m, "must exceed optimizer.safe_distance_m");
  }
  if (m.source == MapSource::kDepth) {
    // The local plan must stay where the map is updated and the ESDF exists (the optimiser needs it).
    const double window = std::min(m.local_update_range_m.x(), m.local_update_range_m.y());
    if (c.search.horizon_m > window - 0.5) {
      Fail("search.horizon_m", c.search.horizon_m, "must be <= min(map.local_update_range_m x, y) - 0.5 m");
    }
  }
}

}  // namespace fast_planner
