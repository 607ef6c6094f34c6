// The expert in closed loop with the simulator core (ROS-free): a short flight through a seeded world, and
// the observer hook (issue 6's data collector) receiving the exact inputs and output of every plan.
#include <gtest/gtest.h>
#include <kr_tracker/config.h>
#include <quad_sim/sim_config.h>

#include <cmath>
#include <memory>
#include <vector>

#include "quad_bench/sim_flight.h"

namespace quad_bench {
namespace {

const std::string kRoot = QUAD_IL_ROOT;

struct Record {
  double depth_stamp_s;
  uint64_t depth_seq;
  size_t depth_pixels;
  double odom_stamp_s;
  Eigen::Vector3d odom_p;
  Eigen::Vector3d goal;
  Eigen::Vector3d request_start;
  double start_time_s;
  int64_t traj_id;
  int num_ctrl_pts;
};

class RecordingObserver : public PlanObserver {
 public:
  void OnPlan(const PlanRecord& r) override {
    ASSERT_TRUE(r.depth);
    ASSERT_TRUE(r.odometry.has_value());
    records.push_back({r.depth->stamp_s, r.depth->seq, r.depth->image.depth_m.size(), r.odometry->t_s,
                       r.odometry->p_world_body, r.goal, r.request.start_p, r.result->start_time_s,
                       r.result->traj_id, r.result->spline->num_ctrl_pts()});
  }
  std::vector<Record> records;
};

TEST(SimFlightTest, ExpertFliesThroughASeededWorldAndReportsEveryPlan) {
  const PlannerConfig planner = LoadPlannerConfig(kRoot + "/config/planner.yaml");
  const quad_sim::SimConfig sim = quad_sim::LoadSimConfig(kRoot + "/config/sim.yaml");
  const kr_tracker::TrackerConfig tracker = kr_tracker::LoadTrackerConfig(kRoot + "/config/tracker.yaml");
  FlightSetup setup;
  RandomStartGoal(sim, 7, 10.0, 1.0, 2.0, &setup.start_m, &setup.goal_m);
  setup.world = MakeWorld(sim, 7, 12.5, setup.start_m, setup.goal_m);
  setup.timeout_s = 30.0;
  auto observer = std::make_shared<RecordingObserver>();
  const FlightStats s = FlyExpert(planner, sim, tracker, setup, observer);
  EXPECT_TRUE(s.reached_goal) << s.end_reason;
  EXPECT_FALSE(s.collided) << s.end_reason;
  EXPECT_GT(s.min_clearance_m, 0.1);
  EXPECT_EQ(s.tracker_rejections, 0);
  EXPECT_NEAR(s.straight_line_m, (setup.goal_m - setup.start_m).norm(), 1e-9);
  // The episode ends within the simulator's goal tolerance (0.5 m) of the goal.
  EXPECT_GE(s.path_length_m, s.straight_line_m - sim.episode.goal_tolerance_m - 0.05);
  ASSERT_EQ(static_cast<int>(observer->records.size()), s.plans);
  ASSERT_GT(s.plans, 2);
  const double odom_period = 1.0 / sim.odometry_rate_hz;
  for (size_t i = 0; i < observer->records.size(); ++i) {
    const Record& r = observer->records[i];
    EXPECT_EQ(r.goal, setup.goal_m);
    EXPECT_EQ(r.depth_pixels,
              static_cast<size_t>(sim.camera.intrinsics.width * sim.camera.intrinsics.height));
    // Synchronised: the odometry the plan used is within one odometry period of the depth frame.
    EXPECT_LE(std::abs(r.odom_stamp_s - r.depth_stamp_s), odom_period + 1e-9) << "plan " << i;
    EXPECT_EQ(r.traj_id, static_cast<int64_t>(i) + 1);
    EXPECT_GT(r.num_ctrl_pts, 3);
    if (i > 0) {
      EXPECT_GE(r.depth_stamp_s, observer->records[i - 1].depth_stamp_s);
    }
  }
}

// The ESDF's only user is the optimiser, so computing it when a plan needs it (map.esdf_on_demand) must give
// exactly the plans of computing it after every frame: the same flight, bit for bit.
class SplineObserver : public PlanObserver {
 public:
  void OnPlan(const PlanRecord& r) override {
    splines.push_back(r.result->spline->ctrl_pts());
    knots.push_back(r.result->spline->knots());
  }
  std::vector<Eigen::MatrixXd> splines;
  std::vector<std::vector<double>> knots;
};

TEST(SimFlightTest, OnDemandEsdfGivesExactlyThePlansOfPerFrameEsdf) {
  PlannerConfig planner = LoadPlannerConfig(kRoot + "/config/planner.yaml");
  const quad_sim::SimConfig sim = quad_sim::LoadSimConfig(kRoot + "/config/sim.yaml");
  const kr_tracker::TrackerConfig tracker = kr_tracker::LoadTrackerConfig(kRoot + "/config/tracker.yaml");
  FlightSetup setup;
  RandomStartGoal(sim, 11, 10.0, 1.0, 2.0, &setup.start_m, &setup.goal_m);
  setup.world = MakeWorld(sim, 11, 15.0, setup.start_m, setup.goal_m);
  setup.timeout_s = 30.0;
  std::vector<std::shared_ptr<SplineObserver>> obs;
  std::vector<FlightStats> stats;
  for (const bool on_demand : {false, true}) {
    planner.map.esdf_on_demand = on_demand;
    obs.push_back(std::make_shared<SplineObserver>());
    stats.push_back(FlyExpert(planner, sim, tracker, setup, obs.back()));
  }
  EXPECT_TRUE(stats[1].reached_goal) << stats[1].end_reason;
  ASSERT_GT(obs[0]->splines.size(), 2u);
  ASSERT_EQ(obs[0]->splines.size(), obs[1]->splines.size());
  for (size_t i = 0; i < obs[0]->splines.size(); ++i) {
    EXPECT_TRUE(obs[0]->splines[i] == obs[1]->splines[i]) << "plan " << i;
    EXPECT_EQ(obs[0]->knots[i], obs[1]->knots[i]) << "plan " << i;
  }
  EXPECT_EQ(stats[0].flight_time_s, stats[1].flight_time_s);
  // On demand no ESDF is computed after a frame, per frame after every one; the plans carry it as map
  // preparation instead. (Structural, not timed: the machines are shared.)
  ASSERT_FALSE(stats[1].map_esdf_computed.empty());
  for (const bool computed : stats[1].map_esdf_computed) EXPECT_FALSE(computed);
  size_t per_frame = 0;
  for (const bool computed : stats[0].map_esdf_computed) per_frame += computed ? 1 : 0;
  EXPECT_EQ(per_frame, stats[0].map_esdf_computed.size());
  double prep = 0.0;
  for (const auto& t : stats[1].plan_timings) prep += t.map_prep_ms;
  EXPECT_GT(prep, 0.0);
}

TEST(SimFlightTest, StartGoalPairsAreSeededAndTheRequestedDistanceApart) {
  const quad_sim::SimConfig sim = quad_sim::LoadSimConfig(kRoot + "/config/sim.yaml");
  Eigen::Vector3d a0, b0, a1, b1, a2, b2;
  RandomStartGoal(sim, 3, 30.0, 1.0, 2.0, &a0, &b0);
  RandomStartGoal(sim, 3, 30.0, 1.0, 2.0, &a1, &b1);
  RandomStartGoal(sim, 4, 30.0, 1.0, 2.0, &a2, &b2);
  EXPECT_EQ(a0, a1);
  EXPECT_EQ(b0, b1);
  EXPECT_NE(a0, a2);
  EXPECT_NEAR((b0.head<2>() - a0.head<2>()).norm(), 30.0, 1e-9);
  for (const auto& p : {a0, b0, a2, b2}) {
    EXPECT_GE(p.z(), 1.0);
    EXPECT_LE(p.z(), 2.0);
    EXPECT_LE(p.head<2>().cwiseAbs().maxCoeff(), 18.0 + 1e-9);  // 2 m inside the +-20 m generator bounds
  }
}

}  // namespace
}  // namespace quad_bench
