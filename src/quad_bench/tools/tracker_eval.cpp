// tracker_eval: closed-loop checks of the tracker + SO(3) controller against the simulator core in-process,
// and the Ziegler-Nichols tuning tool. Results go to stdout as `result <name> <value> <unit>` lines (read by
// scripts/bench/tracker.sh), progress and tables to stderr.
//
//   tracker_eval step   [--csv FILE]   hover at p0, step of (3, 3, 3) m; overshoot, rise, settling, sse
//   tracker_eval fig8   [--csv FILE]   figure-eight B-spline at 2 m/s peak through the B-spline tracker
//   tracker_eval update-time           mean time of one tracker update + controller step (microseconds)
//   tracker_eval zn     [--axis x|y|z|all] [--csv FILE]   Ziegler-Nichols ultimate gain/period and derived
//   gains
// Common options: --tracker-config FILE (config/tracker.yaml), --vehicle-config FILE (config/vehicle.yaml),
// --sim-config FILE (optional config/sim.yaml; default: quad_sim defaults with the vehicle file),
// --kx X,Y,Z --kv X,Y,Z (override the configured gains).
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "kr_tracker/bspline_tracker.h"
#include "kr_tracker/config.h"
#include "kr_tracker/reference_trajectories.h"
#include "kr_tracker/response_metrics.h"
#include "kr_tracker/ziegler_nichols.h"
#include "quad_bench/closed_loop.h"

