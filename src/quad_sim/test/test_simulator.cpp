// The Simulator's contract: bad input, reset errors, schedules, episode outcomes, clearance, determinism.
#include "quad_sim/math_utils.h"
#include "quad_sim/simulator.h"

#include "test_util.h"

#include <gtest/gtest.h>
#include <quad_core/strict_yaml.h>

#include <cstring>
#include <limits>
#include <random>
#include <regex>

using quad_sim::OrientedBox;
using quad_sim::Simulator;
using quad_sim::World;
using quad_sim_test::TempFile;

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();

OrientedBox Box(const Eigen::Vector3d& c, const Eigen::Vector3d& size, double yaw = 0.0) {
  OrientedBox b;
  b.center_world_m = c;
  b.size_m = size;
  b.q_world_box = quad_sim::QuatFromRpy(0, 0, yaw);
  return b;
}

quad_sim::So3Command Climb(const quad_core::VehicleParams& p) {
  quad_sim::So3Command c;
  c.force_world_N = Eigen::Vector3d(0.3, -0.2, 1.2 * p.mass_kg * p.gravity_mps2);
  c.q_world_des = quad_sim::QuatFromRpy(0.05, -0.03, 0.2);
  return c;
}

bool SameState(const quad_sim::DynamicsState& a, const quad_sim::DynamicsState& b) {
  return a.p_world_body == b.p_world_body && a.v_world == b.v_world &&
         a.q_world_body.coeffs() == b.q_world_body.coeffs() && a.w_body == b.w_body &&
         a.motor_speeds_radps == b.motor_speeds_radps;
}

std::string SimYamlWith(const std::string& from, const std::string& to) {
  std::string text = quad_sim_test::ReadFile(quad_sim_test::RepoPath("config/sim.yaml"));
  text = std::regex_replace(text, std::regex("vehicle_file: vehicle.yaml"),
                            "vehicle_file: " + quad_sim_test::RepoPath("config/vehicle.yaml"));
  const std::string out = std::regex_replace(text, std::regex(from), to);
  EXPECT_NE(out, text) << "pattern not found: " << from;
  return out;
}

void ExpectSimConfigError(const std::string& text, const std::string& needle) {
  TempFile f(".yaml");
  f.Write(text);
  try {
    quad_sim::LoadSimConfig(f.path());
    FAIL() << "expected an error mentioning '" << needle << "'";
  } catch (const quad_core::ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
  }
}

}  // namespace

TEST(SimConfig, DefaultFileLoads) {
  const quad_sim::SimConfig c = quad_sim_test::DefaultSimConfig();
  EXPECT_DOUBLE_EQ(c.physics_dt_s, 0.001);
  EXPECT_EQ(c.camera.intrinsics.width, 320);
  EXPECT_DOUBLE_EQ(c.camera.intrinsics.fx, 193.6);
  EXPECT_EQ(c.vehicle.mass_kg, quad_sim_test::DefaultVehicle().mass_kg);
  EXPECT_EQ(c.time.mode, quad_sim::TimeMode::kRealTime);
  EXPECT_EQ(c.world_gen.TargetBoxCount(), 200);
}

TEST(SimConfig, UnknownKeyIsNamed) {
  ExpectSimConfigError(SimYamlWith("  rate_hz: 30.0", "  rate_hz: 30.0\n  frame_rate: 30"),
                       "'camera.frame_rate'");
}

TEST(SimConfig, MissingKeyIsNamed) {
  ExpectSimConfigError(SimYamlWith("odometry_rate_hz: 200.0", ""), "missing required key 'odometry_rate_hz'");
  ExpectSimConfigError(SimYamlWith("    min_gap_m: 0.5\n", ""),
                       "world.generator: missing required key 'min_gap_m'");
}

TEST(SimConfig, BadValuesAreNamed) {
  ExpectSimConfigError(SimYamlWith("policy: freeze", "policy: bounce"),
                       "'collision.policy' has value 'bounce'");
  ExpectSimConfigError(SimYamlWith("mode: real_time ", "mode: turbo "), "'time.mode' has value 'turbo'");
  ExpectSimConfigError(SimYamlWith("odometry_rate_hz: 200.0", "odometry_rate_hz: 300.0"), "must divide");
  ExpectSimConfigError(SimYamlWith("width: 320", "width: 0"), "'camera.width' has value 0");
  ExpectSimConfigError(SimYamlWith("vehicle_file: \\S+", "vehicle_file: /nonexistent.yaml"), "cannot open");
}

