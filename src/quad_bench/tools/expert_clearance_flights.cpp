// expert_clearance_flights: flies the expert in the simulator core (quad_bench::FlyExpert: quad_sim +
// kr_tracker + the planner in one deterministic process, no ROS) over seeded worlds and writes what an
// independent clearance check needs (quad_il.evaluation.clearance_check, docs/fast_planner.md "Clearance
// against the simulator's boxes"):
//
//   expert_clearance_flights --planner-config P --sim-config S --tracker-config T --seeds 1,2,3 --out DIR
//                            [--density D] [--distance-m 30] [--timeout-s 60] [--frames-every K]
//
// Per seed, the same start/goal pair and world as planner_bench's flight-quality flights (RandomStartGoal,
// MakeWorld), and in DIR:
//   world_<seed>.yaml    the world flown (quad_sim world format, exact round trip)
//   flown_<seed>.bin     float64 rows [t_s, p_world_body xyz, q_world_body xyzw, exact clearance_m], one per
//                        control period
//   frames_<seed>.jsonl  every K-th plan (K = --frames-every, 0 = none): the depth frame the plan used
//                        (intrinsics, camera pose, stamp) and the odometry; its pixels (float32, row-major)
//                        at byte `offset` of frames_<seed>.bin
//   flights.jsonl        one line per seed: outcome, exact minimum clearance, counts
//   run.json             the configs, the vehicle's collision box and the camera's depth range
// Prints one progress line per flight on stderr. Exit status: 0 done (whatever the flights did), 1 bad input,
// 2 usage.
#include <kr_tracker/config.h>
#include <quad_sim/sim_config.h>
#include <quad_sim/world.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <limits>
#include <memory>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "quad_bench/sim_flight.h"

namespace {

struct UsageError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

constexpr const char* kUsage =
    "usage: expert_clearance_flights --planner-config P --sim-config S --tracker-config T --seeds 1,2,3 "
    "--out DIR [options]\n"
    "  --planner-config P  the expert's config (required)\n"
    "  --sim-config S      simulator config (required)\n"
    "  --tracker-config T  tracker config (required)\n"
    "  --seeds 1,2,3       world seeds, one flight each (required)\n"
    "  --out DIR           output directory (required)\n"
    "  --density D         box density per 100 m^2, 0 keeps the sim config's (default: 0)\n"
    "  --distance-m M      start-goal distance (default: 30)\n"
    "  --timeout-s S       sim-time limit of a flight (default: 60)\n"
    "  --frames-every K    also save every K-th depth frame with its pose, 0 none (default: 0)\n";

struct Args {
  std::string planner_config, sim_config, tracker_config, out;
  std::vector<uint64_t> seeds;
  double density = 0.0;
  double distance_m = 30.0;
  double timeout_s = 60.0;
  int frames_every = 0;
};

std::vector<uint64_t> ParseSeeds(const std::string& s) {
  std::vector<uint64_t> out;
  std::stringstream in(s);
  std::string item;
  while (std::getline(in, item, ',')) {
    size_t used = 0;
    const unsigned long long v = std::stoull(item, &used);
    if (used != item.size()) throw UsageError("bad seed '" + item + "'");
    out.push_back(v);
  }
  if (out.empty()) throw UsageError("--seeds is empty");
  return out;
}

double ParsePositive(const std::string& key, const std::string& text, bool allow_zero) {
  size_t used = 0;
  const double v = std::stod(text, &used);
  if (used != text.size() || !std::isfinite(v) || v < 0.0 || (!allow_zero && v == 0.0)) {
    throw UsageError(key + " must be a finite number " + (allow_zero ? ">= 0" : "> 0") + ", got '" + text +
                     "'");
  }
  return v;
}

Args Parse(int argc, char** argv) {
  Args a;
  for (int i = 1; i < argc; i += 2) {
    const std::string k = argv[i];
    if (i + 1 >= argc) throw UsageError("missing value after " + k);
    const std::string v = argv[i + 1];
    try {
      if (k == "--planner-config") {
        a.planner_config = v;
      } else if (k == "--sim-config") {
        a.sim_config = v;
      } else if (k == "--tracker-config") {
        a.tracker_config = v;
      } else if (k == "--out") {
        a.out = v;
      } else if (k == "--seeds") {
        a.seeds = ParseSeeds(v);
      } else if (k == "--density") {
        a.density = ParsePositive(k, v, true);
      } else if (k == "--distance-m") {
        a.distance_m = ParsePositive(k, v, false);
      } else if (k == "--timeout-s") {
        a.timeout_s = ParsePositive(k, v, false);
      } else if (k == "--frames-every") {
        size_t used = 0;
        a.frames_every = std::stoi(v, &used);
        if (used != v.size() || a.frames_every < 0)
          throw UsageError("--frames-every must be an integer >= 0");
      } else {
        throw UsageError("unknown argument " + k);
      }
    } catch (const std::logic_error& e) {
      throw UsageError("bad value for " + k + " '" + v + "': " + e.what());
    }
  }
  if (a.planner_config.empty() || a.sim_config.empty() || a.tracker_config.empty() || a.out.empty() ||
      a.seeds.empty()) {
    throw UsageError("--planner-config, --sim-config, --tracker-config, --seeds and --out are required");
  }
  return a;
}

std::string Num(double v) {
  if (!std::isfinite(v)) return v > 0 ? "Infinity" : (v < 0 ? "-Infinity" : "NaN");
  char buf[40];
  std::snprintf(buf, sizeof(buf), "%.17g", v);
  return buf;
}

std::string Vec(const Eigen::Vector3d& v) {
  return "[" + Num(v.x()) + ", " + Num(v.y()) + ", " + Num(v.z()) + "]";
}

std::string Quat(const Eigen::Quaterniond& q) {
  return "[" + Num(q.x()) + ", " + Num(q.y()) + ", " + Num(q.z()) + ", " + Num(q.w()) + "]";
}

std::string JsonString(const std::string& s) {
  std::string out = "\"";
  for (const char c : s) {
    if (c == '"' || c == '\\') {
      out += '\\';
      out += c;
    } else if (static_cast<unsigned char>(c) < 0x20) {
      char buf[8];
      std::snprintf(buf, sizeof(buf), "\\u%04x", c);
      out += buf;
    } else {
      out += c;
    }
  }
  return out + "\"";
}

std::ofstream OpenOut(const std::string& path, std::ios::openmode mode = std::ios::out) {
  std::ofstream f(path, mode);
  if (!f) throw std::runtime_error("cannot write " + path);
  return f;
}

// Keeps every K-th plan's depth frame and odometry (the plan's own inputs, PlanRecord).
class FrameWriter : public fast_planner::PlanObserver {
 public:
  FrameWriter(const std::string& stem, int every)
      : every_(every), meta_(OpenOut(stem + ".jsonl")), pixels_(OpenOut(stem + ".bin", std::ios::binary)) {}

