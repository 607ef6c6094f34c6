// Sim time and the time modes (quad_sim/time_keeper.h), the reset request's resolution
// (quad_sim/episode_request.h) and the published odometry (Simulator::Odometry), without ROS.
#include "quad_sim/episode_request.h"
#include "quad_sim/simulator.h"
#include "quad_sim/time_keeper.h"
#include "test_util.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <optional>
#include <stdexcept>
#include <string>

namespace quad_sim {
namespace {

using quad_sim_test::DefaultSimConfig;

SimConfig WithMode(TimeMode mode, double factor = 1.0) {
  SimConfig c = DefaultSimConfig();
  c.physics_dt_s = 0.001;
  c.odometry_rate_hz = 200.0;
  c.time.mode = mode;
  c.time.real_time_factor = factor;
  c.time.clock_period_s = 0.004;
  return c;
}

TEST(TimeKeeper, SimTimeStartsAtOneSecondAndAdvancesOnlyByStepsAndEpisodes) {
  TimeKeeper t(WithMode(TimeMode::kLockstep), 0.0);
  EXPECT_EQ(t.now_ns(), 1000000000ULL);
  for (int i = 0; i < 7; ++i) t.Stepped();
  EXPECT_EQ(t.now_ns(), 1007000000ULL);
  t.NewEpisode();  // one odometry period (5 steps) later, so no stamp repeats
  EXPECT_EQ(t.now_ns(), 1012000000ULL);
  EXPECT_EQ(t.total_steps(), 12u);
  EXPECT_DOUBLE_EQ(t.sim_s(), 0.012);
}

TEST(TimeKeeper, AKeyedEpisodeStartsAtItsKeysTimeWhateverWasFlownBefore) {
  TimeKeeper straight(WithMode(TimeMode::kLockstep), 0.0);
  TimeKeeper resumed(WithMode(TimeMode::kLockstep), 0.0);
  for (int i = 0; i < 4321; ++i) straight.Stepped();  // an episode flown before
  straight.NewEpisode();
  EpisodeRequest r;
  r.keyed = true;
  r.episode_index = 1;
  EXPECT_EQ(straight.BeginEpisode(r), std::optional<uint32_t>(2u));
  EXPECT_EQ(resumed.BeginEpisode(r), std::optional<uint32_t>(2u));
  EXPECT_EQ(straight.now_ns(), 2001000000000ULL);  // 1 s + (1 + 1) * 1000 s
  EXPECT_EQ(straight.now_ns(), quad_core::EpisodeStartNs(1));
  EXPECT_EQ(straight.total_steps(), resumed.total_steps());
  EXPECT_EQ(straight.sim_s(), resumed.sim_s());
  // The clock schedule continues from the start's step count, the same in both.
  EXPECT_EQ(straight.ClockDue(false, false), resumed.ClockDue(false, false));
  straight.Stepped();
  EXPECT_EQ(straight.now_ns(), 2001001000000ULL);
}

TEST(TimeKeeper, AnUnkeyedEpisodeStartsOneOdometryPeriodLaterWithTheSimulatorsNextId) {
  TimeKeeper t(WithMode(TimeMode::kLockstep), 0.0);
  EXPECT_EQ(t.BeginEpisode(EpisodeRequest()), std::nullopt);
  EXPECT_EQ(t.now_ns(), 1005000000ULL);
}

TEST(TimeKeeper, AKeyedStartNotAfterTheCurrentTimeIsRefusedWithTheReasonAndChangesNothing) {
  TimeKeeper t(WithMode(TimeMode::kLockstep), 0.0);
  EpisodeRequest r;
  r.keyed = true;
  r.episode_index = 3;
  ASSERT_TRUE(t.BeginEpisode(r));
  for (int i = 0; i < 1500; ++i) t.Stepped();
  const uint64_t before = t.now_ns();
  for (uint32_t index : {3u, 2u, 0u}) {
    r.episode_index = index;
    try {
      t.BeginEpisode(r);
      FAIL() << "keyed episode " << index << " after episode 3 was accepted";
    } catch (const std::invalid_argument& e) {
      const std::string want = "keyed episode " + std::to_string(index) + " starts at " +
                               std::to_string(1 + (index + 1) * 1000) + ".000 s, not after the current sim " +
                               "time 4002.500 s (an episode longer than the 1000 s spacing";
      EXPECT_NE(std::string(e.what()).find(want), std::string::npos) << e.what();
    }
    EXPECT_EQ(t.now_ns(), before);
  }
  EXPECT_THROW(t.StartEpisodeAt(before), std::invalid_argument);  // equal is not after
  r.episode_index = 4;
  EXPECT_EQ(t.BeginEpisode(r), std::optional<uint32_t>(5u));
}

TEST(TimeKeeper, AKeyedIndexOutOfRangeOrAStartBetweenStepsIsRefused) {
  TimeKeeper t(WithMode(TimeMode::kLockstep), 0.0);
  EpisodeRequest r;
  r.keyed = true;
  r.episode_index = quad_core::kMaxEpisodeIndex + 1;
  try {
    t.BeginEpisode(r);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_EQ(std::string(e.what()), "episode index 4000001 outside [0, 4000000]");
  }
  EXPECT_EQ(t.now_ns(), 1000000000ULL);
  try {
    t.StartEpisodeAt(2000000500ULL);  // half a physics step
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("2000000500 ns is not a whole number of physics steps (1000000 ns)"),
              std::string::npos)
        << e.what();
  }
  t.StartEpisodeAt(2000000000ULL);
  EXPECT_EQ(t.now_ns(), 2000000000ULL);
}

TEST(TimeKeeper, ClockIsDueEveryClockPeriodAndAtEveryFrame) {
  TimeKeeper t(WithMode(TimeMode::kAsFastAsPossible), 0.0);
  std::vector<uint64_t> due;
  for (int i = 0; i < 10; ++i) {
    if (t.ClockDue(false, false)) due.push_back(t.total_steps());
    t.Stepped();
  }
  EXPECT_EQ(due, (std::vector<uint64_t>{0, 4, 8}));
  EXPECT_TRUE(t.ClockDue(true, false));  // step 10: an odometry time
  EXPECT_TRUE(t.ClockDue(false, true));  // a depth frame time
  EXPECT_FALSE(t.ClockDue(false, false));
}

TEST(TimeKeeper, OnlyLockstepWaitsForTheGate) {
  SimConfig c = WithMode(TimeMode::kLockstep);
  c.lockstep.wait_for_command = true;
  c.lockstep.depth_consumers = {"fast_planner"};
  EXPECT_TRUE(TimeKeeper(c, 0.0).WaitsForCommand());
  EXPECT_TRUE(TimeKeeper(c, 0.0).WaitsForFrames());
  c.time.mode = TimeMode::kRealTime;
  EXPECT_FALSE(TimeKeeper(c, 0.0).WaitsForCommand());
  EXPECT_FALSE(TimeKeeper(c, 0.0).WaitsForFrames());
  c.time.mode = TimeMode::kLockstep;
  c.lockstep.wait_for_command = false;
  c.lockstep.depth_consumers.clear();
  EXPECT_FALSE(TimeKeeper(c, 0.0).WaitsForCommand());
  EXPECT_FALSE(TimeKeeper(c, 0.0).WaitsForFrames());
}

TEST(TimeKeeper, RealTimePacesEachStepToTheWallClock) {
  TimeKeeper t(WithMode(TimeMode::kRealTime), 0.0);
  t.Anchor(100.0);
  for (int i = 0; i < 250; ++i) t.Stepped();  // 0.25 s of sim time
  const std::optional<double> until = t.PaceUntil(100.1);
  ASSERT_TRUE(until.has_value());
  EXPECT_NEAR(*until, 100.25, 1e-9);
  EXPECT_FALSE(t.PaceUntil(100.3).has_value());  // behind by less than a second: catch up, no sleep
}

TEST(TimeKeeper, FactorRunsSimTimeFasterThanWallTime) {
  TimeKeeper t(WithMode(TimeMode::kRealTimeFactor, 4.0), 0.0);
  t.Anchor(10.0);
  for (int i = 0; i < 1000; ++i) t.Stepped();  // 1 s of sim time = 0.25 s of wall time
  const std::optional<double> until = t.PaceUntil(10.0);
  ASSERT_TRUE(until.has_value());
  EXPECT_NEAR(*until, 10.25, 1e-9);
}

TEST(TimeKeeper, FallingMoreThanASecondBehindReanchorsInsteadOfRacing) {
  TimeKeeper t(WithMode(TimeMode::kRealTime), 0.0);
  t.Anchor(0.0);
  for (int i = 0; i < 100; ++i) t.Stepped();
  EXPECT_FALSE(t.PaceUntil(5.0).has_value());  // 4.9 s behind (a slow reset): re-anchored at 5.0
  t.Stepped();
  const std::optional<double> until = t.PaceUntil(5.0);
  ASSERT_TRUE(until.has_value());
  EXPECT_NEAR(*until, 5.001, 1e-9);
}

TEST(TimeKeeper, UnpacedModesNeverSleep) {
  for (TimeMode m : {TimeMode::kAsFastAsPossible, TimeMode::kLockstep}) {
    TimeKeeper t(WithMode(m), 0.0);
    t.Anchor(0.0);
    for (int i = 0; i < 1000; ++i) t.Stepped();
    EXPECT_FALSE(t.PaceUntil(0.0).has_value()) << ToString(m);
  }
}

TEST(TimeKeeper, StatisticsAreDueEverySecondWithTheRealTimeFactorSinceTheLast) {
  TimeKeeper t(WithMode(TimeMode::kAsFastAsPossible), 50.0);
  EXPECT_FALSE(t.StatsDue(50.5));
  EXPECT_TRUE(t.StatsDue(51.0));
  for (int i = 0; i < 3000; ++i) t.Stepped();
  EXPECT_NEAR(t.RealTimeFactor(51.0), 3.0, 1e-9);
  t.MarkStats(51.0);
  for (int i = 0; i < 500; ++i) t.Stepped();
  EXPECT_NEAR(t.RealTimeFactor(52.0), 0.5, 1e-9);
  EXPECT_FALSE(t.StatsDue(51.9));
}

TEST(TimeKeeper, RefusesANonPositivePeriodNamingIt) {
  SimConfig c = WithMode(TimeMode::kRealTime);
  c.time.clock_period_s = 0.0;
  try {
    TimeKeeper t(c, 0.0);
    FAIL() << "accepted clock_period_s 0";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("time.clock_period_s"), std::string::npos) << e.what();
  }
}