TEST(Commands, NanOrInfCommandIsRejectedAndLeavesStateUntouched) {
  const quad_sim::SimConfig cfg = quad_sim_test::DefaultSimConfig();
  Simulator a(cfg), b(cfg);
  for (Simulator* s : {&a, &b}) s->Reset(World(), Eigen::Vector3d(0, 0, 2), 0.0, Eigen::Vector3d(9, 9, 9));
  const quad_sim::So3Command good = Climb(cfg.vehicle);
  a.SetSo3Command(good);
  b.SetSo3Command(good);
  for (int i = 0; i < 50; ++i) {
    a.Step();
    b.Step();
  }
  quad_sim::So3Command bad = good;
  bad.force_world_N.x() = kNaN;
  const quad_sim::CommandStatus st = a.SetSo3Command(bad);
  EXPECT_FALSE(st.ok());
  EXPECT_EQ(st.code, quad_sim::CommandStatusCode::kNonFinite);
  EXPECT_EQ(st.reason, "force has a NaN/Inf element");
  EXPECT_TRUE(SameState(a.state(), b.state()));
  bad = good;
  bad.q_world_des.w() = kInf;
  EXPECT_EQ(a.SetSo3Command(bad).reason, "orientation has a NaN/Inf element");
  bad = good;
  bad.kOm.y() = -1.0;
  EXPECT_EQ(a.SetSo3Command(bad).reason, "kOm has a negative gain");
  bad = good;
  bad.q_world_des.coeffs().setZero();
  EXPECT_EQ(a.SetSo3Command(bad).code, quad_sim::CommandStatusCode::kInvalid);
  quad_sim::TrpyCommand trpy;
  trpy.pitch_rad = kNaN;
  EXPECT_EQ(a.SetTrpyCommand(trpy).reason, "roll/pitch/yaw has a NaN/Inf value");
  trpy.pitch_rad = 0.0;
  trpy.thrust_N = -kInf;
  EXPECT_EQ(a.SetTrpyCommand(trpy).reason, "thrust is NaN/Inf");
  EXPECT_EQ(a.num_rejected_commands(), 6);
  // The previous good command stays in force: both simulators keep evolving identically.
  for (int i = 0; i < 100; ++i) {
    a.Step();
    b.Step();
  }
  EXPECT_TRUE(SameState(a.state(), b.state()));
  EXPECT_GT(a.state().p_world_body.z(), 2.01);
}

TEST(Reset, StartPoseInsideABoxIsAClearError) {
  Simulator sim(quad_sim_test::DefaultSimConfig());
  World world;
  world.boxes.push_back(Box(Eigen::Vector3d(5, 5, 1), Eigen::Vector3d(1, 1, 1)));
  world.boxes.push_back(Box(Eigen::Vector3d(0, 0, 1), Eigen::Vector3d(1, 1, 1), 0.5));
  try {
    sim.Reset(world, Eigen::Vector3d(0.6, 0.0, 1.0), 0.0, Eigen::Vector3d(9, 9, 9));
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find(
                  "start pose (0.600, 0.000, 1.000) puts the vehicle box inside world box 1"),
              std::string::npos)
        << e.what();
  }
  // Just outside: the yawed box reaches x = 0.5 (cos 0.5 + sin 0.5) = 0.678 < 0.9 - 0.125.
  EXPECT_NO_THROW(sim.Reset(world, Eigen::Vector3d(0.9, 0.0, 1.0), 0.0, Eigen::Vector3d(9, 9, 9)));
}

TEST(Reset, StartBelowTheGroundOrNonFiniteIsAClearError) {
  Simulator sim(quad_sim_test::DefaultSimConfig());
  try {
    sim.Reset(World(), Eigen::Vector3d(0, 0, 0.1), 0.0, Eigen::Vector3d(9, 9, 9));
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("below the ground"), std::string::npos) << e.what();
  }
  EXPECT_THROW(sim.Reset(World(), Eigen::Vector3d(0, kNaN, 1), 0.0, Eigen::Vector3d(9, 9, 9)),
               std::invalid_argument);
}

TEST(Reset, EpisodeIdsAreTheGivenKeyedOnesOrUnkeyedOnesFromTheirOwnBase) {
  Simulator sim(quad_sim_test::DefaultSimConfig());
  const Eigen::Vector3d start(0, 0, 1), goal(9, 9, 9);
  sim.Reset(World(), start, 0.0, goal);  // unkeyed: never equal to a keyed id (index + 1)
  EXPECT_EQ(sim.episode().episode_id, quad_core::kUnkeyedEpisodeIdBase);
  sim.Reset(World(), start, 0.0, goal, quad_core::EpisodeIdOf(4));
  EXPECT_EQ(sim.episode().episode_id, 5u);
  EXPECT_TRUE(sim.episode().active);
  sim.Reset(World(), start, 0.0, goal, quad_core::EpisodeIdOf(0));  // the id is the caller's, in any order
  EXPECT_EQ(sim.episode().episode_id, 1u);
  // A refused reset uses no id; the unkeyed count goes on after keyed episodes.
  EXPECT_THROW(sim.Reset(World(), Eigen::Vector3d(0, 0, kNaN), 0.0, goal), std::invalid_argument);
  sim.Reset(World(), start, 0.0, goal);
  EXPECT_EQ(sim.episode().episode_id, quad_core::kUnkeyedEpisodeIdBase + 1);
}