  void OnPlan(const fast_planner::PlanRecord& r) override {
    if (every_ <= 0 || (plans_++ % every_) != 0 || !r.depth || !r.odometry) return;
    const fast_planner::DepthFrame& d = *r.depth;
    const auto& k = d.intrinsics;
    meta_ << "{\"stamp_s\": " << Num(d.stamp_s) << ", \"width\": " << k.width << ", \"height\": " << k.height
          << ", \"fx\": " << Num(k.fx) << ", \"fy\": " << Num(k.fy) << ", \"cx\": " << Num(k.cx)
          << ", \"cy\": " << Num(k.cy) << ", \"p_world_camera\": " << Vec(d.p_world_camera)
          << ", \"q_world_camera\": " << Quat(d.q_world_camera)
          << ", \"odom_stamp_s\": " << Num(r.odometry->t_s)
          << ", \"p_world_body\": " << Vec(r.odometry->p_world_body)
          << ", \"v_world\": " << Vec(r.odometry->v_world)
          << ", \"q_world_body\": " << Quat(r.odometry->q_world_body) << ", \"offset\": " << offset_ << "}\n";
    const auto bytes = static_cast<std::streamsize>(d.image.depth_m.size() * sizeof(float));
    pixels_.write(reinterpret_cast<const char*>(d.image.depth_m.data()), bytes);
    offset_ += bytes;
    if (!meta_ || !pixels_) throw std::runtime_error("writing the frames failed (disk full?)");
  }

