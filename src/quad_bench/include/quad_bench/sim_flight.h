// Closed-loop flights of the expert in-process, without ROS (library fast_planner_sim): quad_sim::Simulator +
// kr_tracker's SO(3) controller and B-spline tracker + the Replanner, exactly as the nodes connect them:
// odometry at the simulator's odometry rate (200 Hz) to the planner and the controller, a depth frame at the
// camera rate (30 Hz) to the planner, each new trajectory to the tracker at once. Single-threaded, so a run
// is fully deterministic (lockstep by construction) and as fast as the CPU allows. Used by the flight-quality
// and timing benchmark (scripts/bench/planner.sh), the clearance check (tools/expert_clearance_flights.cpp)
// and a closed-loop gtest.
#pragma once

#include <kr_tracker/config.h>
#include <quad_sim/sim_config.h>
#include <quad_sim/world.h>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "fast_planner/planner_config.h"
#include "fast_planner/planner_manager.h"

namespace quad_bench {

// The harness is written in the planner's vocabulary.
using namespace fast_planner;  // NOLINT(google-build-using-namespace)

struct FlightSetup {
  quad_sim::World world;
  Eigen::Vector3d start_m = Eigen::Vector3d::Zero();  // the vehicle hovers here, facing the goal, at t = 0
  Eigen::Vector3d goal_m = Eigen::Vector3d::Zero();
  double timeout_s = 60.0;  // sim time
};

// One control period of a flight: the vehicle's pose and its exact clearance (the simulator's
// ClearanceToObstacles: oriented vehicle box to the nearest world box) at that time.
struct FlownSample {
  double t_s = 0.0;
  Eigen::Vector3d p_world_body = Eigen::Vector3d::Zero();
  Eigen::Quaterniond q_world_body = Eigen::Quaterniond::Identity();
  double clearance_m = 0.0;
};

struct FlightStats {
  bool reached_goal = false;  // the simulator's episode ended at the goal
  bool collided = false;      // the simulator reported a collision
  std::string end_reason;     // the simulator's episode reason, or the planner's, or "timeout"
  double flight_time_s = 0.0;
  double path_length_m = 0.0;    // of the vehicle's odometry
  double straight_line_m = 0.0;  // |goal - start|
  double min_clearance_m = 0.0;  // min over the flight of the exact vehicle-box-to-boxes distance
  int plans = 0;                 // successful plans sent to the tracker
  int plan_failures = 0;         // plans that failed (each with a reason)
  int emergency_stops = 0;
  int starts_not_kept = 0;                // plans whose time re-allocation had to change the start state
  int tracker_rejections = 0;             // trajectories the tracker refused (should be 0)
  std::vector<PlanTimings> plan_timings;  // of the successful plans
  std::vector<double> map_update_ms;      // per depth frame: ray casting + ESDF (0 with esdf_on_demand)
  std::vector<double> map_integrate_ms;   // per depth frame: ray casting alone
  std::vector<double> map_esdf_ms;        // per depth frame: ESDF alone
  std::vector<bool> map_esdf_computed;    // per depth frame: whether the ESDF was recomputed after it
  std::vector<std::string> failure_reasons;
  std::vector<std::string> events;  // "t=1.234 s: <state machine transition or failure>"
  std::vector<FlownSample> flown;   // every control period (the odometry rate), in time order
};

// The simulator's world generator config with clear zones at start and goal.
// density_boxes_per_100m2 <= 0 keeps the configured count.
quad_sim::World MakeWorld(const quad_sim::SimConfig& sim_config, uint64_t seed,
                          double density_boxes_per_100m2, const Eigen::Vector3d& start_m,
                          const Eigen::Vector3d& goal_m);

// A start/goal pair distance_m apart, level at a height in [z_min, z_max], centred near the middle of the
// generator's bounds, in a direction drawn from the seed.
void RandomStartGoal(const quad_sim::SimConfig& sim_config, uint64_t seed, double distance_m, double z_min_m,
                     double z_max_m, Eigen::Vector3d* start_m, Eigen::Vector3d* goal_m);

// Flies one episode. The observer, if any, gets every successful plan (as the data collector would).
FlightStats FlyExpert(const PlannerConfig& planner_config, const quad_sim::SimConfig& sim_config,
                      const kr_tracker::TrackerConfig& tracker_config, const FlightSetup& setup,
                      std::shared_ptr<PlanObserver> observer = nullptr);

}  // namespace quad_bench
