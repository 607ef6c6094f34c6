// policy_bench: the inference benchmark's C++ side (scripts/bench/inference.sh, docs/inference.md).
//
//   policy_bench frames --sim-config config/sim.yaml --seed 1 --count 200 --out DIR [--speed-mps 2]
//       renders a flight-like sequence of depth frames in the seeded default world (poses along the
//       start-goal line of the sim config at 1.5 m, sidestepping obstacles, heading to the goal, one frame
//       per camera period at the given speed) and writes them as a DecisionFixture (the Python benchmark
//       reads the same files).
//   policy_bench time --policy FILE --fixture DIR --config config/policy.yaml --threads N --name PREFIX
//       [--repeat R] [--malloc-tuning 0|1]
//       decision latency per frame = preprocessing + forward + decoding + quad_msgs/Bspline construction;
//       prints `BENCH PREFIX_ms_median` and `BENCH PREFIX_ms_p99` (the safety layer's time goes to stderr).
//   policy_bench expert --planner-config config/planner.yaml --fixture DIR
//       the expert's cost per decision on the same frames: map update (depth integration + ESDF) + plan, with
//       the fast_planner core (built only when fast_planner is in the workspace); prints `BENCH
//       expert_decision_ms_median`.
//
// Progress goes to stderr; exit status 0 done, 1 error, 2 usage.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include <quad_sim/depth_camera.h>
#include <quad_sim/geometry.h>
#include <quad_sim/sim_config.h>
#include <quad_sim/world.h>
#include <quad_sim/world_index.h>

#include "quad_policy/config.h"
#include "quad_policy/fixture.h"
#include "quad_policy/policy_decider.h"
#include "quad_policy/torch_policy.h"
#include "ros/messages.h"  // quad_policy/src/ros: the node's message conversion, timed too

#ifdef QUAD_POLICY_HAVE_FAST_PLANNER
#include <fast_planner/planner_config.h>
#include <fast_planner/planner_manager.h>
#endif

namespace {

using Args = std::map<std::string, std::string>;

// A command-line problem (missing or malformed option): usage is printed, exit status 2.
class UsageError : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

constexpr const char* kUsage =
    "usage: policy_bench frames --sim-config F --seed S --count N --out DIR [--speed-mps V]\n"
    "         depth frames along a straight flight in a generated world, written as a decision fixture\n"
    "         --speed-mps V      flight speed between frames (default: 2.0)\n"
    "       policy_bench time --policy F --fixture DIR --config F --threads N --name PREFIX [options]\n"
    "         decision latency of the C++ policy on the fixture's frames (BENCH lines named PREFIX_*)\n"
    "         --repeat R         passes over the fixture (default: 1)\n"
    "         --malloc-tuning 0  leave glibc malloc untuned (default: tuned as policy_node does)\n"
    "       policy_bench expert --planner-config F --fixture DIR\n"
    "         the expert's decision (map update + plan) on the same frames\n";

int Usage() {
  std::cerr << kUsage;
  return 2;
}

const std::string& Need(const Args& a, const std::string& key) {
  const auto it = a.find(key);
  if (it == a.end()) throw UsageError("missing --" + key);
  return it->second;
}

double Percentile(std::vector<double> v, double q) {
  std::sort(v.begin(), v.end());
  // Nearest rank (q in [0, 1]).
  const std::size_t idx = static_cast<std::size_t>(std::ceil(q * v.size())) - 1;
  return v[std::min(idx, v.size() - 1)];
}

double MsSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

int Frames(const Args& a) {
  const quad_sim::SimConfig cfg = quad_sim::LoadSimConfig(Need(a, "sim-config"));
  const uint64_t seed = std::stoull(Need(a, "seed"));
  const int count = std::stoi(Need(a, "count"));
  const double speed = a.count("speed-mps") ? std::stod(a.at("speed-mps")) : 2.0;
  if (count < 1 || !(speed > 0.0)) throw UsageError("--count must be >= 1 and --speed-mps > 0");
  const double altitude_m = 1.5;
  quad_sim::WorldGenConfig gen = cfg.world_gen;
  gen.AddClearZone(cfg.start_m);
  gen.AddClearZone(cfg.goal_m);
  const quad_sim::World world = quad_sim::GenerateWorld(gen, seed);
  quad_sim::WorldIndex index;
  index.Build(world);
  const quad_sim::DepthRenderer renderer(cfg.camera);
  const quad_core::CameraIntrinsics& k = cfg.camera.intrinsics;
  const Eigen::Vector3d goal(cfg.goal_m.x(), cfg.goal_m.y(), altitude_m);
  Eigen::Vector3d p(cfg.start_m.x(), cfg.start_m.y(), altitude_m);
  const double step = speed / cfg.camera.rate_hz;
  const auto clearance = [&](const Eigen::Vector3d& c, double yaw) {
    quad_sim::OrientedBox box;
    box.center_world_m = c;
    box.q_world_box = Eigen::Quaterniond(Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()));
    box.size_m = cfg.vehicle.collision_box_m;
    return index.Clearance(box).distance_m;
  };
  quad_policy::DecisionFixture fx;
  fx.fx = k.fx;
  fx.fy = k.fy;
  fx.cx = k.cx;
  fx.cy = k.cy;
  fx.T_body_camera.linear() = cfg.camera.q_body_camera.toRotationMatrix();
  fx.T_body_camera.translation() = cfg.camera.p_body_camera_m;
  for (int i = 0; i < count; ++i) {
    Eigen::Vector3d dir = goal - p;
    dir.z() = 0.0;
    if (dir.norm() < step) break;
    dir.normalize();
    const double yaw = std::atan2(dir.y(), dir.x());
    const Eigen::Vector3d side(-dir.y(), dir.x(), 0.0);
    // Ahead, or the nearest sideways offset (0.25 m steps, alternating sides) with 0.4 m clearance.
    Eigen::Vector3d next = p + step * dir;
    for (int j = 1; j <= 24 && clearance(next, yaw) < 0.4; ++j) {
      next = p + step * dir + ((j % 2) ? 1.0 : -1.0) * 0.25 * ((j + 1) / 2) * side;
    }
    quad_policy::RecordedFrame f;
    f.stamp_s = 1.0 + i / cfg.camera.rate_hz;
    f.state.v_world = (next - p) * cfg.camera.rate_hz;
    p = next;
    f.state.p_world_body = p;
    f.state.q_world_body = Eigen::Quaterniond(Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()));
    f.goal_world = goal;
    const Eigen::Vector3d p_cam = p + f.state.q_world_body * cfg.camera.p_body_camera_m;
    const Eigen::Quaterniond q_cam = f.state.q_world_body * cfg.camera.q_body_camera;
    const quad_core::DepthImage img = renderer.Render(index, p_cam, q_cam);
    f.depth.width = img.width;
    f.depth.height = img.height;
    f.depth.depth_m = img.depth_m;
    fx.frames.push_back(std::move(f));
  }
  quad_policy::WriteDecisionFixture(Need(a, "out"), fx);
  std::cerr << "[policy_bench] " << fx.frames.size() << " frames of " << k.width << "x" << k.height
            << " in world seed " << seed << " written to " << Need(a, "out") << "\n";
  return 0;
}

