// The one typed configuration of the expert planner (config/planner.yaml), loaded strictly.
//
// Defaults after Zhou et al., RA-L 2019 ("Robust and Efficient Quadrotor Trajectory Generation for Fast
// Autonomous Flight"): max velocity 3.0 m/s, max acceleration 2.0 m/s^2, 0.1 m map resolution, 0.5 m
// control-point spacing. Every value is range-checked when loaded, and cross-field constraints (e.g. the
// search horizon must fit in the local map window) are checked too, so a bad parameter is a ConfigError
// naming the key instead of a crash later (one of Fast-Planner's known faults).
#pragma once

#include <Eigen/Core>

#include <string>

namespace quad_core {
class StrictYaml;
}

namespace fast_planner {

enum class MapSource { kDepth, kGlobal };
const char* ToString(MapSource source);

// Kinodynamic limits shared by the front end, the optimiser and time re-allocation.
struct LimitsConfig {
  double max_vel_mps = 3.0;
  double max_acc_mps2 = 2.0;
};

// Log-odds occupancy from depth frames (ray casting with hit/miss/clamp).
struct DepthIntegrationConfig {
  double min_ray_length_m = 0.1;  // returns closer than this are ignored
  double max_ray_length_m = 5.0;  // longer returns (and no-return pixels) clear free space up to this range
  int skip_pixel = 3;             // use every skip_pixel-th pixel in each image axis
  double prob_hit = 0.65;
  double prob_miss = 0.35;
  double prob_min = 0.12;  // log-odds clamp (so that a voxel can change its mind quickly)
  double prob_max = 0.97;
  double prob_occupied = 0.80;  // a voxel is occupied when its probability exceeds this
};

struct MapConfig {
  MapSource source = MapSource::kDepth;
  double resolution_m = 0.1;
  Eigen::Vector3d origin_m{-25.0, -25.0, -0.5};  // lower corner of the map box in the world frame
  Eigen::Vector3d size_m{50.0, 50.0, 6.5};
  double ground_z_m = 0.0;   // everything at or below is an obstacle (Fast-Planner planned below the ground)
  double ceiling_z_m = 5.5;  // everything at or above is an obstacle
  // Half extents of the window around the vehicle in which depth is integrated and the ESDF is computed.
  Eigen::Vector3d local_update_range_m{5.5, 5.5, 2.0};
  double inflation_m =
      0.3;  // occupied voxels are inflated by this radius for the front end's collision checks
  double esdf_max_distance_m = 2.0;  // ESDF distances are exact up to this and clamped beyond
  // Depth source: compute the ESDF of the latest frame's window only when a plan needs it (the optimiser is
  // its only user), not after every frame. The plans are identical either way; it saves most of the per-frame
  // mapping cost when frames arrive faster than plans are made.
  bool esdf_on_demand = true;
  DepthIntegrationConfig depth;
};

// Kinodynamic A* over double-integrator motion primitives.
struct SearchConfig {
  double primitive_duration_s = 0.6;  // tau of every motion primitive
  int acc_levels_per_axis = 5;        // odd; accelerations -a_max .. a_max per axis
  double time_weight = 10.0;          // rho in J = integral(|u|^2) + rho T
  double heuristic_weight = 5.0;      // lambda_h in f = g + lambda_h h (weighted A*)
  double resolution_m = 0.1;          // cell size of the position grid that prunes states
  double horizon_m = 5.0;             // the search stops at this distance from the start (local planning)
  int max_nodes = 20000;              // expansion budget: "no path" beyond it
  double collision_step_m = 0.1;      // spacing of the collision samples along primitives and shots
  double shot_radius_m = 5.0;         // analytic expansions are tried when the goal is closer than this
};

// B-spline optimisation (NLopt L-BFGS) and time re-allocation.
struct OptimizerConfig {
  double ctrl_pt_dist_m = 0.5;  // knot span = ctrl_pt_dist / max_vel
  double w_smooth = 1.0;
  double w_distance = 50.0;
  double w_feasibility = 1.0;
  double w_endpoint = 10.0;
  double safe_distance_m = 0.6;  // the ESDF clearance below which control points are penalised
  int max_iterations = 120;
  int realloc_max_iterations = 20;
  double realloc_margin = 1.02;         // knot spans are stretched to limit / margin
  double check_step_m = 0.05;           // spacing of the final collision check along the B-spline
  double collision_retry_factor = 4.0;  // the distance weight is multiplied by this when a result collides
};

// The replanning state machine and its event thresholds.
struct FsmConfig {
  double replan_distance_m = 1.0;    // replan after travelling this far along the current trajectory
  double goal_tolerance_m = 0.3;     // the goal is reached within this distance once the trajectory ended
  double stopped_speed_mps = 0.15;   // after an emergency stop the vehicle counts as stopped below this speed
  int max_consecutive_failures = 6;  // plan failures in a row before the goal is abandoned
  // Keep replanning every replan_distance_m on a trajectory that already reaches the goal, while the vehicle
  // is farther than replan_distance_m from it. false: the trajectory to the goal is flown without replans
  // (Fast-Planner), so a recorded dataset has no plans for the final approach (the last ~9 m).
  bool replan_final_approach = false;
};

// Settings of the ROS node (fast_planner_node) alone; the in-process harnesses do not use them.
struct NodeConfig {
  // The simulator's odometry period: a depth frame is processed once the odometry of its control period has
  // arrived (odometry_history.h).
  double odom_period_s = 0.005;
  // Wall time the node waits for the tracker to take a trajectory before acknowledging the frame (0: no
  // wait); in lockstep the trajectory then takes effect at the same control period in every run.
  double tracker_accept_timeout_s = 1.0;
  // Labeller mode: labels start at the odometry's acceleration over this window (0: zero acceleration).
  double label_acc_window_s = 0.05;
  // The data collector's statistics are logged this often (wall time; 0: only at exit).
  double collector_stats_period_s = 30.0;
};

struct PlannerConfig {
  LimitsConfig limits;
  MapConfig map;
  SearchConfig search;
  OptimizerConfig optimizer;
  FsmConfig fsm;
  NodeConfig node;
};

// Loads config/planner.yaml. Throws quad_core::ConfigError naming the file, the key and the bad value.
PlannerConfig LoadPlannerConfig(const std::string& yaml_path);
// Reads the planner keys from an open strict YAML document and checks that no key is left unread.
PlannerConfig ReadPlannerConfig(quad_core::StrictYaml& y);
// Throws quad_core::ConfigError (source "PlannerConfig") on a value out of range or inconsistent with
// another; used after loading and by code that builds a PlannerConfig by hand (tests, benchmarks).
void ValidatePlannerConfig(const PlannerConfig& cfg);
// The sections alone (used by the constructors of the classes that take them); no cross-section checks.
void ValidateLimitsConfig(const LimitsConfig& cfg);
void ValidateMapConfig(const MapConfig& cfg);
void ValidateSearchConfig(const SearchConfig& cfg);
void ValidateOptimizerConfig(const OptimizerConfig& cfg);
void ValidateFsmConfig(const FsmConfig& cfg);
void ValidateNodeConfig(const NodeConfig& cfg);

}  // namespace fast_planner
