// The planner benchmark (issue 5), ROS-free: closed-loop flights of the expert in the simulator core.
//
//   planner_bench --planner-config config/planner.yaml --sim-config config/sim.yaml
//                 --tracker-config config/tracker.yaml [--seeds 1,2,3 | --worlds 20] [--density 12.5]
//                 [--timing-seed 1] [--min-replans 200] [--skip-timing] [--skip-flight]
//
// Timing: flights between a fixed list of start/goal pairs in one fixed seeded world until at least
// --min-replans plans were made; every plan's front-end, optimisation and total time, and every depth frame's
// map update time. Flight quality: one 30 m start/goal pair per seeded world (seeds from --seeds,
// else 1..--worlds) at the given box density (boxes per 100 m^2; default: the simulator config's count).
// Prints `BENCH name value unit` lines on stdout and progress on stderr.
#include <kr_tracker/config.h>
#include <quad_sim/sim_config.h>
#include <quad_sim/voxel_map.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "quad_bench/sim_flight.h"

namespace {

struct Args {
  std::string planner_config;
  std::string sim_config;
  std::string tracker_config;
  std::vector<uint64_t> seeds;
  int worlds = 20;
  double density = 0.0;
  uint64_t timing_seed = 1;
  int min_replans = 200;
  bool timing = true;
  bool flight = true;
};

constexpr const char* kUsage =
    "usage: planner_bench --planner-config P --sim-config S --tracker-config T [options]\n"
    "  --planner-config P  the expert's config (required)\n"
    "  --sim-config S      simulator config (required)\n"
    "  --tracker-config T  tracker config (required)\n"
    "  --seeds 1,2,3       world seeds of the flights (default: 1..N of --worlds)\n"
    "  --worlds N          number of worlds when --seeds is not given (default: 20)\n"
    "  --density D         box density per 100 m^2, 0 keeps the sim config's (default: 0)\n"
    "  --timing-seed S     seed of the timing part's world (default: 1)\n"
    "  --min-replans N     replans the timing part measures at least (default: 200)\n"
    "  --skip-timing       skip the timing part (default: run it)\n"
    "  --skip-flight       skip the flight-quality part (default: run it)\n";

[[noreturn]] void Usage(const std::string& why) {
  std::cerr << "planner_bench: " << why << "\n" << kUsage;
  std::exit(2);
}

std::vector<uint64_t> ParseSeeds(const std::string& s) {
  std::vector<uint64_t> out;
  std::stringstream in(s);
  std::string item;
  while (std::getline(in, item, ',')) {
    if (item.empty()) continue;
    size_t used = 0;
    const unsigned long long v = std::stoull(item, &used);
    if (used != item.size()) throw std::invalid_argument("bad seed '" + item + "'");
    out.push_back(v);
  }
  return out;
}

Args Parse(int argc, char** argv) {
  Args a;
  for (int i = 1; i < argc; ++i) {
    const std::string k = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) Usage("missing value after " + k);
      return argv[++i];
    };
    try {
      if (k == "--help" || k == "-h") {
        std::fputs(kUsage, stdout);
        std::exit(0);
      } else if (k == "--planner-config") {
        a.planner_config = value();
      } else if (k == "--sim-config") {
        a.sim_config = value();
      } else if (k == "--tracker-config") {
        a.tracker_config = value();
      } else if (k == "--seeds") {
        a.seeds = ParseSeeds(value());
      } else if (k == "--worlds") {
        a.worlds = std::stoi(value());
      } else if (k == "--density") {
        a.density = std::stod(value());
      } else if (k == "--timing-seed") {
        a.timing_seed = std::stoull(value());
      } else if (k == "--min-replans") {
        a.min_replans = std::stoi(value());
      } else if (k == "--skip-timing") {
        a.timing = false;
      } else if (k == "--skip-flight") {
        a.flight = false;
      } else {
        Usage("unknown argument " + k);
      }
    } catch (const std::logic_error& e) {
      Usage("bad value for " + k + ": " + e.what());
    }
  }
  if (a.planner_config.empty() || a.sim_config.empty() || a.tracker_config.empty())
    Usage("configs are required");
  if (a.worlds < 1) Usage("--worlds must be >= 1");
  if (!(a.density >= 0.0) || !std::isfinite(a.density)) Usage("--density must be >= 0");
  if (a.seeds.empty()) {
    for (int i = 1; i <= a.worlds; ++i) a.seeds.push_back(static_cast<uint64_t>(i));
  }
  return a;
}