int Time(const Args& a) {
  const quad_policy::PolicyNodeConfig cfg = quad_policy::LoadPolicyNodeConfig(Need(a, "config"));
  const int threads = std::stoi(Need(a, "threads"));
  const std::string name = Need(a, "name");
  const int repeat = a.count("repeat") ? std::stoi(a.at("repeat")) : 1;
  // As policy_node does; --malloc-tuning 0 measures without it.
  if (!a.count("malloc-tuning") || a.at("malloc-tuning") != "0") quad_policy::TuneMallocForInference();
  quad_policy::ConfigureTorchThreads(threads);
  auto policy = std::make_shared<const quad_policy::TorchPolicy>(Need(a, "policy"));
  quad_policy::PolicyDecider decider(policy, cfg.safety, cfg.refusal);
  const quad_policy::DecisionFixture fx = quad_policy::ReadDecisionFixture(Need(a, "fixture"));
  std::vector<double> decision_ms, safety_ms, forward_ms, pre_ms;
  int64_t traj_id = 0;
  for (int r = -1; r < repeat; ++r) {  // r = -1: warm-up pass, not recorded
    for (std::size_t i = 0; i < fx.frames.size(); ++i) {
      const quad_policy::RecordedFrame& f = fx.frames[i];
      quad_policy::DecisionInputs in;
      in.stamp_s = f.stamp_s;
      in.depth = f.depth.view();
      in.camera = fx.Camera(i);
      in.state = f.state;
      in.goal_world = f.goal_world;
      const quad_policy::Decision d = decider.Decide(in);
      const auto t0 = std::chrono::steady_clock::now();
      const quad_msgs::Bspline msg =
          quad_policy::ToBsplineMessage(d.proposed, ++traj_id, ros::Time(f.stamp_s));
      const double message_ms = MsSince(t0) + d.timings.decode_ms;
      if (msg.pos_pts.empty()) throw std::runtime_error("empty message");
      if (r < 0) continue;
      pre_ms.push_back(d.timings.preprocess_ms);
      forward_ms.push_back(d.timings.forward_ms);
      decision_ms.push_back(d.timings.preprocess_ms + d.timings.forward_ms + message_ms);
      safety_ms.push_back(d.timings.safety_ms);
    }
  }
  const auto& counts = decider.counts();
  std::fprintf(
      stderr,
      "[policy_bench] %s: %zu decisions, %d thread(s): preprocessing median %.3f ms, forward median %.3f "
      "ms, safety layer median %.3f ms p99 %.3f ms; verdicts: %lu accepted, %lu refused\n",
      name.c_str(), decision_ms.size(), quad_policy::TorchThreads(), Percentile(pre_ms, 0.5),
      Percentile(forward_ms, 0.5), Percentile(safety_ms, 0.5), Percentile(safety_ms, 0.99),
      counts[quad_policy::SafetyVerdict::kAccepted], counts.refused());
  std::printf("BENCH %s_ms_median %.3f ms\n", name.c_str(), Percentile(decision_ms, 0.5));
  std::printf("BENCH %s_ms_p99 %.3f ms\n", name.c_str(), Percentile(decision_ms, 0.99));
  return 0;
}