// A keyed episode's flight does not depend on what the simulator flew before it: the same world, start and
// commands after a long previous episode give bit-identical states and depth to a fresh simulator's.
TEST(Reset, AnEpisodeFlownAfterAnotherEqualsTheSameEpisodeOfAFreshSimulator) {
  const quad_sim::SimConfig c = quad_sim_test::DefaultSimConfig();
  const World world = quad_sim::GenerateWorld(c.world_gen, 7);
  const auto fly = [](Simulator* sim, double thrust_scale, int steps) {
    quad_sim::So3Command cmd;
    cmd.force_world_N = Eigen::Vector3d(0.2, -0.1, thrust_scale * sim->config().vehicle.HoverThrustN());
    cmd.enable_motors = true;
    for (int i = 0; i < steps; ++i) {
      if (sim->OdometryDue()) ASSERT_TRUE(sim->SetSo3Command(cmd).ok());
      sim->Step();
    }
  };
  Simulator used(c), fresh(c);
  used.Reset(world, c.start_m, 0.3, c.goal_m, quad_core::EpisodeIdOf(0));
  fly(&used, 1.3, 1500);
  used.Reset(world, c.start_m, c.start_yaw_rad, c.goal_m, quad_core::EpisodeIdOf(1));
  fresh.Reset(world, c.start_m, c.start_yaw_rad, c.goal_m, quad_core::EpisodeIdOf(1));
  fly(&used, 1.1, 800);
  fly(&fresh, 1.1, 800);
  EXPECT_TRUE(SameState(used.state(), fresh.state()));
  EXPECT_EQ(used.step_count(), fresh.step_count());
  EXPECT_EQ(used.episode().episode_id, fresh.episode().episode_id);
  const quad_core::DepthImage a = used.RenderDepth(), b = fresh.RenderDepth();
  ASSERT_EQ(a.depth_m.size(), b.depth_m.size());
  EXPECT_EQ(std::memcmp(a.depth_m.data(), b.depth_m.data(), a.depth_m.size() * sizeof(float)), 0);
}

TEST(Schedule, OdometryAt200HzAndDepthAt30Hz) {
  Simulator sim(quad_sim_test::DefaultSimConfig());
  sim.Reset(World(), Eigen::Vector3d(0, 0, 0.125), 0.0, Eigen::Vector3d(9, 9, 9));
  int odom = 0, depth = 0;
  std::vector<uint64_t> depth_steps;
  while (sim.step_count() < 3000) {
    odom += sim.OdometryDue();
    if (sim.DepthDue()) {
      ++depth;
      depth_steps.push_back(sim.step_count());
    }
    sim.Step();
  }
  EXPECT_EQ(odom, 600);
  EXPECT_EQ(depth, 90);
  // Frame k at the first step at or after k / 30 s.
  for (size_t k = 0; k < depth_steps.size(); ++k) {
    EXPECT_EQ(depth_steps[k], static_cast<uint64_t>(std::ceil(k * 1000.0 / 30.0 - 1e-9))) << k;
  }
}

TEST(Episode, ReachingTheGoalEndsTheEpisode) {
  Simulator sim(quad_sim_test::DefaultSimConfig());
  sim.Reset(World(), Eigen::Vector3d(0, 0, 2), 0.0, Eigen::Vector3d(0, 0, 3.0));
  const quad_sim::So3Command up = Climb(sim.config().vehicle);
  while (sim.time_s() < 3.0 && sim.episode().active) {
    if (sim.OdometryDue()) sim.SetSo3Command(up);
    sim.Step();
  }
  EXPECT_TRUE(sim.episode().reached_goal);
  EXPECT_EQ(sim.episode().outcome, quad_sim::EpisodeOutcome::kReachedGoal);
  EXPECT_LE((sim.state().p_world_body - Eigen::Vector3d(0, 0, 3)).norm(),
            sim.config().episode.goal_tolerance_m);
  EXPECT_GT((sim.state().p_world_body - Eigen::Vector3d(0, 0, 3)).norm(),
            sim.config().episode.goal_tolerance_m - 0.01);
}

TEST(Episode, MaxDurationEndsTheEpisode) {
  quad_sim::SimConfig cfg = quad_sim_test::DefaultSimConfig();
  cfg.episode.max_duration_s = 0.5;
  Simulator sim(cfg);
  sim.Reset(World(), Eigen::Vector3d(0, 0, 0.125), 0.0, Eigen::Vector3d(9, 9, 9));
  while (sim.episode().active) sim.Step();
  EXPECT_EQ(sim.episode().outcome, quad_sim::EpisodeOutcome::kTimedOut);
  EXPECT_EQ(sim.step_count(), 500u);
}

