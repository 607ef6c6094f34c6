// Benchmark driver for scripts/bench/sim.sh: depth render time per frame and the simulator's real-time factor
// (as fast as possible, 1 kHz dynamics, odometry at odometry_rate_hz, depth at camera.rate_hz) in the default
// world. Prints `BENCH <name> <value> <unit>` lines on stdout and progress on stderr.
//
//   quad_sim_bench --config config/sim.yaml --width 320 --height 240 [--frames 200] [--sim-seconds 20]
#include "quad_sim/math_utils.h"
#include "quad_sim/simulator.h"

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <stdexcept>
#include <string>

namespace {

struct Args {
  std::string config = "config/sim.yaml";
  int width = 320;
  int height = 240;
  int frames = 200;
  double sim_seconds = 20.0;
  uint64_t seed = 1;
};

Args Parse(int argc, char** argv) {
  Args a;
  for (int i = 1; i < argc; ++i) {
    const std::string k = argv[i];
    if (i + 1 >= argc) throw std::invalid_argument("missing value for " + k);
    const std::string v = argv[++i];
    if (k == "--config") {
      a.config = v;
    } else if (k == "--width") {
      a.width = std::stoi(v);
    } else if (k == "--height") {
      a.height = std::stoi(v);
    } else if (k == "--frames") {
      a.frames = std::stoi(v);
    } else if (k == "--sim-seconds") {
      a.sim_seconds = std::stod(v);
    } else if (k == "--seed") {
      a.seed = std::stoull(v);
    } else {
      throw std::invalid_argument("unknown argument " + k);
    }
  }
  return a;
}

using Clock = std::chrono::steady_clock;
double Seconds(Clock::duration d) { return std::chrono::duration<double>(d).count(); }

// A small position PD loop on top of the SO(3) command interface: flies the vehicle along the start-goal line
// at 1.5 m so that the depth camera sees a changing scene (the benchmark does not need the real tracker).
quad_sim::So3Command Follow(const quad_sim::Simulator& sim, const Eigen::Vector3d& p_ref,
                            const Eigen::Vector3d& v_ref) {
  const quad_core::VehicleParams& p = sim.config().vehicle;
  const quad_sim::DynamicsState& s = sim.state();
  const Eigen::Vector3d a = 4.0 * (p_ref - s.p_world_body) + 3.0 * (v_ref - s.v_world);
  quad_sim::So3Command c;
  c.force_world_N = p.mass_kg * (a + Eigen::Vector3d(0, 0, p.gravity_mps2));
  const Eigen::Vector3d z_b = c.force_world_N.normalized();
  const Eigen::Vector3d y_b = z_b.cross(Eigen::Vector3d::UnitX()).normalized();
  Eigen::Matrix3d R;
  R << y_b.cross(z_b), y_b, z_b;
  c.q_world_des = Eigen::Quaterniond(R);
  return c;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    const Args args = Parse(argc, argv);
    quad_sim::SimConfig cfg = quad_sim::LoadSimConfig(args.config);
    cfg.camera.intrinsics = quad_sim::DepthCameraConfig::FastPlannerFov(args.width, args.height);
    cfg.collision_policy =
        quad_sim::CollisionPolicy::kContinue;  // keep flying: we time the simulator, not a plan
    const std::string res = std::to_string(args.width) + "x" + std::to_string(args.height);

    // Depth render time: frames along the start-goal line of the default world, looking towards the goal.
    quad_sim::Simulator sim(cfg);
    const quad_sim::World world = quad_sim::GenerateWorld(cfg.world_gen, args.seed);
    const Eigen::Vector3d start(cfg.start_m.x(), cfg.start_m.y(), 1.5);
    const Eigen::Vector3d goal = cfg.goal_m;
    sim.Reset(world, start, 0.0, goal);
    quad_sim::WorldIndex index;
    index.Build(world);
    const quad_sim::DepthRenderer renderer(cfg.camera);
    double total_s = 0.0;
    double checksum = 0.0;
    for (int i = 0; i < args.frames; ++i) {
      const double f = static_cast<double>(i) / std::max(1, args.frames - 1);
      const Eigen::Vector3d p = start + f * (goal - start);
      const Eigen::Quaterniond q =
          quad_sim::QuatFromRpy(0, 0, 0.3 * std::sin(0.1 * i)) * cfg.camera.q_body_camera;
      const auto t0 = Clock::now();
      const quad_core::DepthImage img = renderer.Render(index, p, q);
      total_s += Seconds(Clock::now() - t0);
      checksum +=
          std::isfinite(img.depth_m[img.depth_m.size() / 2]) ? img.depth_m[img.depth_m.size() / 2] : 0.0;
    }
    std::cerr << "[bench] depth " << res << ": " << args.frames << " frames, " << cfg.camera.num_threads
              << " thread(s), checksum " << checksum << "\n";
    std::printf("BENCH sim_depth_ms_%s %.3f ms\n", res.c_str(), 1000.0 * total_s / args.frames);

    // Real-time factor: the whole loop as the node runs it, without ROS.
    sim.Reset(world, start, 0.0, goal);
    const double speed_mps = 2.0;
    const Eigen::Vector3d dir = (goal - start).normalized();
    int depth_frames = 0;
    int odom_msgs = 0;
    const auto t0 = Clock::now();
    while (sim.time_s() < args.sim_seconds) {
      if (sim.OdometryDue()) {
        ++odom_msgs;
        const double s = std::min(speed_mps * sim.time_s(), (goal - start).norm());
        sim.SetSo3Command(Follow(sim, start + s * dir, dir * speed_mps));
      }
      if (sim.DepthDue()) {
        const quad_core::DepthImage img = sim.RenderDepth();
        ++depth_frames;
        checksum += img.depth_m[0];
      }
      sim.Step();
    }
    const double wall_s = Seconds(Clock::now() - t0);
    std::cerr << "[bench] rtf " << res << ": " << args.sim_seconds << " s sim in " << wall_s << " s wall, "
              << odom_msgs << " odometry, " << depth_frames << " depth frames, final x "
              << sim.state().p_world_body.x() << ", collisions " << sim.collision().num_collisions << "\n";
    std::printf("BENCH sim_rtf_%s %.2f x\n", res.c_str(), sim.time_s() / wall_s);
    return 0;
  } catch (const std::exception& e) {
    std::cerr << "quad_sim_bench: " << e.what() << "\n";
    return 1;
  }
}
