#include "quad_bench/sim_flight.h"

#include <kr_tracker/bspline_tracker.h>
#include <kr_tracker/so3_controller.h>
#include <quad_bench/closed_loop.h>
#include <quad_sim/simulator.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>

#include "fast_planner/replanner.h"

namespace quad_bench {

namespace {

kr_tracker::BsplineGoalSpec ToGoalSpec(const PlanResult& plan) {
  kr_tracker::BsplineGoalSpec spec;
  spec.order = plan.spline->order();
  spec.traj_id = plan.traj_id;
  spec.start_time_s = plan.start_time_s;
  spec.knots = plan.spline->knots();
  spec.pos_pts = plan.spline->ctrl_pts();
  return spec;
}

}  // namespace

quad_sim::World MakeWorld(const quad_sim::SimConfig& sim_config, uint64_t seed,
                          double density_boxes_per_100m2, const Eigen::Vector3d& start_m,
                          const Eigen::Vector3d& goal_m) {
  quad_sim::WorldGenConfig gen = sim_config.world_gen;
  if (density_boxes_per_100m2 > 0.0) gen.density_boxes_per_100m2 = density_boxes_per_100m2;
  gen.AddClearZone(start_m);
  gen.AddClearZone(goal_m);
  return quad_sim::GenerateWorld(gen, seed);
}

void RandomStartGoal(const quad_sim::SimConfig& sim_config, uint64_t seed, double distance_m, double z_min_m,
                     double z_max_m, Eigen::Vector3d* start_m, Eigen::Vector3d* goal_m) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  const auto& g = sim_config.world_gen;
  const Eigen::Vector3d mid = 0.5 * (g.bounds_min_m + g.bounds_max_m);
  const double angle = 2.0 * M_PI * unit(rng);
  const Eigen::Vector3d dir(std::cos(angle), std::sin(angle), 0.0);
  // Centre jitter small enough that both ends stay 2 m inside the bounds.
  const double half_x =
      0.5 * (g.bounds_max_m.x() - g.bounds_min_m.x()) - 2.0 - 0.5 * distance_m * std::abs(dir.x());
  const double half_y =
      0.5 * (g.bounds_max_m.y() - g.bounds_min_m.y()) - 2.0 - 0.5 * distance_m * std::abs(dir.y());
  const Eigen::Vector3d centre = mid + Eigen::Vector3d(std::max(half_x, 0.0) * (2.0 * unit(rng) - 1.0),
                                                       std::max(half_y, 0.0) * (2.0 * unit(rng) - 1.0), 0.0);
  *start_m = centre - 0.5 * distance_m * dir;
  *goal_m = centre + 0.5 * distance_m * dir;
  start_m->z() = z_min_m + (z_max_m - z_min_m) * unit(rng);
  goal_m->z() = z_min_m + (z_max_m - z_min_m) * unit(rng);
}

