// The planner manager: owns the map and ESDF, runs front end -> fit -> optimisation -> time re-allocation ->
// final collision check for one plan, and tells an optional observer (the data collector of issue 6) about
// every successful plan with the exact inputs it used.
#pragma once

#include <quad_core/bspline.h>
#include <quad_core/vehicle_state.h>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <deque>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "fast_planner/bspline_optimizer.h"
#include "fast_planner/esdf.h"
#include "fast_planner/kinodynamic_astar.h"
#include "fast_planner/planner_config.h"
#include "fast_planner/voxel_map.h"

namespace fast_planner {

// The odometry is quad_core::VehicleState (nav_msgs/Odometry without ROS: twist in the world frame; its
// acceleration fields are not used). "" when every field is finite and the quaternion is not zero, else the
// reason (a check of its own, looser than VehicleState::AllFinite: any non-zero quaternion is normalised).
std::string ValidateOdometry(const quad_core::VehicleState& odom);

// The vehicle's acceleration at time t_s from an odometry history ordered by stamp (oldest first): the
// velocity difference between the newest odometry at or before t_s and the newest one at least window_s older
// than it, over their time difference (a backward difference, late by about window_s / 2), its norm capped at
// max_acc_mps2. Zero when window_s <= 0 or the history holds no such pair. The labeller's plans start from it
// (docs/fast_planner.md, "Labeller mode"): a plan started at zero acceleration while the vehicle accelerates
// drops the tracker's feed-forward, and replanned every frame such plans never let the vehicle speed up.
Eigen::Vector3d AccelerationFromOdometry(const std::deque<quad_core::VehicleState>& history, double t_s,
                                         double window_s, double max_acc_mps2);

enum class PlanStatus {
  kSuccess,
  kMapNotReady,            // no depth frame yet (depth source) or no map yet (global source)
  kInvalidStart,           // non-finite, outside the map or inside an obstacle
  kInvalidGoal,            // non-finite, outside the map, inside or too close to an obstacle
  kFrontEndFailed,         // no path, node budget, ...: the reason has the search status
  kTrajectoryInCollision,  // every optimised (and the fitted) trajectory hit the inflated map
};
const char* ToString(PlanStatus status);

struct PlanRequest {
  Eigen::Vector3d start_p = Eigen::Vector3d::Zero();
  Eigen::Vector3d start_v = Eigen::Vector3d::Zero();
  Eigen::Vector3d start_a = Eigen::Vector3d::Zero();
  Eigen::Vector3d goal = Eigen::Vector3d::Zero();
  double start_time_s = 0.0;  // when the start state is flown: the trajectory's t = 0
};

// Milliseconds of the planning thread's CPU time (not wall time, which on a shared machine also counts other
// processes' turns on the core).
struct PlanTimings {
  double frontend_ms = 0.0;
  double optimization_ms = 0.0;  // fit + NLopt (all attempts)
  double reallocation_ms = 0.0;  // time re-allocation (all attempts)
  double check_ms = 0.0;         // final collision checks (all attempts)
  double total_ms = 0.0;         // the whole Plan() call, without map_prep_ms
  double map_prep_ms = 0.0;      // ESDF computed for this plan before it (map.esdf_on_demand; 0 for global)
};

struct PlanResult {
  PlanStatus status = PlanStatus::kInvalidStart;
  std::string reason;  // "success" or why not, printable
  int64_t traj_id = 0;
  double start_time_s = 0.0;
  // The trajectory (degree 3, t = 0 at start_time_s); set exactly when status == kSuccess.
  std::optional<quad_core::NonUniformBspline> spline;
  bool reaches_goal = false;     // ends at the goal at rest (else at the search horizon or a safe stop)
  bool ends_at_rest = false;     // at the goal, at a safe stop short of it, or an emergency stop
  bool start_state_kept = true;  // time re-allocation kept the start state exactly (see time_reallocation.h)
  SearchStatus search_status = SearchStatus::kNoPath;
  PolyPath frontend_path;
  Eigen::MatrixXd initial_ctrl_pts;  // the fit before optimisation (for visualisation)
  int optimizer_evaluations = 0;
  int attempts = 0;  // optimisation attempts (1 + collision retries; + 1 for the fitted fallback)
  PlanTimings timings;
  bool ok() const { return status == PlanStatus::kSuccess; }
};

// What the data collector receives right after each successful plan: exactly what the plan used.
struct PlanRecord {
  std::shared_ptr<const DepthFrame> depth;  // the last depth frame received before the plan (null if none)
  std::optional<quad_core::VehicleState> odometry;  // the last odometry received before the plan
  Eigen::Vector3d goal = Eigen::Vector3d::Zero();
  PlanRequest request;
  const PlanResult* result = nullptr;  // valid during the callback only
};

class PlanObserver {
 public:
  virtual ~PlanObserver() = default;
  // Called on the planning thread right after a successful plan; must be quick (the collector queues it).
  virtual void OnPlan(const PlanRecord& record) = 0;
};

// Milliseconds of CPU time, as PlanTimings.
struct MapUpdateResult {
  MapUpdateStats stats;
  double integrate_ms = 0.0;
  double esdf_ms = 0.0;
  double total_ms = 0.0;
  bool esdf_computed = false;  // the ESDF was recomputed in this update (never with map.esdf_on_demand)
};

class PlannerManager {
 public:
  // Throws quad_core::ConfigError on an invalid configuration.
  explicit PlannerManager(const PlannerConfig& cfg);

