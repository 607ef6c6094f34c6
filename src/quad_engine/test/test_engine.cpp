// The rollout engine without ROS: the collection's episode logic, the run codec, the wire conversions and the
// keyed property of a worker's episodes (the same key gives the same records whatever was flown before).
#include <gtest/gtest.h>

#include <quad_core/episode_key.h>
#include <quad_core/wire.h>

#include <cmath>
#include <string>

#include "quad_engine/expert_worker.h"
#include "quad_engine/run_codec.h"

namespace quad_engine {
namespace {

const std::string kConfig = QUAD_IL_CONFIG_DIR;

EpisodeSpec Spec() {
  EpisodeSpec s;
  s.index = 3;
  s.seed = 7;
  s.start_world = Eigen::Vector3d(1.0, 2.0, 1.5);
  s.start_yaw_rad = 0.3;
  s.goal_world = Eigen::Vector3d(15.0, 2.0, 1.5);
  return s;
}

StatusView Running() { return StatusView{false, false, true, "running"}; }

TEST(EpisodeDirector, TakesOffThenGivesTheGoalWithinTolerance) {
  EpisodeLimits limits;
  EpisodeDirector d(Spec(), limits, 1001.0);
  EXPECT_EQ(d.OnFrame(1001.0, Eigen::Vector3d(1, 2, 0.125), 0.0, Running(), 0),
            EpisodeDirector::Action::kGoto);
  d.OnGotoAnswer("");
  // Too far, then too fast, then within tolerance and slow enough.
  EXPECT_EQ(d.OnFrame(1002.0, Eigen::Vector3d(1, 2, 1.0), 0.0, Running(), 0),
            EpisodeDirector::Action::kContinue);
  EXPECT_EQ(d.OnFrame(1003.0, Eigen::Vector3d(1, 2, 1.45), 0.5, Running(), 0),
            EpisodeDirector::Action::kContinue);
  EXPECT_EQ(d.OnFrame(1004.0, Eigen::Vector3d(1, 2, 1.45), 0.1, Running(), 0),
            EpisodeDirector::Action::kGiveGoal);
  d.OnGoalAnswer("");
  EXPECT_FALSE(d.done());
  EXPECT_EQ(d.t_goal_s(), 1004.0);
  StatusView reached{true, false, false, "goal reached"};
  EXPECT_EQ(d.OnFrame(1010.5, Eigen::Vector3d(15, 2, 1.5), 0.0, reached, 12), EpisodeDirector::Action::kEnd);
  EXPECT_EQ(d.outcome(), "goal_reached");
  EXPECT_EQ(d.reason(), "goal reached");
  EXPECT_DOUBLE_EQ(d.duration_s(), 6.5);
}

TEST(EpisodeDirector, EndsOnCollisionTimeoutsAndMaxSamples) {
  EpisodeLimits limits;
  limits.takeoff_timeout_s = 2.0;
  limits.episode_timeout_s = 5.0;
  {
    EpisodeDirector d(Spec(), limits, 1001.0);
    d.OnFrame(1001.0, Eigen::Vector3d::Zero(), 0.0, Running(), 0);
    EXPECT_EQ(d.OnFrame(1003.0, Eigen::Vector3d::Zero(), 0.0, Running(), 0),
              EpisodeDirector::Action::kContinue);
    EXPECT_EQ(d.OnFrame(1003.01, Eigen::Vector3d::Zero(), 0.0, Running(), 0), EpisodeDirector::Action::kEnd);
    EXPECT_EQ(d.outcome(), "timeout");
    EXPECT_EQ(d.reason(), "take-off did not reach its altitude");
  }
  auto flying = [&](EpisodeLimits l) {
    auto d = std::make_unique<EpisodeDirector>(Spec(), l, 1001.0);
    d->OnFrame(1001.0, Eigen::Vector3d::Zero(), 0.0, Running(), 0);
    d->OnFrame(1002.0, Spec().start_world, 0.0, Running(), 0);
    return d;
  };
  {
    auto d = flying(limits);
    EXPECT_EQ(d->OnFrame(1003.0, Eigen::Vector3d::Zero(), 1.0,
                         StatusView{false, true, false, "collision with box 4"}, 3),
              EpisodeDirector::Action::kEnd);
    EXPECT_EQ(d->outcome(), "collision");
    EXPECT_EQ(d->reason(), "collision with box 4");
  }
  {
    auto d = flying(limits);
    EXPECT_EQ(d->OnFrame(1007.0, Eigen::Vector3d::Zero(), 1.0, Running(), 3),
              EpisodeDirector::Action::kContinue);
    EXPECT_EQ(d->OnFrame(1007.1, Eigen::Vector3d::Zero(), 1.0, Running(), 3), EpisodeDirector::Action::kEnd);
    EXPECT_EQ(d->reason(), "no goal within 5 s");
  }
  {
    EpisodeLimits l = limits;
    l.max_samples = 10;
    l.samples_before = 7;
    auto d = flying(l);
    EXPECT_EQ(d->OnFrame(1003.0, Eigen::Vector3d::Zero(), 1.0, Running(), 2),
              EpisodeDirector::Action::kContinue);
    EXPECT_EQ(d->OnFrame(1003.1, Eigen::Vector3d::Zero(), 1.0, Running(), 3), EpisodeDirector::Action::kEnd);
    EXPECT_EQ(d->outcome(), "stopped");
    EXPECT_EQ(d->reason(), "10 samples recorded (max_samples=10)");
  }
  {
    auto d = flying(limits);
    d->OnGoalAnswer("goal inside an obstacle");
    EXPECT_TRUE(d->done());
    EXPECT_EQ(d->outcome(), "goal_rejected");
    EXPECT_EQ(d->reason(), "goal rejected: goal inside an obstacle");
  }
}

TEST(Wire, TrajectoryStartTimeIsRoundedToNanoseconds) {
  EXPECT_EQ(quad_core::RosTimeRoundTrip(1001.0000000004), quad_core::StampSeconds(1001000000000ULL));
  EXPECT_EQ(quad_core::RosTimeRoundTrip(1001.0000000006), quad_core::StampSeconds(1001000000001ULL));
  const quad_core::VehicleState s = [] {
    quad_core::VehicleState v;
    v.q_world_body = Eigen::Quaterniond(Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitZ()));
    v.w_body = Eigen::Vector3d(1.0, 0.0, 0.0);
    v.has_accel = true;
    return v;
  }();
  const quad_core::VehicleState r = quad_core::OdometryAsReceived(s, 1001005000000ULL);
  EXPECT_NEAR(r.w_body.y(), 1.0, 1e-12);  // world axes, as the simulator publishes it
  EXPECT_FALSE(r.has_accel);
  EXPECT_EQ(r.t_s, quad_core::StampSeconds(1001005000000ULL));
}

TEST(Wire, ZeroGainsKeepTheSimulatorsDefaults) {
  kr_tracker::So3Command c;
  c.force_world_N = Eigen::Vector3d(0, 0, 9.0);
  const quad_sim::So3Command keep = ToSimCommand(c);
  EXPECT_EQ(keep.kR, quad_sim::So3Command().kR);
  c.kR = Eigen::Vector3d(2, 2, 2);
  EXPECT_EQ(ToSimCommand(c).kR, Eigen::Vector3d(2, 2, 2));
  EXPECT_EQ(ToSimCommand(c).kOm, Eigen::Vector3d::Zero());
}

Configs TestConfigs() {
  return LoadConfigs(ConfigPaths{kConfig + "/sim.yaml", kConfig + "/planner.yaml", kConfig + "/tracker.yaml",
                                 kConfig + "/vehicle.yaml"});
}

EpisodeSpec ShortEpisode(int64_t index, uint64_t seed) {
  EpisodeSpec s;
  s.index = index;
  s.seed = seed;
  s.start_world = Eigen::Vector3d(-6.0, 0.5, 1.5);
  s.start_yaw_rad = 0.0;
  s.goal_world = Eigen::Vector3d(4.0, 0.5, 1.5);
  return s;
}

void ExpectSameRecords(const EpisodeRun& a, const EpisodeRun& b) {
  ASSERT_EQ(a.records.size(), b.records.size());
  EXPECT_EQ(a.outcome, b.outcome);
  EXPECT_EQ(a.steps, b.steps);
  for (size_t i = 0; i < a.records.size(); ++i) {
    const auto& x = a.records[i].record;
    const auto& y = b.records[i].record;
    EXPECT_EQ(x.sim_time_s, y.sim_time_s) << i;
    EXPECT_EQ(x.episode_id, y.episode_id) << i;
    EXPECT_EQ(x.bspline.traj_id, y.bspline.traj_id) << i;
    EXPECT_EQ(x.bspline.knots, y.bspline.knots) << i;
    EXPECT_EQ(x.bspline.ctrl_pts_world, y.bspline.ctrl_pts_world) << i;
    EXPECT_EQ(x.odom.p_world_body, y.odom.p_world_body) << i;
    ASSERT_EQ(x.depth.width * x.depth.height, y.depth.width * y.depth.height);
    for (int r = 0; r < x.depth.height; ++r)
      for (int c = 0; c < x.depth.width; ++c) ASSERT_EQ(x.depth.at(r, c), y.depth.at(r, c));
  }
}

TEST(ExpertWorker, AnEpisodesRecordsDependOnItsKeyOnly) {
  const Configs cfg = TestConfigs();
  EpisodeLimits limits;
  limits.episode_timeout_s = 20.0;
  ExpertWorker fresh(cfg);
  const EpisodeRun alone = fresh.Run(ShortEpisode(1, 11), limits);
  ASSERT_EQ(alone.outcome, "goal_reached") << alone.reason;
  ASSERT_GT(alone.records.size(), 3u);
  EXPECT_EQ(alone.records[0].record.episode_id, quad_core::EpisodeIdOf(1));
  EXPECT_GE(alone.records[0].record.sim_time_s, quad_core::StampSeconds(quad_core::EpisodeStartNs(1)));

  ExpertWorker used(cfg);
  used.Run(ShortEpisode(0, 12), limits);
  const EpisodeRun after = used.Run(ShortEpisode(1, 11), limits);
  ExpectSameRecords(alone, after);

  // The codec carries every record bit for bit.
  const EpisodeRun decoded = DecodeRun(EncodeRun(alone));
  ExpectSameRecords(alone, decoded);
  EXPECT_EQ(decoded.outcome, alone.outcome);
  EXPECT_EQ(decoded.spec.goal_world, alone.spec.goal_world);
}

TEST(ExpertWorker, ThePrivilegedExpertRendersOnlyRecordedFramesAndRecordsTheSame) {
  Configs cfg = TestConfigs();
  cfg.planner.map.source = fast_planner::MapSource::kGlobal;
  EpisodeLimits limits;
  limits.episode_timeout_s = 20.0;
  ExpertWorker lazy(cfg);
  ASSERT_TRUE(lazy.lazy_depth());
  ExpertWorker every(cfg);
  every.set_lazy_depth(false);
  const EpisodeRun a = lazy.Run(ShortEpisode(2, 13), limits);
  const EpisodeRun b = every.Run(ShortEpisode(2, 13), limits);
  ASSERT_EQ(a.outcome, "goal_reached") << a.reason;
  ASSERT_GT(a.records.size(), 2u);
  ExpectSameRecords(a, b);                // depth pixels included
  EXPECT_GT(a.frames, a.records.size());  // most frames were never rendered
}

TEST(RunCodec, RefusesBytesThatAreNotARun) {
  try {
    DecodeRun("nonsense");
    FAIL() << "decoded nonsense";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("not an encoded episode run"), std::string::npos) << e.what();
  }
  EpisodeRun r;
  r.outcome = "timeout";
  std::string bytes = EncodeRun(r);
  bytes.pop_back();
  EXPECT_THROW(DecodeRun(bytes), std::invalid_argument);
}

TEST(ExpertWorker, ARefusedResetIsTheOutcomeResetFailed) {
  ExpertWorker w(TestConfigs());
  EpisodeSpec s = ShortEpisode(0, 5);
  s.start_world = Eigen::Vector3d(std::nan(""), 0.0, 1.0);
  const EpisodeRun r = w.Run(s, EpisodeLimits{});
  EXPECT_EQ(r.outcome, "reset_failed");
  EXPECT_NE(r.reason.find("reset rejected"), std::string::npos) << r.reason;
}

}  // namespace
}  // namespace quad_engine