FlightStats FlyExpert(const PlannerConfig& planner_config, const quad_sim::SimConfig& sim_config,
                      const kr_tracker::TrackerConfig& tracker_config, const FlightSetup& setup,
                      std::shared_ptr<PlanObserver> observer) {
  FlightStats stats;
  stats.straight_line_m = (setup.goal_m - setup.start_m).norm();
  stats.min_clearance_m = std::numeric_limits<double>::infinity();

  quad_sim::Simulator sim(sim_config);
  const Eigen::Vector3d to_goal = setup.goal_m - setup.start_m;
  sim.Reset(setup.world, setup.start_m, std::atan2(to_goal.y(), to_goal.x()), setup.goal_m);

  const auto& vehicle = sim_config.vehicle;
  kr_tracker::So3Controller controller(tracker_config.gains, vehicle.mass_kg, vehicle.gravity_mps2,
                                       vehicle.MaxThrustN());
  kr_tracker::BsplineTracker tracker(tracker_config.bspline);
  const quad_core::VehicleState s0 = sim.state().Odometry(sim.time_s());
  tracker.Activate(kr_tracker::PositionReference::Hold(s0.p_world_body, s0.Yaw()), s0);

  Replanner replanner(planner_config);
  if (observer) replanner.manager().SetObserver(observer);
  if (planner_config.map.source == MapSource::kGlobal) {
    const auto centres = sim.ComputeVoxelMap().OccupiedCenters();
    std::vector<Eigen::Vector3d> points;
    points.reserve(centres.size());
    for (const auto& c : centres) points.push_back(c.cast<double>());
    replanner.manager().SetGlobalMap(points);
  }

  auto handle = [&](const ReplannerOutput& out, double now, const quad_core::VehicleState& state) {
    const std::string at = "t=" + std::to_string(now) + " s: ";
    for (const auto& t : out.transitions) stats.events.push_back(at + t);
    for (const auto& f : out.failed_plans) {
      ++stats.plan_failures;
      stats.failure_reasons.push_back(f.reason);
      stats.events.push_back(at + f.reason);
    }
    if (out.trajectory) {
      const PlanResult& plan = *out.trajectory;
      if (plan.reason == "emergency stop") {
        ++stats.emergency_stops;
      } else {
        ++stats.plans;
        stats.plan_timings.push_back(plan.timings);
        if (!plan.start_state_kept) ++stats.starts_not_kept;
      }
      const std::string why =
          tracker.AddGoal(static_cast<uint64_t>(plan.traj_id), ToGoalSpec(plan), now, state);
      if (!why.empty()) {
        ++stats.tracker_rejections;
        stats.failure_reasons.push_back("tracker rejected trajectory " + std::to_string(plan.traj_id) + ": " +
                                        why);
      }
    }
    if (out.abandoned) stats.end_reason = "planner gave up: " + *out.abandoned;
  };

  bool goal_sent = false;
  double t_prev_control = -1.0;
  Eigen::Vector3d p_prev = sim.state().p_world_body;
  while (sim.episode().active && sim.time_s() < setup.timeout_s && stats.end_reason.empty()) {
    const double now = sim.time_s();
    const bool odom_due = sim.OdometryDue();
    const quad_core::VehicleState state = sim.state().Odometry(now);
    if (odom_due) {
      handle(replanner.OnOdometry(state), now, state);
      if (!goal_sent) {
        ReplannerOutput out;
        const std::string why = replanner.SetGoal(setup.goal_m, now, &out);
        if (!why.empty()) stats.end_reason = "goal rejected: " + why;
        handle(out, now, state);
        goal_sent = true;
      }
    }
    if (sim.DepthDue()) {
      auto frame = std::make_shared<DepthFrame>();
      quad_core::DepthImage image = sim.RenderDepth();
      const auto& k = sim.camera_intrinsics();
      frame->stamp_s = now;
      frame->intrinsics = quad_core::CameraIntrinsics{k.width, k.height, k.fx, k.fy, k.cx, k.cy};
      frame->image = std::move(image);
      sim.CameraPoseWorld(&frame->p_world_camera, &frame->q_world_camera);
      MapUpdateResult mu;
      handle(replanner.OnDepth(frame, &mu), now, state);
      if (planner_config.map.source == MapSource::kDepth) {
        stats.map_update_ms.push_back(mu.total_ms);
        stats.map_integrate_ms.push_back(mu.integrate_ms);
        stats.map_esdf_ms.push_back(mu.esdf_ms);
        stats.map_esdf_computed.push_back(mu.esdf_computed);
      }
    }
    if (odom_due) {
      const kr_tracker::PositionReference ref = tracker.Update(state);
      const kr_tracker::ControlOutput u =
          controller.Compute(ref, state, t_prev_control < 0.0 ? 0.0 : now - t_prev_control);
      t_prev_control = now;
      sim.SetSo3Command(quad_bench::ToSim(u.command));
      const double clearance_m = sim.ClearanceToObstacles();
      stats.min_clearance_m = std::min(stats.min_clearance_m, clearance_m);
      stats.flown.push_back({now, sim.state().p_world_body, sim.state().q_world_body, clearance_m});
      stats.path_length_m += (sim.state().p_world_body - p_prev).norm();
      p_prev = sim.state().p_world_body;
    }
    sim.Step();
  }
  stats.flight_time_s = sim.time_s();
  stats.reached_goal = sim.episode().reached_goal;
  stats.collided = sim.collision().collided;
  if (!sim.episode().active) {
    stats.end_reason = sim.episode().reason;
  } else if (stats.end_reason.empty()) {
    stats.end_reason = "timeout";
  }
  return stats;
}

}  // namespace quad_bench
