// The plan-to-record conversion and the embedded collector (issue 6), without ROS: a record built from a
// known plan has the expected fields, and what the collector writes reads back the same.
#include <cpp_data_collector/dataset_reader.h>
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "fast_planner/plan_collector.h"

namespace fast_planner {
namespace {

namespace fs = std::filesystem;

// A plan as the manager hands it to its observer: a cubic trajectory through 5 known control points, its
// depth frame (4x3) and odometry (with a quaternion that is not normalised).
struct KnownPlan {
  PlanResult result;
  std::shared_ptr<DepthFrame> depth = std::make_shared<DepthFrame>();
  PlanRecord record;

  KnownPlan() {
    Eigen::MatrixXd cp(5, 3);
    cp << 0, 0, 1, 1, 0, 1, 2, 0.5, 1.2, 3, 1, 1.4, 4, 1, 1.5;
    result.status = PlanStatus::kSuccess;
    result.reason = "success";
    result.traj_id = 7;
    result.start_time_s = 12.25;
    result.search_status = SearchStatus::kReachedHorizon;
    result.spline = quad_core::NonUniformBspline::Uniform(cp, 3, 0.5);
    result.timings.frontend_ms = 1.5;
    result.timings.optimization_ms = 2.5;
    result.timings.total_ms = 4.5;
    depth->stamp_s = 12.2;
    depth->seq = 9;
    depth->intrinsics = quad_core::CameraIntrinsics{4, 3, 3.0, 3.0, 1.5, 1.0};
    depth->image = quad_core::DepthImage{4, 3, {1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12}};
    quad_core::VehicleState odom;
    odom.t_s = 12.195;
    odom.p_world_body = Eigen::Vector3d(0.1, 0.2, 1.0);
    odom.v_world = Eigen::Vector3d(1.0, 0.5, 0.0);
    odom.q_world_body = Eigen::Quaterniond(2.0, 0.0, 0.0, 2.0);  // norm 2*sqrt(2): normalised in the record
    odom.w_body = Eigen::Vector3d(0.0, 0.0, 0.3);
    record.depth = depth;
    record.odometry = odom;
    record.goal = Eigen::Vector3d(10.0, 1.0, 1.5);
    record.request.start_time_s = 12.2;
    record.result = &result;
  }
};

TEST(FillPlanRecord, ARecordOfAKnownPlanHasTheExpectedFields) {
  const KnownPlan p;
  cpp_data_collector::PlanRecord r;
  FillPlanRecord(p.record, RecordContext{3, 1234, 0.75}, &r);
  EXPECT_EQ(r.episode_id, 3);
  EXPECT_EQ(r.world_seed, 1234u);
  EXPECT_EQ(r.sim_time_s, 12.2);                           // the request's start time: when the plan was made
  EXPECT_EQ(r.depth.data, p.depth->image.depth_m.data());  // the frame's own pixels, not a copy
  EXPECT_EQ(r.depth.width, 4);
  EXPECT_EQ(r.depth.height, 3);
  EXPECT_EQ(r.depth.row_stride, 4u);
  EXPECT_EQ(r.depth_stamp_s, 12.2);
  EXPECT_EQ(r.odom.stamp_s, 12.195);
  EXPECT_EQ(r.odom.p_world_body, (std::array<double, 3>{0.1, 0.2, 1.0}));
  EXPECT_EQ(r.odom.v_world, (std::array<double, 3>{1.0, 0.5, 0.0}));
  EXPECT_NEAR(r.odom.q_world_body[2], std::sqrt(0.5), 1e-15);  // (x, y, z, w), normalised
  EXPECT_NEAR(r.odom.q_world_body[3], std::sqrt(0.5), 1e-15);
  EXPECT_EQ(r.odom.q_world_body[0], 0.0);
  EXPECT_EQ(r.odom.w_body, (std::array<double, 3>{0.0, 0.0, 0.3}));
  EXPECT_EQ(r.goal_world, (std::array<double, 3>{10.0, 1.0, 1.5}));
  EXPECT_EQ(r.bspline.order, 3);
  EXPECT_EQ(r.bspline.traj_id, 7);
  EXPECT_EQ(r.bspline.start_time_s, 12.25);
  EXPECT_EQ(r.bspline.knots, p.result.spline->knots());
  ASSERT_EQ(r.bspline.ctrl_pts_world.size(), 5u);
  EXPECT_EQ(r.bspline.ctrl_pts_world[2], (std::array<double, 3>{2.0, 0.5, 1.2}));
  EXPECT_TRUE(r.bspline.yaw_pts.empty());
  EXPECT_EQ(r.bspline.yaw_dt_s, 0.0);
  EXPECT_EQ(r.status.code, static_cast<int32_t>(SearchStatus::kReachedHorizon));
  EXPECT_EQ(r.status.text, "success");
  EXPECT_EQ(r.timings.map_update_ms, 0.75);
  EXPECT_EQ(r.timings.frontend_ms, 1.5);
  EXPECT_EQ(r.timings.optimization_ms, 2.5);
  EXPECT_EQ(r.timings.total_ms, 4.5);
}

TEST(FillPlanRecord, APlanWithoutItsInputsIsRefused) {
  KnownPlan p;
  p.record.odometry.reset();
  cpp_data_collector::PlanRecord r;
  EXPECT_THROW(FillPlanRecord(p.record, RecordContext{}, &r), std::invalid_argument);
}

class PlanCollectorTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("fast_planner_collector_" + std::to_string(::testing::UnitTest::GetInstance()->random_seed()) +
            "_" + ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
};

TEST_F(PlanCollectorTest, WhatItRecordsReadsBackAsThePlan) {
  std::vector<std::string> warnings;
  PlanCollector c(COLLECTOR_CONFIG_PATH, dir_.string(), "abc123", {{"launch", "test"}},
                  cpp_data_collector::OpenMode::kCreate,
                  [&](CollectorWarning, const std::string& text) { warnings.push_back(text); });
  KnownPlan p;
  c.OnPlan(p.record);  // before camera_info: counted, not recorded
  EXPECT_EQ(c.not_recorded(), 1u);
  ASSERT_EQ(warnings.size(), 1u);
  EXPECT_NE(warnings[0].find("no camera_info yet"), std::string::npos) << warnings[0];
  EXPECT_NE(c.Start(p.depth->intrinsics).find(dir_.string()), std::string::npos);
  EXPECT_EQ(c.Start(p.depth->intrinsics), "");  // once only
  c.SetEpisode(2, 55);
  c.SetMapUpdateMs(0.5);
  c.OnPlan(p.record);
  const PlanCollector::Finalized f = c.Finalize();
  ASSERT_TRUE(f.ok) << f.text;
  EXPECT_NE(f.text.find("written 1"), std::string::npos) << f.text;

  const cpp_data_collector::DatasetReader reader(dir_.string());
  ASSERT_EQ(reader.num_records(), 1u);
  const cpp_data_collector::DecodedRecord d = reader.shards().at(0).Decode(0);
  EXPECT_EQ(d.head.episode_id, 2);
  EXPECT_EQ(d.head.world_seed, 55u);
  EXPECT_EQ(d.head.depth_stamp_s, 12.2);
  EXPECT_EQ(d.head.odom_stamp_s, 12.195);
  EXPECT_EQ(d.head.bspline_traj_id, 7);
  EXPECT_EQ(d.head.t_map_update_ms, 0.5);
  EXPECT_EQ(d.knots, p.result.spline->knots());
  ASSERT_EQ(d.ctrl_pts_world.size(), 5u);
  EXPECT_EQ(d.ctrl_pts_world[4], (std::array<double, 3>{4.0, 1.0, 1.5}));
  EXPECT_EQ(d.width, 4u);
  EXPECT_EQ(d.height, 3u);
  const std::vector<float> depth = d.DepthMetres();
  ASSERT_EQ(depth.size(), 12u);
  EXPECT_NEAR(depth[11], 12.0f, 0.01f);
  EXPECT_EQ(d.plan_status_text(), "success");
}

// The planner node hears sim/status on its own connection: a goal and a depth frame can arrive first, and the
// plan made from them must be recorded with the episode the status then names, not with "unknown" (-1).
TEST_F(PlanCollectorTest, APlanMadeBeforeTheEpisodeIsKnownIsWrittenWithThatEpisode) {
  std::vector<std::string> warnings;
  PlanCollector c(COLLECTOR_CONFIG_PATH, dir_.string(), "", {}, cpp_data_collector::OpenMode::kCreate,
                  [&](CollectorWarning, const std::string& text) { warnings.push_back(text); });
  KnownPlan p;
  c.Start(p.depth->intrinsics);
  c.SetMapUpdateMs(0.25);
  c.OnPlan(p.record);
  EXPECT_EQ(c.held(), 1u);
  EXPECT_EQ(c.not_recorded(), 0u);
  ASSERT_EQ(warnings.size(), 1u);
  EXPECT_NE(warnings[0].find("held until the episode is known"), std::string::npos) << warnings[0];
  p.result.traj_id = 8;  // a later plan of the same frame (the held record must not follow the observer's)
  c.SetMapUpdateMs(0.5);
  c.SetEpisode(1, 77);
  EXPECT_EQ(c.held(), 0u);
  c.OnPlan(p.record);
  const PlanCollector::Finalized f = c.Finalize();
  ASSERT_TRUE(f.ok) << f.text;
  EXPECT_NE(f.text.find("written 2"), std::string::npos) << f.text;

  const cpp_data_collector::DatasetReader reader(dir_.string());
  ASSERT_EQ(reader.num_records(), 2u);
  const cpp_data_collector::DecodedRecord held = reader.shards().at(0).Decode(0);
  const cpp_data_collector::DecodedRecord later = reader.shards().at(0).Decode(1);
  EXPECT_EQ(held.head.episode_id, 1);
  EXPECT_EQ(held.head.world_seed, 77u);
  EXPECT_EQ(held.head.bspline_traj_id, 7);
  EXPECT_EQ(held.head.t_map_update_ms, 0.25);  // the context of when it was made
  const std::vector<float> depth = held.DepthMetres();
  ASSERT_EQ(depth.size(), 12u);
  EXPECT_NEAR(depth[11], 12.0f, 0.01f);
  EXPECT_EQ(later.head.episode_id, 1);
  EXPECT_EQ(later.head.bspline_traj_id, 8);
  EXPECT_EQ(later.head.t_map_update_ms, 0.5);
}

// Without any episode (no simulator publishing sim/status) nothing unkeyed is written: a bounded number of
// plans is held, the rest counted as not recorded, and Finalize says why none of them was written.
TEST_F(PlanCollectorTest, PlansWhoseEpisodeIsNeverKnownAreNotWrittenAndSaySo) {
  std::vector<std::string> warnings;
  PlanCollector c(COLLECTOR_CONFIG_PATH, dir_.string(), "", {}, cpp_data_collector::OpenMode::kCreate,
                  [&](CollectorWarning, const std::string& text) { warnings.push_back(text); });
  const KnownPlan p;
  c.Start(p.depth->intrinsics);
  for (size_t i = 0; i < PlanCollector::kMaxHeldPlans + 3; ++i) c.OnPlan(p.record);
  EXPECT_EQ(c.held(), PlanCollector::kMaxHeldPlans);
  EXPECT_EQ(c.not_recorded(), 3u);
  EXPECT_NE(warnings.back().find("no episode yet"), std::string::npos) << warnings.back();
  const PlanCollector::Finalized f = c.Finalize();
  ASSERT_TRUE(f.ok) << f.text;
  EXPECT_NE(f.text.find(std::to_string(PlanCollector::kMaxHeldPlans) +
                        " plan(s) not recorded: the episode was never known"),
            std::string::npos)
      << f.text;
  EXPECT_EQ(c.not_recorded(), PlanCollector::kMaxHeldPlans + 3);
  EXPECT_EQ(cpp_data_collector::DatasetReader(dir_.string()).num_records(), 0u);
}

TEST_F(PlanCollectorTest, ADirectoryHoldingADatasetIsRefusedAtOnce) {
  {
    PlanCollector c(COLLECTOR_CONFIG_PATH, dir_.string(), "", {}, cpp_data_collector::OpenMode::kCreate,
                    nullptr);
    c.Start(quad_core::CameraIntrinsics{4, 3, 3.0, 3.0, 1.5, 1.0});
    ASSERT_TRUE(c.Finalize().ok);
  }
  try {
    PlanCollector c(COLLECTOR_CONFIG_PATH, dir_.string(), "", {}, cpp_data_collector::OpenMode::kCreate,
                    nullptr);
    FAIL() << "expected the existing dataset to be refused";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("already holds a dataset"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace fast_planner
