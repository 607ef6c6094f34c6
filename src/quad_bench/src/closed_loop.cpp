#include "quad_bench/closed_loop.h"

#include <quad_core/vehicle_params.h>

#include <cmath>
#include <stdexcept>

#include "kr_tracker/reference_trajectories.h"

namespace quad_bench {

quad_sim::So3Command ToSim(const So3Command& c) {
  quad_sim::So3Command s;
  s.force_world_N = c.force_world_N;
  s.q_world_des = c.q_world_des;
  s.w_body_des_radps = c.w_body_des_radps;
  s.kR = c.kR;
  s.kOm = c.kOm;
  s.enable_motors = c.enable_motors;
  return s;
}

LoopRun RunClosedLoop(quad_sim::Simulator* sim, So3Controller* controller, Tracker* tracker,
                      double duration_s, const std::function<void(const LoopSample&)>& on_tick) {
  LoopRun run;
  const double t_end = sim->time_s() + duration_s;
  double t_prev = -1.0;
  while (sim->time_s() < t_end - 1e-9) {
    if (sim->OdometryDue()) {
      const double t = sim->time_s();
      const quad_core::VehicleState state = sim->state().Odometry(t);
      const PositionReference ref = tracker->Update(state);
      const ControlOutput out = controller->Compute(ref, state, t_prev < 0.0 ? 0.0 : t - t_prev);
      t_prev = t;
      if (out.status != ControlStatus::kOk) ++run.controller_fallbacks;
      if (!sim->SetSo3Command(ToSim(out.command)).ok()) ++run.rejected_commands;
      LoopSample s;
      s.t_s = t;
      s.p_world = state.p_world_body;
      s.p_ref_world = ref.p_world;
      s.v_world = state.v_world;
      s.v_ref_world = ref.v_world;
      s.yaw_rad = state.Yaw();
      s.yaw_ref_rad = ref.yaw_rad;
      run.samples.push_back(s);
      if (on_tick) on_tick(s);
    }
    sim->Step();
  }
  run.collided = sim->collision().collided;
  run.episode_reason = sim->episode().reason;
  return run;
}

quad_sim::SimConfig MakeSimConfig(const std::string& sim_yaml, const std::string& vehicle_yaml) {
  if (!sim_yaml.empty()) return quad_sim::LoadSimConfig(sim_yaml);
  quad_sim::SimConfig c;
  c.vehicle_file = vehicle_yaml;
  c.vehicle = quad_core::LoadVehicleParams(vehicle_yaml);
  c.Validate();
  return c;
}

void ResetEmptyWorld(quad_sim::Simulator* sim, const Eigen::Vector3d& p_start_world) {
  quad_sim::World world;
  world.bounds_min_m = Eigen::Vector3d(-50.0, -50.0, 0.0);
  world.bounds_max_m = Eigen::Vector3d(50.0, 50.0, 20.0);
  sim->Reset(world, p_start_world, 0.0, Eigen::Vector3d(1e4, 1e4, 1e4));
}

StepResult RunStepExperiment(const quad_sim::SimConfig& sim_config, const So3Gains& gains,
                             const StepExperiment& e) {
  quad_sim::Simulator sim(sim_config);
  ResetEmptyWorld(&sim, e.p0_world);
  So3Controller controller(gains, sim_config.vehicle.mass_kg, sim_config.vehicle.gravity_mps2,
                           sim_config.vehicle.MaxThrustN());
  const Eigen::Vector3d target = e.p0_world + e.step_m;
  FunctionTracker tracker(
      [&](double t) { return PositionReference::Hold(t < e.t_step_s ? e.p0_world : target, 0.0); });
  tracker.Activate(PositionReference::Hold(e.p0_world, 0.0), quad_core::VehicleState{});
  StepResult r;
  r.run = RunClosedLoop(&sim, &controller, &tracker, e.t_step_s + e.after_step_s);
  std::vector<double> t;
  std::array<std::vector<double>, 3> y;
  Eigen::Vector3d final_err = Eigen::Vector3d::Zero();
  int n_final = 0;
  for (const LoopSample& smp : r.run.samples) {
    t.push_back(smp.t_s);
    for (int a = 0; a < 3; ++a) y[a].push_back(smp.p_world[a]);
    if (smp.t_s >= r.run.samples.back().t_s - 1.0) {
      final_err += smp.p_world - target;
      ++n_final;
    }
  }
  r.sse_m = (final_err / n_final).norm();
  for (int a = 0; a < 3; ++a) {
    if (e.step_m[a] == 0.0) continue;
    r.axes[a] = AnalyzeStep(t, y[a], e.p0_world[a], target[a], e.t_step_s);
    r.worst.overshoot_pct = std::max(r.worst.overshoot_pct, r.axes[a].overshoot_pct);
    r.worst.rise_time_s = std::max(r.worst.rise_time_s, r.axes[a].rise_time_s);
    r.worst.settling_time_s = std::max(r.worst.settling_time_s, r.axes[a].settling_time_s);
  }
  return r;
}

Fig8Result RunFigureEightExperiment(const quad_sim::SimConfig& sim_config,
                                    const TrackerConfig& tracker_config) {
  quad_sim::Simulator sim(sim_config);
  const FigureEightSpec spec;
  ResetEmptyWorld(&sim, spec.center_world);
  So3Controller controller(tracker_config.gains, sim_config.vehicle.mass_kg, sim_config.vehicle.gravity_mps2,
                           sim_config.vehicle.MaxThrustN());
  BsplineTracker tracker(tracker_config.bspline);
  tracker.Activate(PositionReference::Hold(spec.center_world, 0.0), sim.state().Odometry(0.0));
  const double t_start = 1.0;
  const quad_core::NonUniformBspline fig8 = MakeFigureEight(spec);
  BsplineGoalSpec goal;
  goal.order = fig8.order();
  goal.start_time_s = t_start;
  goal.knots = fig8.knots();
  goal.pos_pts = fig8.ctrl_pts();
  const std::string why = tracker.AddGoal(1, goal, 0.0, sim.state().Odometry(0.0));
  if (!why.empty()) throw std::runtime_error("figure-eight goal rejected: " + why);
  Fig8Result r;
  r.duration_s = fig8.duration();
  r.length_m = fig8.Length();
  r.run = RunClosedLoop(&sim, &controller, &tracker, t_start + fig8.duration() + 2.0);
  std::vector<Eigen::Vector3d> p, p_ref;
  for (const LoopSample& smp : r.run.samples) {
    if (smp.t_s >= t_start && smp.t_s <= t_start + fig8.duration()) {
      p.push_back(smp.p_world);
      p_ref.push_back(smp.p_ref_world);
    }
  }
  r.error = ComputeTrackingError(p, p_ref);
  r.events = tracker.TakeEvents();
  return r;
}

}  // namespace quad_bench