// Nearest-rank percentile of an unsorted sample (p in (0, 100]).
double Percentile(std::vector<double> v, double p) {
  if (v.empty()) return std::nan("");
  std::sort(v.begin(), v.end());
  const size_t rank = static_cast<size_t>(std::ceil(p / 100.0 * v.size()));
  return v[std::clamp<size_t>(rank, 1, v.size()) - 1];
}

void Bench(const std::string& name, double value, const std::string& unit) {
  std::printf("BENCH %s %.4f %s\n", name.c_str(), value, unit.c_str());
}

void Progress(const std::string& what, const quad_bench::FlightStats& s) {
  std::fprintf(
      stderr,
      "[planner_bench] %s: %s%s after %.1f s, %d plans, %d failures, %d stops, %d starts not kept, min "
      "clearance %.3f m, path %.1f m (straight %.1f m): %s\n",
      what.c_str(), s.reached_goal ? "reached" : "NOT reached", s.collided ? ", COLLIDED" : "",
      s.flight_time_s, s.plans, s.plan_failures, s.emergency_stops, s.starts_not_kept, s.min_clearance_m,
      s.path_length_m, s.straight_line_m, s.end_reason.c_str());
  for (size_t i = 0; i < s.failure_reasons.size() && i < 3; ++i) {
    std::fprintf(stderr, "[planner_bench]   failure: %s\n", s.failure_reasons[i].c_str());
  }
  if (!s.reached_goal || s.collided) {
    // The end of the story: the last state machine transitions and failures.
    const size_t from = s.events.size() > 12 ? s.events.size() - 12 : 0;
    for (size_t i = from; i < s.events.size(); ++i) {
      std::fprintf(stderr, "[planner_bench]   %s\n", s.events[i].c_str());
    }
  }
}

constexpr double kPairDistanceM = 30.0;
constexpr double kMinHeightM = 1.0;
constexpr double kMaxHeightM = 2.0;
constexpr int kTimingPairs = 8;

}  // namespace