namespace quad_bench {
namespace {

struct Options {
  std::string command;
  std::string tracker_config = "config/tracker.yaml";
  std::string vehicle_config = "config/vehicle.yaml";
  std::string sim_config;
  std::string csv;
  std::string axis = "all";
  std::optional<Eigen::Vector3d> kx, kv;
};

Eigen::Vector3d ParseVec3(const std::string& s, const std::string& flag) {
  std::stringstream ss(s);
  std::vector<double> v;
  std::string item;
  while (std::getline(ss, item, ',')) v.push_back(std::stod(item));
  if (v.size() != 3)
    throw std::invalid_argument(flag + " needs three comma-separated numbers, got '" + s + "'");
  return Eigen::Vector3d(v[0], v[1], v[2]);
}

constexpr const char* kUsage =
    "usage: tracker_eval step|fig8|update-time|zn [options]\n"
    "  step          the thesis's step test (hover, then a 3 m step on each axis), metrics per axis\n"
    "  fig8          the figure eight through the B-spline tracker, tracking error\n"
    "  update-time   the controller + tracker update time\n"
    "  zn            Ziegler-Nichols tuning experiments (docs/kr_tracker.md)\n"
    "options:\n"
    "  --tracker-config F   tracker gains and limits (default: config/tracker.yaml)\n"
    "  --vehicle-config F   vehicle parameters (default: config/vehicle.yaml)\n"
    "  --sim-config F       simulator config (default: none: quad_sim's defaults with the vehicle file)\n"
    "  --csv F              write every odometry tick of the run as CSV (default: none)\n"
    "  --axis x|y|z|all     zn: the axes to tune (default: all)\n"
    "  --kx X,Y,Z           override the configured position gains (default: the tracker config's)\n"
    "  --kv X,Y,Z           override the configured velocity gains (default: the tracker config's)\n";

Options Parse(int argc, char** argv) {
  if (argc < 2) throw std::invalid_argument(kUsage);
  Options o;
  o.command = argv[1];
  for (int i = 2; i < argc; ++i) {
    const std::string a = argv[i];
    if (i + 1 >= argc) throw std::invalid_argument("option " + a + " needs a value");
    const std::string v = argv[++i];
    if (a == "--tracker-config") {
      o.tracker_config = v;
    } else if (a == "--vehicle-config") {
      o.vehicle_config = v;
    } else if (a == "--sim-config") {
      o.sim_config = v;
    } else if (a == "--csv") {
      o.csv = v;
    } else if (a == "--axis") {
      o.axis = v;
    } else if (a == "--kx") {
      o.kx = ParseVec3(v, a);
    } else if (a == "--kv") {
      o.kv = ParseVec3(v, a);
    } else {
      throw std::invalid_argument("unknown option " + a);
    }
  }
  return o;
}

void Result(const std::string& name, double value, const std::string& unit) {
  std::printf("result %s %.6g %s\n", name.c_str(), value, unit.c_str());
}

struct Setup {
  TrackerConfig tracker;
  quad_sim::SimConfig sim;
};

Setup Load(const Options& o) {
  Setup s{LoadTrackerConfig(o.tracker_config), MakeSimConfig(o.sim_config, o.vehicle_config)};
  if (o.kx) s.tracker.gains.kx = *o.kx;
  if (o.kv) s.tracker.gains.kv = *o.kv;
  return s;
}

void WriteCsv(const std::string& path, const LoopRun& run) {
  std::ofstream f(path);
  if (!f) throw std::runtime_error("cannot write " + path);
  f << "t_s,x_m,y_m,z_m,x_ref_m,y_ref_m,z_ref_m,vx_mps,vy_mps,vz_mps,yaw_rad,yaw_ref_rad\n";
  f.precision(9);
  for (const LoopSample& s : run.samples) {
    f << s.t_s << ',' << s.p_world.x() << ',' << s.p_world.y() << ',' << s.p_world.z() << ','
      << s.p_ref_world.x() << ',' << s.p_ref_world.y() << ',' << s.p_ref_world.z() << ',' << s.v_world.x()
      << ',' << s.v_world.y() << ',' << s.v_world.z() << ',' << s.yaw_rad << ',' << s.yaw_ref_rad << '\n';
  }
}

int CmdStep(const Options& o) {
  const Setup s = Load(o);
  const StepResult r = RunStepExperiment(s.sim, s.tracker.gains);
  const char* names[3] = {"x", "y", "z"};
  for (int a = 0; a < 3; ++a) {
    std::fprintf(stderr, "step %s: overshoot %.2f %%, rise %.3f s, settling (2 %%) %.3f s, sse %.4f m\n",
                 names[a], r.axes[a].overshoot_pct, r.axes[a].rise_time_s, r.axes[a].settling_time_s,
                 r.axes[a].steady_state_error);
  }
  if (!o.csv.empty()) WriteCsv(o.csv, r.run);
  Result("step_overshoot_pct", r.worst.overshoot_pct, "%");
  Result("step_rise_s", r.worst.rise_time_s, "s");
  Result("step_settle_s", r.worst.settling_time_s, "s");
  Result("step_sse_m", r.sse_m, "m");
  Result("step_rejected_commands", r.run.rejected_commands + r.run.controller_fallbacks, "count");
  return 0;
}

// ---------------------------------------------------------------------------------------------------------------
// Figure eight through the B-spline tracker.

int CmdFig8(const Options& o) {
  const Setup s = Load(o);
  const Fig8Result r = RunFigureEightExperiment(s.sim, s.tracker);
  std::fprintf(stderr, "fig8: duration %.2f s, length %.2f m, %d samples, episode: %s\n", r.duration_s,
               r.length_m, r.error.samples, r.run.episode_reason.c_str());
  for (const GoalEvent& ev : r.events) {
    std::fprintf(stderr, "fig8: goal %s after %.2f s, %.2f m flown\n", ToString(ev.kind), ev.total_time_s,
                 ev.distance_travelled_m);
  }
  if (!o.csv.empty()) WriteCsv(o.csv, r.run);
  Result("fig8_rms_m", r.error.rms_m, "m");
  Result("fig8_max_m", r.error.max_m, "m");
  Result("fig8_rejected_commands", r.run.rejected_commands + r.run.controller_fallbacks, "count");
  return 0;
}

// ---------------------------------------------------------------------------------------------------------------
// Controller update time: B-spline tracker update + SO(3) controller step, on figure-eight states.

int CmdUpdateTime(const Options& o) {
  const Setup s = Load(o);
  So3Controller controller(s.tracker.gains, s.sim.vehicle.mass_kg, s.sim.vehicle.gravity_mps2,
                           s.sim.vehicle.MaxThrustN());
  FigureEightSpec spec;
  const quad_core::NonUniformBspline fig8 = MakeFigureEight(spec);
  BsplineGoalSpec goal;
  goal.order = fig8.order();
  goal.knots = fig8.knots();
  goal.pos_pts = fig8.ctrl_pts();
  const int n = 20000;
  std::vector<double> batch_us;
  double sink = 0.0;
  for (int batch = 0; batch < 7; ++batch) {
    BsplineTracker tracker(s.tracker.bspline);
    quad_core::VehicleState state;
    state.p_world_body = spec.center_world;
    tracker.Activate(PositionReference::Hold(spec.center_world, 0.0), state);
    if (!tracker.AddGoal(1, goal, 0.0, state).empty()) throw std::runtime_error("goal rejected");
    const double dt = fig8.duration() / n;
    const auto t0 = std::chrono::steady_clock::now();
    for (int i = 0; i < n; ++i) {
      state.t_s = i * dt;
      // A state slightly off the reference, so every term of the law is exercised.
      state.p_world_body = fig8.Evaluate(state.t_s) + Eigen::Vector3d(0.01, -0.02, 0.005);
      const PositionReference ref = tracker.Update(state);
      sink += controller.Compute(ref, state, dt).command.force_world_N.z();
    }
    const auto t1 = std::chrono::steady_clock::now();
    batch_us.push_back(std::chrono::duration<double, std::micro>(t1 - t0).count() / n);
  }
  std::sort(batch_us.begin(), batch_us.end());
  // The state evaluation above (one spline evaluation) is included: an upper bound of the node's work per
  // tick.
  std::fprintf(stderr, "update time: median of 7 batches of %d: %.3f us (min %.3f, max %.3f) [%g]\n", n,
               batch_us[3], batch_us.front(), batch_us.back(), sink > 0 ? 1.0 : 0.0);
  Result("update_us", batch_us[3], "us");
  return 0;
}

// ---------------------------------------------------------------------------------------------------------------
// Ziegler-Nichols on the simulator.
//
// A P-only loop on position around a double integrator has no finite ultimate gain (its phase is -180 deg at
// every frequency before any lag is added, so any gain with the attitude lag is unstable). The tool therefore
// applies Ziegler-Nichols to the axis's velocity loop (kx = 0, ki = 0, P gain kv = K), excited by a short
// velocity reference pulse, and maps the rules onto the position controller: the integral of the velocity
// error is the position error, so a PI on velocity is kv = Kp, kx = Kp / Ti (a D term would be acceleration
// feedback, which the SO(3) law does not have; it is reported and dropped).

UltimateGainResult ZnAxis(const Setup& s, int axis, std::ofstream* csv) {
  const Eigen::Vector3d p0(0.0, 0.0, 3.0);
  const double t_pulse = 0.5;
  const double pulse_s = 0.1;
  // The pulse commands 0.5 m/s^2 whatever the gain, so the loop starts in its linear range (tilt and thrust
  // limits far away) and the first extrema show the linear growth or decay.
  const double pulse_accel_mps2 = 0.5;
  const GainExperiment experiment = [&](double k, std::vector<double>* t, std::vector<double>* y) {
    const double pulse_mps = pulse_accel_mps2 / k;
    quad_sim::Simulator sim(s.sim);
    ResetEmptyWorld(&sim, p0);
    So3Gains g = s.tracker.gains;
    g.kx[axis] = 0.0;
    g.kv[axis] = k;
    g.ki.setZero();
    So3Controller controller(g, s.sim.vehicle.mass_kg, s.sim.vehicle.gravity_mps2,
                             s.sim.vehicle.MaxThrustN());
    FunctionTracker tracker([&](double tt) {
      PositionReference r = PositionReference::Hold(p0, 0.0);
      if (tt >= t_pulse && tt < t_pulse + pulse_s) r.v_world[axis] = pulse_mps;
      return r;
    });
    tracker.Activate(PositionReference::Hold(p0, 0.0), quad_core::VehicleState{});
    const LoopRun run = RunClosedLoop(&sim, &controller, &tracker, 5.0);
    t->clear();
    y->clear();
    for (const LoopSample& smp : run.samples) {
      t->push_back(smp.t_s);
      y->push_back(smp.v_world[axis]);
      if (csv) *csv << axis << ',' << k << ',' << smp.t_s << ',' << smp.v_world[axis] << '\n';
    }
  };
  UltimateGainSearch search;
  search.k_min = 0.5;
  search.k_max = 2000.0;
  search.relative_tol = 0.01;
  search.t_from_s = t_pulse + pulse_s + 0.05;
  search.noise_floor = 1e-9;
  return FindUltimateGain(experiment, search);
}

int CmdZn(const Options& o) {
  const Setup s = Load(o);
  std::vector<int> axes;
  if (o.axis == "all") {
    axes = {0, 1, 2};
  } else if (o.axis == "x" || o.axis == "y" || o.axis == "z") {
    axes = {o.axis[0] - 'x'};
  } else {
    throw std::invalid_argument("--axis must be x, y, z or all");
  }
  std::ofstream csv;
  if (!o.csv.empty()) {
    csv.open(o.csv);
    csv << "axis,gain,t_s,v_mps\n";
  }
  const char* names = "xyz";
  Eigen::Vector3d ku = Eigen::Vector3d::Constant(NAN), tu = Eigen::Vector3d::Constant(NAN);
  for (int a : axes) {
    const UltimateGainResult r = ZnAxis(s, a, o.csv.empty() ? nullptr : &csv);
    std::fprintf(stderr, "zn %c: %s after %d experiments: Ku = %.3f 1/s, Tu = %.4f s\n", names[a],
                 ToString(r.status), r.experiments, r.ku, r.tu_s);
    for (const auto& tr : r.trials) {
      std::fprintf(stderr, "   K = %9.3f  growth/half-period %.3f  period %.4f s\n", tr.gain, tr.growth_ratio,
                   tr.period_s);
    }
    if (r.status != UltimateGainStatus::kFound) continue;
    ku[a] = r.ku;
    tu[a] = r.tu_s;
    Result(std::string("zn_ku_") + names[a], r.ku, "1/s");
    Result(std::string("zn_tu_") + names[a], r.tu_s, "s");
    std::fprintf(stderr, "   %-20s %9s %9s %9s -> %9s %9s\n", "rule", "Kp", "Ti", "Td", "kv", "kx");
    for (const PidGains& g : ZieglerNicholsRules(r.ku, r.tu_s)) {
      const double kx = std::isinf(g.ti_s) ? 0.0 : g.kp / g.ti_s;
      std::fprintf(stderr, "   %-20s %9.3f %9.4f %9.4f -> %9.3f %9.3f%s\n", g.rule.c_str(), g.kp, g.ti_s,
                   g.td_s, g.kp, kx, g.td_s > 0 ? "  (Td dropped)" : "");
    }
  }
  // Closed-loop checks with the gains of the PI and "no overshoot" rules, applied to every tuned axis, and to
  // the horizontal axes only (configured z gains: the vertical ultimate gain reflects only the motor lag and
  // the control period, and its rules give gains no position loop can use).
  for (const bool horizontal_only : {false, true}) {
    for (const std::string rule : {"PI", "PID no overshoot"}) {
      Setup tuned = s;
      for (int a : axes) {
        if (!std::isfinite(ku[a]) || (horizontal_only && a == 2)) continue;
        for (const PidGains& g : ZieglerNicholsRules(ku[a], tu[a])) {
          if (g.rule != rule) continue;
          tuned.tracker.gains.kv[a] = g.kp;
          tuned.tracker.gains.kx[a] = g.kp / g.ti_s;
        }
      }
      const StepResult st = RunStepExperiment(tuned.sim, tuned.tracker.gains);
      const Fig8Result f8 = RunFigureEightExperiment(tuned.sim, tuned.tracker);
      const So3Gains& g = tuned.tracker.gains;
      std::fprintf(stderr,
                   "zn '%s'%s: kx [%.2f %.2f %.2f] kv [%.2f %.2f %.2f]: step overshoot %.2f %%, rise %.3f s, "
                   "settling %.3f s, sse %.4f m; fig8 rms %.4f m, max %.4f m\n",
                   rule.c_str(), horizontal_only ? " (x, y only)" : "", g.kx.x(), g.kx.y(), g.kx.z(),
                   g.kv.x(), g.kv.y(), g.kv.z(), st.worst.overshoot_pct, st.worst.rise_time_s,
                   st.worst.settling_time_s, st.sse_m, f8.error.rms_m, f8.error.max_m);
    }
  }
  return 0;
}

}  // namespace
}  // namespace quad_bench

int main(int argc, char** argv) {
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--help" || a == "-h") {
      std::fputs(quad_bench::kUsage, stdout);
      return 0;
    }
  }
  try {
    const quad_bench::Options o = quad_bench::Parse(argc, argv);
    if (o.command == "step") return quad_bench::CmdStep(o);
    if (o.command == "fig8") return quad_bench::CmdFig8(o);
    if (o.command == "update-time") return quad_bench::CmdUpdateTime(o);
    if (o.command == "zn") return quad_bench::CmdZn(o);
    std::fprintf(stderr, "tracker_eval: unknown command '%s' (step, fig8, update-time, zn)\n",
                 o.command.c_str());
    return 2;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "tracker_eval: %s\n", e.what());
    return 1;
  }
}