int Expert(const Args& a) {
#ifdef QUAD_POLICY_HAVE_FAST_PLANNER
  const fast_planner::PlannerConfig cfg = fast_planner::LoadPlannerConfig(Need(a, "planner-config"));
  const quad_policy::DecisionFixture fx = quad_policy::ReadDecisionFixture(Need(a, "fixture"));
  fast_planner::PlannerManager manager(cfg);
  std::vector<double> ms, map_ms;
  int ok = 0;
  for (std::size_t i = 0; i < fx.frames.size(); ++i) {
    const quad_policy::RecordedFrame& f = fx.frames[i];
    const quad_policy::CameraModel cam = fx.Camera(i);
    auto frame = std::make_shared<fast_planner::DepthFrame>();
    frame->stamp_s = f.stamp_s;
    frame->seq = i;
    frame->intrinsics.width = f.depth.width;
    frame->intrinsics.height = f.depth.height;
    frame->intrinsics.fx = fx.fx;
    frame->intrinsics.fy = fx.fy;
    frame->intrinsics.cx = fx.cx;
    frame->intrinsics.cy = fx.cy;
    frame->image = f.depth;
    frame->p_world_camera = cam.T_world_camera.translation();
    frame->q_world_camera = Eigen::Quaterniond(cam.T_world_camera.linear());
    quad_core::VehicleState odom;
    odom.t_s = f.stamp_s;
    odom.p_world_body = f.state.p_world_body;
    odom.q_world_body = f.state.q_world_body;
    odom.v_world = f.state.v_world;
    fast_planner::PlanRequest req;
    req.start_p = f.state.p_world_body;
    req.start_v = f.state.v_world;
    req.goal = f.goal_world;
    req.start_time_s = f.stamp_s;
    const auto t0 = std::chrono::steady_clock::now();
    manager.UpdateOdometry(odom);
    const fast_planner::MapUpdateResult upd = manager.UpdateDepth(frame);
    const fast_planner::PlanResult plan = manager.Plan(req);
    ms.push_back(MsSince(t0));
    map_ms.push_back(upd.total_ms);
    ok += plan.ok() ? 1 : 0;
  }
  std::fprintf(
      stderr,
      "[policy_bench] expert: %zu decisions (map update + plan), %d plans succeeded; map update median "
      "%.3f ms; decision p99 %.3f ms\n",
      ms.size(), ok, Percentile(map_ms, 0.5), Percentile(ms, 0.99));
  std::printf("BENCH expert_decision_ms_median %.3f ms\n", Percentile(ms, 0.5));
  return 0;
#else
  (void)a;
  std::cerr << "policy_bench expert: built without fast_planner (not in the workspace)\n";
  return 3;
#endif
}

}  // namespace

int main(int argc, char** argv) {
  for (int i = 1; i < argc; ++i) {
    if (std::string(argv[i]) == "--help" || std::string(argv[i]) == "-h") {
      std::cout << kUsage;
      return 0;
    }
  }
  if (argc < 2) return Usage();
  const std::string cmd = argv[1];
  Args args;
  for (int i = 2; i < argc; i += 2) {
    const std::string key = argv[i];
    if (key.rfind("--", 0) != 0 || i + 1 >= argc) return Usage();
    args[key.substr(2)] = argv[i + 1];
  }
  try {
    if (cmd == "frames") return Frames(args);
    if (cmd == "time") return Time(args);
    if (cmd == "expert") return Expert(args);
  } catch (const UsageError& e) {
    std::cerr << "policy_bench: " << e.what() << "\n";
    return Usage();
  } catch (const std::exception& e) {
    std::cerr << "policy_bench: " << e.what() << "\n";
    return 1;
  }
  return Usage();
}
