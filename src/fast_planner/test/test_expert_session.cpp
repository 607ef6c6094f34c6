// The expert as fast_planner_node drives it, without ROS: labeller mode end to end (the label starts from the
// paired odometry and the collector records exactly that odometry), flight mode's odometry, episode resets.
#include <cpp_data_collector/dataset_reader.h>
#include <gtest/gtest.h>

#include <filesystem>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "fast_planner/expert_session.h"
#include "test_util.h"

namespace fast_planner {
namespace {

namespace fs = std::filesystem;

constexpr double kPeriodS = 0.005;

PlannerConfig DepthConfig() {
  PlannerConfig c;
  c.map = test::SmallMapConfig(Eigen::Vector3d(20.0, 10.0, 4.0), 0.1, 0.3, 0.0, 4.0);
  c.map.source = MapSource::kDepth;
  c.map.local_update_range_m = Eigen::Vector3d(8.0, 8.0, 2.0);
  return c;
}

// Hovering at (2, 5, 1.5), stamped i * 5 ms.
quad_core::VehicleState Hover(int i) {
  quad_core::VehicleState s;
  s.t_s = i * kPeriodS;
  s.p_world_body = Eigen::Vector3d(2.0, 5.0, 1.5);
  return s;
}

// An empty view (no return within range) stamped at odometry step i, its pose still unset.
std::shared_ptr<DepthFrame> Frame(int i) {
  auto f = std::make_shared<DepthFrame>(
      test::ConstantDepthFrame(std::numeric_limits<float>::infinity(), Eigen::Vector3d::Zero()));
  f->stamp_s = i * kPeriodS;
  return f;
}

const CameraMount kMount{Eigen::Vector3d(0.1, 0.0, 0.0), test::CameraLookingAlongX()};

TEST(ExpertSession, LabellerPlansFromThePairedOdometryAndRecordsIt) {
  const fs::path dir = fs::temp_directory_path() / "fast_planner_expert_session_labeller";
  fs::remove_all(dir);
  ExpertSession s(DepthConfig(), /*label_every_frame=*/true);
  auto collector = std::make_shared<PlanCollector>(COLLECTOR_CONFIG_PATH, dir.string(), "",
                                                   std::vector<std::pair<std::string, std::string>>{},
                                                   cpp_data_collector::OpenMode::kCreate, nullptr);
  s.SetCollector(collector);
  collector->Start(Frame(0)->intrinsics);
  collector->SetEpisode(3, 77);  // as the node does from sim/status (a plan before it would be held)
  for (int i = 890; i <= 899; ++i) {
    const ReplannerOutput out = s.OnOdometry(Hover(i));
    EXPECT_TRUE(out.transitions.empty() && !out.trajectory);  // the labeller never flies
  }
  EXPECT_FALSE(s.FrameCovered(900 * kPeriodS));  // the frame's own period has not arrived
  s.OnOdometry(Hover(900));
  EXPECT_TRUE(s.FrameCovered(900 * kPeriodS));

  auto frame = Frame(900);
  ASSERT_TRUE(s.SetCameraPose(kMount, frame.get()));
  EXPECT_NEAR((frame->p_world_camera - Eigen::Vector3d(2.1, 5.0, 1.5)).norm(), 0.0, 1e-12);
  EXPECT_FALSE(s.OnDepth(frame).label.has_value());  // no goal yet: the node answers with an empty B-spline

  ReplannerOutput goal_out;
  ASSERT_EQ(s.SetGoal(Eigen::Vector3d(6.0, 5.0, 1.5), 0.0, &goal_out), "");
  EXPECT_FALSE(goal_out.trajectory.has_value());
  s.OnOdometry(Hover(901));  // newer than the frame: never paired with it
  const ExpertSession::FrameOutput out = s.OnDepth(frame);
  ASSERT_TRUE(out.label.has_value());
  ASSERT_TRUE(out.label->ok()) << out.label->reason;
  EXPECT_EQ(out.label->start_time_s, frame->stamp_s);
  EXPECT_NEAR(
      (out.label->spline->Evaluate(out.label->spline->tmin()).head<3>() - Eigen::Vector3d(2.0, 5.0, 1.5))
          .norm(),
      0.0, 1e-6);
  EXPECT_EQ(s.last_map_update_ms(), out.map_update.total_ms);
  ASSERT_TRUE(collector->Finalize().ok);

  const cpp_data_collector::DatasetReader reader(dir.string());
  ASSERT_EQ(reader.num_records(), 1u);
  const cpp_data_collector::DecodedRecord d = reader.shards().at(0).Decode(0);
  EXPECT_EQ(d.head.odom_stamp_s, 900 * kPeriodS);  // the paired odometry, not the newest (901)
  EXPECT_EQ(d.head.depth_stamp_s, frame->stamp_s);
  EXPECT_EQ(d.head.sim_time_s, frame->stamp_s);
  EXPECT_EQ(d.head.t_map_update_ms, out.map_update.total_ms);  // this frame's map update
  EXPECT_EQ(d.head.bspline_traj_id, out.label->traj_id);
  EXPECT_EQ(d.head.episode_id, 3);
  EXPECT_EQ(d.head.world_seed, 77u);
  fs::remove_all(dir);
}

TEST(ExpertSession, AFrameWithoutOdometryBeforeItHasNoPose) {
  ExpertSession s(DepthConfig(), true);
  s.OnOdometry(Hover(901));
  auto frame = Frame(900);
  EXPECT_FALSE(s.SetCameraPose(kMount, frame.get()));
}

TEST(ExpertSession, FlightModeStepsTheReplannerAndMalformedInputChangesNothing) {
  ExpertSession s(DepthConfig(), /*label_every_frame=*/false);
  const ReplannerOutput first = s.OnOdometry(Hover(1));
  ASSERT_FALSE(first.transitions.empty());  // the state machine leaves idle on the first odometry
  quad_core::VehicleState bad = Hover(2);
  bad.v_world.x() = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(s.OnOdometry(bad), std::invalid_argument);
  EXPECT_EQ(s.odometry().samples().size(), 1u);
  auto frame = Frame(1);
  frame->image.depth_m.pop_back();
  EXPECT_THROW(s.OnDepth(frame), std::invalid_argument);
  EXPECT_EQ(s.replanner().manager().last_depth(), nullptr);
}

TEST(ExpertSession, ANewEpisodeKeepsOnlyItsOwnEarlyOdometry) {
  ExpertSession s(DepthConfig(), /*label_every_frame=*/false);
  for (int i = 880; i <= 900; ++i) s.OnOdometry(Hover(i));
  const auto replay = s.StartEpisode(890 * kPeriodS);
  ASSERT_EQ(replay.size(), 11u);  // stamps 890..900
  EXPECT_EQ(replay.front().first, 890 * kPeriodS);
  EXPECT_FALSE(replay.front().second.transitions.empty());  // the reset replanner left idle again
  EXPECT_EQ(s.odometry().samples().size(), 11u);
  EXPECT_EQ(s.odometry().samples().front().t_s, 890 * kPeriodS);
}

TEST(ExpertSession, ANewEpisodeForgetsTheLabellersGoal) {
  ExpertSession s(DepthConfig(), true);
  s.OnOdometry(Hover(1));
  ReplannerOutput out;
  ASSERT_EQ(s.SetGoal(Eigen::Vector3d(6.0, 5.0, 1.5), 0.0, &out), "");
  EXPECT_TRUE(s.labeller().goal().has_value());
  EXPECT_TRUE(s.StartEpisode(1.0).empty());
  EXPECT_FALSE(s.labeller().goal().has_value());
  EXPECT_TRUE(s.odometry().empty());
}

// Everything a session decided, in order: transitions, plans (traj_id, start, knots, control points).
struct Trace {
  std::vector<std::string> transitions;
  std::vector<int64_t> traj_ids;
  std::vector<double> start_times_s;
  std::vector<std::vector<double>> knots;
  std::vector<Eigen::MatrixXd> ctrl_pts;
  void Add(const ReplannerOutput& out) {
    transitions.insert(transitions.end(), out.transitions.begin(), out.transitions.end());
    if (!out.trajectory) return;
    traj_ids.push_back(out.trajectory->traj_id);
    start_times_s.push_back(out.trajectory->start_time_s);
    if (out.trajectory->spline) {
      knots.push_back(out.trajectory->spline->knots());
      ctrl_pts.push_back(out.trajectory->spline->ctrl_pts());
    }
  }
};

// One episode in flight mode: hovering at p, a box ahead, the goal given at the 10th odometry, a depth frame
// (rendered exactly) every 6th odometry, `steps` odometry periods from t0_s.
Trace FlyEpisode(ExpertSession* s, double t0_s, const Eigen::Vector3d& p, const test::Aabb& box,
                 const Eigen::Vector3d& goal, int steps) {
  Trace trace;
  for (int i = 0; i < steps; ++i) {
    quad_core::VehicleState o;
    o.t_s = t0_s + i * kPeriodS;
    o.p_world_body = p;
    trace.Add(s->OnOdometry(o));
    if (i == 10) {
      ReplannerOutput out;
      EXPECT_EQ(s->SetGoal(goal, o.t_s, &out), "");
      trace.Add(out);
    }
    if (i % 6 == 0) {
      auto frame = std::make_shared<DepthFrame>(
          test::RenderDepth({box}, p + kMount.p_body_camera, test::CameraLookingAlongX(), 80, 60));
      frame->stamp_s = o.t_s;
      EXPECT_TRUE(s->SetCameraPose(kMount, frame.get()));
      trace.Add(s->OnDepth(frame).flight);
    }
  }
  return trace;
}

// Keyed episodes (issue 32): collect.launch keeps the planner across episodes, so an episode's plans must not
// depend on the episodes flown before it. A session that flew an episode and then starts a new one plans it
// exactly as a fresh session does (the fresh node's first status only names the episode: no StartEpisode):
// the same transitions, traj_ids, knots and control points, compared bit for bit.
TEST(ExpertSession, ANewEpisodeIsPlannedBitIdenticallyToAFreshSessionsFirstEpisode) {
  ExpertSession used(DepthConfig(), false), fresh(DepthConfig(), false);
  const Trace before = FlyEpisode(&used, 1.0, Eigen::Vector3d(3.0, 2.0, 1.0),
                                  test::Aabb{Eigen::Vector3d(6, 0, 0), Eigen::Vector3d(7, 4, 3)},
                                  Eigen::Vector3d(12.0, 8.0, 2.0), 240);
  ASSERT_FALSE(before.traj_ids.empty());  // the previous episode planned (and counted traj_ids)
  const double t0 = 2001.0;
  EXPECT_TRUE(used.StartEpisode(t0).empty());
  const Eigen::Vector3d p(2.0, 5.0, 1.5), goal(15.0, 5.0, 1.5);
  const test::Aabb box{Eigen::Vector3d(6, 3.5, 0), Eigen::Vector3d(7, 6.5, 3)};
  const Trace a = FlyEpisode(&used, t0, p, box, goal, 240);
  const Trace b = FlyEpisode(&fresh, t0, p, box, goal, 240);
  ASSERT_GE(a.traj_ids.size(), 2u);
  EXPECT_EQ(a.traj_ids.front(), 1);
  EXPECT_EQ(a.transitions, b.transitions);
  EXPECT_EQ(a.traj_ids, b.traj_ids);
  EXPECT_EQ(a.start_times_s, b.start_times_s);
  EXPECT_EQ(a.knots, b.knots);
  ASSERT_EQ(a.ctrl_pts.size(), b.ctrl_pts.size());
  for (size_t i = 0; i < a.ctrl_pts.size(); ++i) {
    EXPECT_TRUE(a.ctrl_pts[i].rows() == b.ctrl_pts[i].rows() && a.ctrl_pts[i] == b.ctrl_pts[i])
        << "plan " << i;
  }
}

}  // namespace
}  // namespace fast_planner
