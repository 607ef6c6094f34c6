#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "fast_planner/replanner.h"
#include "test_util.h"

namespace fast_planner {
namespace {

Eigen::Vector3d V3(const Eigen::VectorXd& v) { return Eigen::Vector3d(v[0], v[1], v[2]); }

double DistanceToBox(const Eigen::Vector3d& p, const test::Aabb& b) {
  return (p - p.cwiseMax(b.lo).cwiseMin(b.hi)).norm();
}

// A perfectly tracking vehicle: its odometry is the current trajectory's state; a 30 Hz depth camera looks
// along its direction of travel. Runs until the goal is reached, the goal is abandoned or the time runs out.
struct FlightLog {
  bool reached = false;
  std::optional<std::string> abandoned;
  std::vector<std::string> transitions;
  int plans = 0;
  std::vector<double> goal_reaching_plan_distances;  // distance to the goal at each plan that reaches it
  double min_box_distance = std::numeric_limits<double>::infinity();
  double duration_s = 0.0;
};

FlightLog Fly(Replanner* rp, const std::vector<test::Aabb>& world, const Eigen::Vector3d& start,
              const Eigen::Vector3d& goal, double max_time_s, bool render_depth = true) {
  FlightLog log;
  quad_core::VehicleState odom;
  auto collect = [&](const ReplannerOutput& out) {
    log.transitions.insert(log.transitions.end(), out.transitions.begin(), out.transitions.end());
    if (out.trajectory && out.trajectory->reason != "emergency stop") {
      ++log.plans;
      if (out.trajectory->reaches_goal)
        log.goal_reaching_plan_distances.push_back((odom.p_world_body - goal).norm());
    }
    if (out.abandoned) log.abandoned = out.abandoned;
  };
  odom.p_world_body = start;
  double yaw = std::atan2(goal.y() - start.y(), goal.x() - start.x());
  collect(rp->OnOdometry(odom));
  ReplannerOutput out;
  EXPECT_EQ(rp->SetGoal(goal, 0.0, &out), "");
  collect(out);
  for (int k = 1; k <= static_cast<int>(max_time_s * 30); ++k) {
    const double t = k / 30.0;
    if (rp->current()) {
      const auto& s = *rp->current()->spline;
      const double tt = std::clamp(t - rp->current()->start_time_s, s.tmin(), s.tmax());
      odom.p_world_body = V3(s.Evaluate(tt));
      odom.v_world = V3(s.Derivative().Evaluate(tt));
      if (odom.v_world.head<2>().norm() > 0.2) yaw = std::atan2(odom.v_world.y(), odom.v_world.x());
    }
    odom.t_s = t;
    collect(rp->OnOdometry(odom));
    for (const auto& b : world)
      log.min_box_distance = std::min(log.min_box_distance, DistanceToBox(odom.p_world_body, b));
    std::shared_ptr<DepthFrame> frame;
    if (render_depth) {
      frame =
          std::make_shared<DepthFrame>(test::RenderDepth(world, odom.p_world_body, test::CameraWithYaw(yaw)));
    } else {
      frame = std::make_shared<DepthFrame>(
          test::ConstantDepthFrame(std::numeric_limits<float>::infinity(), odom.p_world_body, 8, 6));
    }
    frame->stamp_s = t;
    collect(rp->OnDepth(frame));
    log.duration_s = t;
    if (rp->state().mode == FsmMode::kGoalReached) {
      log.reached = true;
      break;
    }
    if (log.abandoned) break;
  }
  return log;
}

bool Contains(const std::vector<std::string>& v, const std::string& fragment) {
  return std::any_of(v.begin(), v.end(),
                     [&](const std::string& s) { return s.find(fragment) != std::string::npos; });
}

PlannerConfig DepthConfig() {
  PlannerConfig c;
  c.map = test::SmallMapConfig(Eigen::Vector3d(30.0, 12.0, 4.0), 0.1, 0.3, 0.0, 4.0);
  c.map.local_update_range_m = PlannerConfig().map.local_update_range_m;
  c.map.depth.skip_pixel = 2;
  return c;
}

TEST(ReplannerTest, DepthFlightDiscoversAWallOnTheWayAndDetoursToTheGoal) {
  Replanner rp(DepthConfig());
  const std::vector<test::Aabb> world = {{{12.0, 2.0, 0.0}, {12.4, 10.0, 4.0}}};
  const FlightLog log =
      Fly(&rp, world, Eigen::Vector3d(2.0, 6.0, 1.5), Eigen::Vector3d(22.0, 6.0, 1.5), 40.0);
  ASSERT_TRUE(log.reached) << (log.abandoned ? *log.abandoned : "timeout") << " after " << log.duration_s
                           << " s";
  EXPECT_GE(log.min_box_distance, 0.3);
  EXPECT_GT(log.plans, 5);
  EXPECT_TRUE(Contains(log.transitions, "executing + replan distance travelled -> replanning"));
  EXPECT_TRUE(Contains(log.transitions, "executing + goal reached -> goal reached"));
  EXPECT_FALSE(rp.state().has_goal);
}

// Fast-Planner flies the trajectory to the goal without replanning, so a dataset of its plans has none for
// the final approach; fsm.replan_final_approach keeps the plans coming every replan_distance_m down to that
// distance from the goal.
TEST(ReplannerTest, FinalApproachIsReplannedOnlyWhenConfigured) {
  const Eigen::Vector3d start(2.0, 6.0, 1.5), goal(14.0, 6.0, 1.5);
  for (const bool replan : {false, true}) {
    SCOPED_TRACE(replan ? "replan_final_approach" : "fast-planner");
    PlannerConfig cfg = DepthConfig();
    cfg.fsm.replan_final_approach = replan;
    Replanner rp(cfg);
    const FlightLog log = Fly(&rp, {}, start, goal, 30.0);
    ASSERT_TRUE(log.reached) << (log.abandoned ? *log.abandoned : "timeout");
    const auto& d = log.goal_reaching_plan_distances;
    ASSERT_FALSE(d.empty());
    // The goal comes into reach when the search horizon plus the final shot cover it (here ~9 m away).
    EXPECT_LE(d.front(), cfg.search.horizon_m + cfg.search.shot_radius_m + 0.5);
    if (!replan) {
      EXPECT_EQ(d.size(), 1u);
    } else {
      // About one plan per metre of the final approach, the last one between 1 and 2 m from the goal.
      EXPECT_GE(d.size(), static_cast<size_t>(d.front() - 2.0));
      EXPECT_GT(d.back(), cfg.fsm.replan_distance_m);
      EXPECT_LT(d.back(), 2.0 * cfg.fsm.replan_distance_m + 0.1);
      for (size_t i = 1; i < d.size(); ++i) EXPECT_LT(d[i], d[i - 1]);
    }
  }
}

TEST(ReplannerTest, GoalsInObstaclesOrOutsideTheMapAreRejectedAndChangeNothing) {
  PlannerConfig c = DepthConfig();
  c.map.source = MapSource::kGlobal;
  Replanner rp(c);
  std::vector<Eigen::Vector3d> pts;
  for (double x = 5.05; x < 6.0; x += 0.1) pts.emplace_back(x, 5.05, 1.55);
  rp.manager().SetGlobalMap(pts);
  quad_core::VehicleState odom;
  odom.p_world_body = Eigen::Vector3d(2.0, 5.0, 1.5);
  rp.OnOdometry(odom);
  ASSERT_EQ(rp.state().mode, FsmMode::kWaitGoal);
  ReplannerOutput out;
  EXPECT_EQ(rp.SetGoal(Eigen::Vector3d(5.55, 5.05, 1.55), 0.0, &out),
            "goal is inside an obstacle (or at/below the ground or at/above the ceiling)");
  EXPECT_NE(rp.SetGoal(Eigen::Vector3d(45.0, 5.0, 1.5), 0.0, &out).find("outside the map"),
            std::string::npos);
  EXPECT_EQ(rp.SetGoal(Eigen::Vector3d(5.0, 5.0, 0.1), 0.0, &out),
            "goal is within 0.3 m of an obstacle (or the ground/ceiling)");
  EXPECT_EQ(rp.state().mode, FsmMode::kWaitGoal);
  EXPECT_FALSE(rp.goal().has_value());
  EXPECT_TRUE(out.transitions.empty());
  EXPECT_FALSE(out.trajectory.has_value());
}

TEST(ReplannerTest, NonFiniteOdometryIsRejectedAndLeavesTheStateAlone) {
  Replanner rp(DepthConfig());
  quad_core::VehicleState odom;
  odom.p_world_body = Eigen::Vector3d(2.0, 5.0, std::numeric_limits<double>::quiet_NaN());
  EXPECT_THROW(rp.OnOdometry(odom), std::invalid_argument);
  EXPECT_EQ(rp.state().mode, FsmMode::kIdle);
  odom.p_world_body.z() = 1.5;
  rp.OnOdometry(odom);
  EXPECT_EQ(rp.state().mode, FsmMode::kWaitGoal);
}

TEST(ReplannerTest, GoalEnclosedMidFlightStopsTheVehicleThenAbandonsTheGoalWithTheReason) {
  PlannerConfig c = DepthConfig();
  c.map.source = MapSource::kGlobal;
  c.search.max_nodes = 1500;
  c.fsm.max_consecutive_failures = 3;
  Replanner rp(c);
  rp.manager().SetGlobalMap({});
  quad_core::VehicleState odom;
  odom.p_world_body = Eigen::Vector3d(2.0, 6.0, 1.5);
  rp.OnOdometry(odom);
  ReplannerOutput out;
  ASSERT_EQ(rp.SetGoal(Eigen::Vector3d(14.0, 6.0, 1.5), 0.0, &out), "");
  ASSERT_TRUE(out.trajectory.has_value());
  ASSERT_TRUE(out.trajectory->reaches_goal);
  // After 1 s of flight, walls appear all around the goal (and across the trajectory).
  std::vector<test::Aabb> walls = {
      {{12.0, 4.0, 0.5}, {16.0, 4.2, 3.0}}, {{12.0, 7.8, 0.5}, {16.0, 8.0, 3.0}},
      {{12.0, 4.0, 0.5}, {12.2, 8.0, 3.0}}, {{15.8, 4.0, 0.5}, {16.0, 8.0, 3.0}},
      {{12.0, 4.0, 0.5}, {16.0, 8.0, 0.7}}, {{12.0, 4.0, 2.8}, {16.0, 8.0, 3.0}}};
  std::vector<Eigen::Vector3d> pts;
  for (const auto& w : walls) {
    for (double x = w.lo.x() + 0.05; x < w.hi.x(); x += 0.1) {
      for (double y = w.lo.y() + 0.05; y < w.hi.y(); y += 0.1) {
        for (double z = w.lo.z() + 0.05; z < w.hi.z(); z += 0.1) pts.emplace_back(x, y, z);
      }
    }
  }
  std::vector<std::string> transitions;
  std::optional<std::string> abandoned;
  bool stop_sent = false;
  for (int k = 1; k <= 30 * 20 && !abandoned; ++k) {
    const double t = k / 30.0;
    if (k == 30) rp.manager().SetGlobalMap(pts);
    const auto& s = *rp.current()->spline;
    const double tt = std::clamp(t - rp.current()->start_time_s, s.tmin(), s.tmax());
    odom.p_world_body = V3(s.Evaluate(tt));
    odom.v_world = V3(s.Derivative().Evaluate(tt));
    odom.t_s = t;
    rp.OnOdometry(odom);
    const ReplannerOutput o = rp.Step(t);
    transitions.insert(transitions.end(), o.transitions.begin(), o.transitions.end());
    if (o.trajectory && o.trajectory->reason == "emergency stop") stop_sent = true;
    if (o.abandoned) abandoned = o.abandoned;
  }
  EXPECT_TRUE(stop_sent);
  EXPECT_TRUE(Contains(transitions, "executing + trajectory collides -> replanning: plan from trajectory"));
  EXPECT_TRUE(Contains(transitions, "replanning + plan failed -> emergency stop: emergency stop"));
  EXPECT_TRUE(Contains(transitions, "emergency stop + vehicle stopped -> planning: plan from odometry"));
  EXPECT_TRUE(Contains(transitions, "planning + plan failed -> waiting for goal: abandon goal"));
  ASSERT_TRUE(abandoned.has_value());
  EXPECT_EQ(abandoned->rfind("front end failed:", 0), 0u) << *abandoned;
  EXPECT_EQ(rp.state().mode, FsmMode::kWaitGoal);
  EXPECT_FALSE(rp.goal().has_value());
}

TEST(ReplannerTest, GlobalSourcePlansTheWholeRouteAtOnce) {
  PlannerConfig c = DepthConfig();
  c.map.source = MapSource::kGlobal;
  c.search.max_nodes =
      200000;  // detours around two 8 m walls: a large search for one plan of the whole route
  Replanner rp(c);
  const std::vector<test::Aabb> world = {{{8.0, 0.0, 0.0}, {8.4, 8.0, 4.0}},
                                         {{16.0, 4.0, 0.0}, {16.4, 12.0, 4.0}}};
  std::vector<Eigen::Vector3d> pts;
  for (const auto& w : world) {
    for (double x = w.lo.x() + 0.05; x < w.hi.x(); x += 0.1) {
      for (double y = w.lo.y() + 0.05; y < w.hi.y(); y += 0.1) {
        for (double z = w.lo.z() + 0.05; z < w.hi.z(); z += 0.1) pts.emplace_back(x, y, z);
      }
    }
  }
  rp.manager().SetGlobalMap(pts);
  const FlightLog log =
      Fly(&rp, world, Eigen::Vector3d(2.0, 3.0, 1.5), Eigen::Vector3d(26.0, 8.0, 1.5), 40.0, false);
  ASSERT_TRUE(log.reached) << (log.abandoned ? *log.abandoned : "timeout");
  EXPECT_EQ(log.plans, 1);  // one plan to the goal, never replanned: nothing new is ever seen
  EXPECT_GE(log.min_box_distance, 0.3);
}

}  // namespace
}  // namespace fast_planner