TEST(EpisodeRequest, ZeroOrientationSelectsTheConfiguredStartAndGoal) {
  const SimConfig c = DefaultSimConfig();
  EpisodeRequest r;
  r.seed = 7;
  r.start_world_m = Eigen::Vector3d(1, 2, 3);  // ignored without an orientation
  const EpisodeSetup e = ResolveEpisode(c, r);
  EXPECT_TRUE(e.start_world_m.isApprox(c.start_m));
  EXPECT_TRUE(e.goal_world_m.isApprox(c.goal_m));
  EXPECT_EQ(e.start_yaw_rad, c.start_yaw_rad);
  EXPECT_EQ(e.world.seed, 7u);
}

TEST(EpisodeRequest, AGivenPoseSetsStartYawAndGoalAndKeepsThemClear) {
  const SimConfig c = DefaultSimConfig();
  EpisodeRequest r;
  r.seed = 9;
  r.start_world_m = Eigen::Vector3d(-5.0, 3.0, 0.125);
  const Eigen::Quaterniond q(Eigen::AngleAxisd(0.7, Eigen::Vector3d::UnitZ()));
  r.q_start_wxyz = Eigen::Vector4d(q.w(), q.x(), q.y(), q.z()) * 2.0;  // not normalised: still a pose
  r.goal_world_m = Eigen::Vector3d(5.0, 3.0, 1.5);
  const EpisodeSetup e = ResolveEpisode(c, r);
  EXPECT_TRUE(e.start_world_m.isApprox(r.start_world_m));
  EXPECT_NEAR(e.start_yaw_rad, 0.7, 1e-12);
  EXPECT_TRUE(e.goal_world_m.isApprox(r.goal_world_m));
  // The episode's own start is kept clear (not the configured one): the vehicle can start there.
  Simulator sim(c);
  ASSERT_NO_THROW(sim.Reset(e.world, e.start_world_m, e.start_yaw_rad, e.goal_world_m));
  EXPECT_GT(sim.ClearanceToObstacles(), 0.5);
  EXPECT_NEAR(sim.state().q_world_body.normalized().toRotationMatrix().eulerAngles(2, 1, 0)[0], 0.7, 1e-9);
}