TEST(Clearance, EqualsBruteForceOverAllBoxes) {
  const quad_sim::SimConfig cfg = quad_sim_test::DefaultSimConfig();
  Simulator sim(cfg);
  const World world = quad_sim::GenerateWorld(cfg.world_gen, 21);
  sim.Reset(world, cfg.start_m, 0.0, cfg.goal_m);
  std::mt19937_64 rng(2);
  std::uniform_real_distribution<double> u(-1, 1);
  for (int k = 0; k < 300; ++k) {
    OrientedBox v;
    v.center_world_m = Eigen::Vector3d(19 * u(rng), 19 * u(rng), 2.5 + 2.5 * u(rng));
    v.q_world_box = quad_sim::QuatFromRpy(0.5 * u(rng), 0.5 * u(rng), 3 * u(rng));
    v.size_m = cfg.vehicle.collision_box_m;
    double brute = kInf;
    int id = -1;
    for (size_t i = 0; i < world.boxes.size(); ++i) {
      const double d = quad_sim::BoxBoxDistance(v, world.boxes[i]);
      if (d < brute) {
        brute = d;
        id = static_cast<int>(i);
      }
    }
    const quad_sim::ClearanceResult c = sim.Clearance(v);
    ASSERT_EQ(c.distance_m, brute);
    if (brute > 0) {
      ASSERT_EQ(c.box_index, id);
    }
  }
  // At the start pose: the clear zone guarantees more than clear_radius minus the vehicle's half diagonal.
  EXPECT_GT(sim.ClearanceToObstacles(), cfg.world_gen.clear_radius_m - 0.25);
}

TEST(Determinism, SameSeedAndCommandsGiveBitIdenticalStatesAndDepth) {
  quad_sim::SimConfig cfg = quad_sim_test::DefaultSimConfig();
  cfg.camera.intrinsics = quad_sim::DepthCameraConfig::FastPlannerFov(160, 120);
  cfg.camera.noise_std_at_1m_m = 0.001;  // the noise stream must be reproducible too
  auto run = [&cfg](std::vector<float>* depth_log, std::vector<double>* state_log) {
    Simulator sim(cfg);
    sim.ResetDefault(7);
    const quad_sim::So3Command up = Climb(cfg.vehicle);
    while (sim.time_s() < 1.0) {
      if (sim.OdometryDue()) {
        sim.SetSo3Command(up);
        const auto& s = sim.state();
        state_log->insert(state_log->end(), s.p_world_body.data(), s.p_world_body.data() + 3);
        state_log->insert(state_log->end(), s.q_world_body.coeffs().data(),
                          s.q_world_body.coeffs().data() + 4);
      }
      if (sim.DepthDue()) {
        const quad_core::DepthImage img = sim.RenderDepth();
        depth_log->insert(depth_log->end(), img.depth_m.begin(), img.depth_m.end());
      }
      sim.Step();
    }
  };
  std::vector<float> d1, d2;
  std::vector<double> s1, s2;
  run(&d1, &s1);
  run(&d2, &s2);
  ASSERT_EQ(d1.size(), d2.size());
  ASSERT_EQ(s1.size(), s2.size());
  EXPECT_EQ(0, std::memcmp(d1.data(), d2.data(), d1.size() * sizeof(float)));
  EXPECT_EQ(0, std::memcmp(s1.data(), s2.data(), s1.size() * sizeof(double)));
  EXPECT_EQ(s1.size(), 200u * 7u);
}

TEST(SpawnFrame, ZOffsetIsMeasuredFromTheEngineGroundQuery) {
  quad_sim::SimConfig cfg = quad_sim_test::DefaultSimConfig();
  cfg.spawn_frame.origin_world_m = Eigen::Vector3d(1.0, -2.0, 1.7);
  cfg.spawn_frame.units_per_m = 100.0;  // centimetres, as Unreal
  Simulator sim(cfg);
  sim.Reset(World(), Eigen::Vector3d(3.0, 4.0, 0.125), 0.0, Eigen::Vector3d(9, 9, 9));
  // The engine reports the ground 170 cm below its origin, and the vehicle in centimetres from the origin.
  EXPECT_NEAR(sim.GroundHeightInSpawnFrame(), -170.0, 1e-9);
  EXPECT_TRUE(sim.VehiclePositionInSpawnFrame().isApprox(Eigen::Vector3d(200.0, 600.0, -157.5)));
  const quad_sim::SpawnFrame& f = sim.spawn_frame();
  EXPECT_TRUE(f.FromSpawn(f.ToSpawn(Eigen::Vector3d(1, 2, 3))).isApprox(Eigen::Vector3d(1, 2, 3)));
}