 private:
  int every_;
  int plans_ = 0;
  std::streamsize offset_ = 0;
  std::ofstream meta_;
  std::ofstream pixels_;
};

int Run(const Args& args) {
  const fast_planner::PlannerConfig planner = fast_planner::LoadPlannerConfig(args.planner_config);
  const quad_sim::SimConfig sim = quad_sim::LoadSimConfig(args.sim_config);
  const kr_tracker::TrackerConfig tracker = kr_tracker::LoadTrackerConfig(args.tracker_config);
  std::filesystem::create_directories(args.out);
  const std::string dir = args.out + "/";
  {
    std::ofstream run = OpenOut(dir + "run.json");
    run << "{\"planner_config\": " << JsonString(args.planner_config)
        << ", \"sim_config\": " << JsonString(args.sim_config)
        << ", \"tracker_config\": " << JsonString(args.tracker_config)
        << ", \"density\": " << Num(args.density) << ", \"distance_m\": " << Num(args.distance_m)
        << ", \"timeout_s\": " << Num(args.timeout_s) << ", \"frames_every\": " << args.frames_every
        << ", \"vehicle_collision_box_m\": " << Vec(sim.vehicle.collision_box_m)
        << ", \"camera_min_depth_m\": " << Num(sim.camera.min_depth_m)
        << ", \"camera_max_depth_m\": " << Num(sim.camera.max_depth_m)
        << ", \"camera_noise_std_at_1m_m\": " << Num(sim.camera.noise_std_at_1m_m) << "}\n";
  }
  std::ofstream flights = OpenOut(dir + "flights.jsonl");
  for (const uint64_t seed : args.seeds) {
    const std::string tag = std::to_string(seed);
    quad_bench::FlightSetup setup;
    quad_bench::RandomStartGoal(sim, seed, args.distance_m, 1.0, 2.0, &setup.start_m, &setup.goal_m);
    setup.world = quad_bench::MakeWorld(sim, seed, args.density, setup.start_m, setup.goal_m);
    setup.timeout_s = args.timeout_s;
    quad_sim::SaveWorld(setup.world, dir + "world_" + tag + ".yaml");
    auto frames = std::make_shared<FrameWriter>(dir + "frames_" + tag, args.frames_every);
    const quad_bench::FlightStats s = quad_bench::FlyExpert(planner, sim, tracker, setup, frames);

    std::ofstream flown = OpenOut(dir + "flown_" + tag + ".bin", std::ios::binary);
    for (const auto& f : s.flown) {
      const double row[9] = {f.t_s,
                             f.p_world_body.x(),
                             f.p_world_body.y(),
                             f.p_world_body.z(),
                             f.q_world_body.x(),
                             f.q_world_body.y(),
                             f.q_world_body.z(),
                             f.q_world_body.w(),
                             f.clearance_m};
      flown.write(reinterpret_cast<const char*>(row), sizeof(row));
    }
    if (!flown) throw std::runtime_error("writing " + dir + "flown_" + tag + ".bin failed");
    flights << "{\"seed\": " << seed << ", \"boxes\": " << setup.world.boxes.size()
            << ", \"start_m\": " << Vec(setup.start_m) << ", \"goal_m\": " << Vec(setup.goal_m)
            << ", \"reached_goal\": " << (s.reached_goal ? "true" : "false")
            << ", \"collided\": " << (s.collided ? "true" : "false")
            << ", \"end_reason\": " << JsonString(s.end_reason)
            << ", \"flight_time_s\": " << Num(s.flight_time_s)
            << ", \"min_clearance_m\": " << Num(s.min_clearance_m) << ", \"plans\": " << s.plans
            << ", \"plan_failures\": " << s.plan_failures << ", \"emergency_stops\": " << s.emergency_stops
            << ", \"flown_samples\": " << s.flown.size() << "}" << std::endl;
    std::fprintf(
        stderr,
        "[expert_clearance_flights] seed %s: %s%s after %.1f s, %d plans, min exact clearance %.3f m: "
        "%s\n",
        tag.c_str(), s.reached_goal ? "reached" : "NOT reached", s.collided ? ", COLLIDED" : "",
        s.flight_time_s, s.plans, s.min_clearance_m, s.end_reason.c_str());
  }
  if (!flights) throw std::runtime_error("writing " + dir + "flights.jsonl failed");
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  for (int i = 1; i < argc; ++i) {
    if (std::string(argv[i]) == "--help" || std::string(argv[i]) == "-h") {
      std::cout << kUsage;
      return 0;
    }
  }
  try {
    return Run(Parse(argc, argv));
  } catch (const UsageError& e) {
    std::cerr << "expert_clearance_flights: " << e.what() << "\n" << kUsage;
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "expert_clearance_flights: " << e.what() << "\n";
    return 1;
  }
}