  // Forgets the map, the last observations and the trajectory ids (a new episode). Global source: the global
  // map and its ESDF are kept as a cache, unused (MapReady() is false) until SetGlobalMap() is called again.
  void Reset();

  // Depth source: integrates the frame and recomputes the ESDF in the local window around the camera (with
  // map.esdf_on_demand: marks it to be recomputed by the next Plan()). Global source: only remembers the
  // frame (for the observer). Throws std::invalid_argument on a malformed frame.
  MapUpdateResult UpdateDepth(std::shared_ptr<const DepthFrame> frame);
  // Remembers the odometry (for the observer). Throws std::invalid_argument on non-finite odometry.
  void UpdateOdometry(const quad_core::VehicleState& odom);
  // Global source: marks the simulator's occupied voxels (world points) and computes the ESDF once, over the
  // box of the obstacles widened by map.esdf_max_distance_m in x and y (beyond it the field only depends on
  // the ground and ceiling, so the Esdf's clamping gives the whole map's values) and the map's full height.
  // Plans never recompute it (issue 32). Cost: a full build when the points differ from the last call's (for
  // config/sim.yaml's 40 x 40 m world at 0.1 m: 0.9-1.1 s of CPU, of which 0.6-0.75 s the ESDF, 43 MB kept;
  // docs/notebook/2026-12_expert_maps_issue32.md); the same points again (ExpertSession::StartEpisode after
  // every reset) cost one comparison of the points (about 2 ms). Returns the CPU milliseconds spent.
  double SetGlobalMap(const std::vector<Eigen::Vector3d>& occupied_points_world);

  // Whether Plan() has a map to plan on: a depth frame (depth source) or the global map (global source).
  bool MapReady() const;

  // Why this goal cannot be planned to ("" if it can): non-finite, outside the map, in or near an obstacle.
  std::string CheckGoal(const Eigen::Vector3d& goal) const;

  PlanResult Plan(const PlanRequest& request);

  // A braking trajectory from (p, v, a) to rest along the current direction of motion at the acceleration
  // limit (the emergency stop). Never fails; the result starts at start_time_s.
  PlanResult PlanStop(const Eigen::Vector3d& p, const Eigen::Vector3d& v, const Eigen::Vector3d& a,
                      double start_time_s);

  // The first time t in [t_from, tmax] (spline time) at which the trajectory enters the inflated map, sampled
  // every optimizer.check_step_m of arc length; samples within the escape radius of escape_center may be
  // inflated but not occupied (leaving an inflated start). nullopt if it stays free.
  std::optional<double> FirstCollision(const quad_core::NonUniformBspline& spline, double t_from,
                                       const Eigen::Vector3d& escape_center) const;

  void SetObserver(std::shared_ptr<PlanObserver> observer) { observer_ = std::move(observer); }

  const PlannerConfig& config() const { return cfg_; }
  const VoxelMap& map() const { return map_; }
  // With map.esdf_on_demand the ESDF is the one of the last Plan(), not necessarily of the latest frame.
  const Esdf& esdf() const { return esdf_; }
  // How many times this manager computed its ESDF (every source; for tests and diagnostics).
  int64_t esdf_updates() const { return esdf_updates_; }
  std::shared_ptr<const DepthFrame> last_depth() const { return last_depth_; }
  const std::optional<quad_core::VehicleState>& last_odometry() const { return last_odom_; }

 private:
  void UpdateEsdf(const Eigen::Vector3i& min_idx, const Eigen::Vector3i& max_idx);
  double EscapeRadius(const Eigen::Vector3d& start) const;
  // Plan() once the ESDF is up to date.
  PlanResult PlanOnPreparedMap(const PlanRequest& request);
  PlanResult Fail(PlanStatus status, const std::string& reason, const PlanRequest& request,
                  double t0_ms) const;

  PlannerConfig cfg_;
  VoxelMap map_;
  Esdf esdf_;
  KinodynamicAstar search_;
  BsplineOptimizer optimizer_;
  bool global_map_set_ = false;
  // Global source: the points the map and ESDF were last built from (kept across Reset()).
  std::optional<std::vector<Eigen::Vector3d>> global_points_;
  int64_t esdf_updates_ = 0;
  // esdf_on_demand: the window of the latest frame whose ESDF is not computed yet.
  std::optional<std::pair<Eigen::Vector3i, Eigen::Vector3i>> esdf_pending_;
  std::shared_ptr<const DepthFrame> last_depth_;
  std::optional<quad_core::VehicleState> last_odom_;
  std::shared_ptr<PlanObserver> observer_;
  int64_t next_traj_id_ = 1;
};

}  // namespace fast_planner