int main(int argc, char** argv) {
  const Args args = Parse(argc, argv);
  try {
    const fast_planner::PlannerConfig planner = fast_planner::LoadPlannerConfig(args.planner_config);
    const quad_sim::SimConfig sim = quad_sim::LoadSimConfig(args.sim_config);
    const kr_tracker::TrackerConfig tracker = kr_tracker::LoadTrackerConfig(args.tracker_config);

    if (args.timing) {
      // A fixed world with clear zones at every start and goal of the fixed pair list.
      std::vector<std::pair<Eigen::Vector3d, Eigen::Vector3d>> pairs(kTimingPairs);
      quad_sim::WorldGenConfig gen = sim.world_gen;
      for (int i = 0; i < kTimingPairs; ++i) {
        quad_bench::RandomStartGoal(sim, 1000 + i, kPairDistanceM, kMinHeightM, kMaxHeightM, &pairs[i].first,
                                    &pairs[i].second);
        gen.AddClearZone(pairs[i].first);
        gen.AddClearZone(pairs[i].second);
      }
      const quad_sim::World world = quad_sim::GenerateWorld(gen, args.timing_seed);
      if (planner.map.source == fast_planner::MapSource::kGlobal) {
        // The privileged expert's one-off cost per world (issue 32): the map and its ESDF in SetGlobalMap,
        // and the same world again after a reset (what ExpertSession::StartEpisode does every episode).
        std::vector<Eigen::Vector3d> points;
        for (const auto& c : quad_sim::VoxelMap::FromWorld(world, sim.voxel_map).OccupiedCenters()) {
          points.push_back(c.cast<double>());
        }
        fast_planner::PlannerManager manager(planner);
        const double build_ms = manager.SetGlobalMap(points);
        manager.Reset();
        const double again_ms = manager.SetGlobalMap(points);
        const Eigen::Vector3i n =
            manager.esdf().window_max() - manager.esdf().window_min() + Eigen::Vector3i::Ones();
        const Eigen::Vector3i m = manager.map().size_voxels();
        const double voxels = static_cast<double>(n.x()) * n.y() * n.z();
        std::fprintf(
            stderr,
            "[planner_bench] global map of %zu points: SetGlobalMap %.1f ms CPU (map + ESDF over %dx%dx%d "
            "voxels, %.1f MB kept, %.1f MB of scratch while built), the same points after a reset %.3f "
            "ms; the voxel map itself %dx%dx%d voxels, %.1f MB\n",
            points.size(), build_ms, n.x(), n.y(), n.z(), 4.0 * voxels / 1e6, 9.0 * voxels / 1e6, again_ms,
            m.x(), m.y(), m.z(), 7.0 * m.cast<double>().prod() / 1e6);
      }
      std::vector<double> front, opt, total, map, integrate, esdf, prep;
      for (int i = 0; static_cast<int>(total.size()) < args.min_replans; ++i) {
        quad_bench::FlightSetup setup;
        setup.world = world;
        setup.start_m = pairs[i % kTimingPairs].first;
        setup.goal_m = pairs[i % kTimingPairs].second;
        const quad_bench::FlightStats s = quad_bench::FlyExpert(planner, sim, tracker, setup);
        Progress("timing flight " + std::to_string(i + 1), s);
        for (const auto& t : s.plan_timings) {
          front.push_back(t.frontend_ms);
          opt.push_back(t.optimization_ms);
          total.push_back(t.total_ms);
          prep.push_back(t.map_prep_ms);
        }
        map.insert(map.end(), s.map_update_ms.begin(), s.map_update_ms.end());
        integrate.insert(integrate.end(), s.map_integrate_ms.begin(), s.map_integrate_ms.end());
        esdf.insert(esdf.end(), s.map_esdf_ms.begin(), s.map_esdf_ms.end());
        if (i > 10 * kTimingPairs) throw std::runtime_error("too few plans: the flights keep failing early");
      }
      std::fprintf(
          stderr,
          "[planner_bench] timing over %zu plans and %zu depth frames; map update median: ray casting %.2f "
          "ms, ESDF %.2f ms; ESDF computed before a plan (map.esdf_on_demand; none with the global source): "
          "median %.2f ms, p90 %.2f ms, max %.2f ms\n",
          total.size(), map.size(), Percentile(integrate, 50), Percentile(esdf, 50), Percentile(prep, 50),
          Percentile(prep, 90), Percentile(prep, 100));
      for (const auto& [name, v] : {std::pair<std::string, const std::vector<double>*>{"frontend", &front},
                                    {"opt", &opt},
                                    {"total", &total}}) {
        Bench("planner_" + name + "_ms_median", Percentile(*v, 50), "ms");
        Bench("planner_" + name + "_ms_p90", Percentile(*v, 90), "ms");
        Bench("planner_" + name + "_ms_p99", Percentile(*v, 99), "ms");
      }
      Bench("planner_map_update_ms_median", Percentile(map, 50), "ms");
    }

    if (args.flight) {
      int reached = 0, collisions = 0;
      double min_clearance = std::numeric_limits<double>::infinity();
      double speed_sum = 0.0, ratio_sum = 0.0;
      for (const uint64_t seed : args.seeds) {
        quad_bench::FlightSetup setup;
        quad_bench::RandomStartGoal(sim, seed, kPairDistanceM, kMinHeightM, kMaxHeightM, &setup.start_m,
                                    &setup.goal_m);
        setup.world = quad_bench::MakeWorld(sim, seed, args.density, setup.start_m, setup.goal_m);
        const quad_bench::FlightStats s = quad_bench::FlyExpert(planner, sim, tracker, setup);
        Progress("world seed " + std::to_string(seed) + " (" + std::to_string(setup.world.boxes.size()) +
                     " boxes)",
                 s);
        reached += s.reached_goal ? 1 : 0;
        collisions += s.collided ? 1 : 0;
        min_clearance = std::min(min_clearance, s.min_clearance_m);
        if (s.reached_goal) {
          speed_sum += s.path_length_m / s.flight_time_s;
          ratio_sum += s.path_length_m / s.straight_line_m;
        }
      }
      Bench("planner_goals_reached", reached, "goals");
      Bench("planner_goals_total", static_cast<double>(args.seeds.size()), "goals");
      Bench("planner_collisions", collisions, "collisions");
      Bench("planner_min_clearance_m", min_clearance, "m");
      Bench("planner_mean_speed_mps", reached ? speed_sum / reached : 0.0, "m/s");
      Bench("planner_path_ratio", reached ? ratio_sum / reached : 0.0, "ratio");
    }
  } catch (const std::exception& e) {
    std::cerr << "planner_bench: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