TEST(EpisodeRequest, NonFiniteOrientationIsRefused) {
  EpisodeRequest r;
  r.q_start_wxyz = Eigen::Vector4d(std::numeric_limits<double>::quiet_NaN(), 0, 0, 1);
  try {
    ResolveEpisode(DefaultSimConfig(), r);
    FAIL() << "accepted a NaN start orientation";
  } catch (const std::invalid_argument& e) {
    EXPECT_STREQ(e.what(), "start orientation is not finite");
  }
}

TEST(Odometry, IsTheDynamicsStateWithThePositionThroughTheSpawnFrame) {
  SimConfig c = DefaultSimConfig();
  c.spawn_frame.origin_world_m = Eigen::Vector3d(0.0, 0.0, 1.7);
  c.spawn_frame.units_per_m = 100.0;
  Simulator sim(c);
  sim.ResetDefault(3);
  const double z_offset_m = sim.MeasureZOffset();
  EXPECT_NEAR(z_offset_m, 1.7, 1e-12);
  const quad_core::VehicleState o = sim.Odometry(z_offset_m, 2.5);
  EXPECT_EQ(o.t_s, 2.5);
  EXPECT_NEAR((o.p_world_body - sim.state().p_world_body).norm(), 0.0, 1e-12);
  EXPECT_TRUE(o.q_world_body.coeffs().isApprox(sim.state().q_world_body.coeffs()));
  EXPECT_EQ(o.v_world, sim.state().v_world);
  EXPECT_EQ(o.w_body, sim.state().w_body);
  EXPECT_FALSE(o.has_accel);
  // A wrong calibration shows in every position.
  EXPECT_NEAR(sim.Odometry(z_offset_m + 0.5, 2.5).p_world_body.z() - o.p_world_body.z(), 0.5, 1e-12);
}

}  // namespace
}  // namespace quad_sim
