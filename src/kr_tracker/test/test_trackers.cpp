// Hover, line (min-jerk goto) and B-spline trackers, driven with odometry that follows the reference exactly.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "kr_tracker/bspline_tracker.h"
#include "kr_tracker/line_tracker.h"

namespace kr_tracker {
namespace {

constexpr double kDt = 0.005;

quad_core::VehicleState StateAt(double t, const Eigen::Vector3d& p) {
  quad_core::VehicleState s;
  s.t_s = t;
  s.p_world_body = p;
  return s;
}

TEST(HoverTracker, HoldsThePositionAndYawItWasActivatedFrom) {
  HoverTracker h;
  EXPECT_EQ(h.status(), TrackerStatus::kInactive);
  PositionReference from = PositionReference::Hold(Eigen::Vector3d(1, 2, 3), 0.4);
  from.v_world = Eigen::Vector3d(1, 0, 0);
  h.Activate(from, StateAt(0.0, Eigen::Vector3d::Zero()));
  EXPECT_EQ(h.status(), TrackerStatus::kHolding);
  const PositionReference r = h.Update(StateAt(5.0, Eigen::Vector3d(9, 9, 9)));
  EXPECT_TRUE(r.p_world.isApprox(from.p_world));
  EXPECT_DOUBLE_EQ(r.yaw_rad, 0.4);
  EXPECT_EQ(r.v_world.norm(), 0.0);
}

TEST(MinJerk, SegmentMeetsBoundaryConditionsAndItsDerivativesMatchFiniteDifferences) {
  const Eigen::Vector3d p0(0, 1, 2), v0(1, -0.5, 0.2), a0(0.3, 0.1, -0.4), p1(4, -1, 3);
  const MinJerkSegment seg(p0, v0, a0, p1, 2.5);
  EXPECT_TRUE(seg.Eval(0, 0).isApprox(p0, 1e-12));
  EXPECT_TRUE(seg.Eval(0, 1).isApprox(v0, 1e-12));
  EXPECT_TRUE(seg.Eval(0, 2).isApprox(a0, 1e-12));
  EXPECT_TRUE(seg.Eval(2.5, 0).isApprox(p1, 1e-12));
  EXPECT_LT(seg.Eval(2.5, 1).norm(), 1e-12);
  EXPECT_LT(seg.Eval(2.5, 2).norm(), 1e-11);
  const double h = 1e-6;
  for (double t : {0.3, 1.1, 2.0}) {
    for (int k = 1; k <= 3; ++k) {
      const Eigen::Vector3d fd = (seg.Eval(t + h, k - 1) - seg.Eval(t - h, k - 1)) / (2 * h);
      EXPECT_LT((fd - seg.Eval(t, k)).norm(), 1e-5) << t << " " << k;
    }
  }
}

TEST(MinJerk, RestToRestDurationIsTheClosedFormAndLimitsHold) {
  const Eigen::Vector3d z = Eigen::Vector3d::Zero();
  // Long move: velocity-limited, T = 1.875 D / v.
  EXPECT_NEAR(MinJerkDuration(z, z, z, Eigen::Vector3d(10, 0, 0), 2.0, 5.0), 1.875 * 10 / 2.0, 1e-12);
  // Short move: acceleration-limited, T = sqrt(5.7735 D / a).
  EXPECT_NEAR(MinJerkDuration(z, z, z, Eigen::Vector3d(0, 0.5, 0), 5.0, 1.0),
              std::sqrt(5.773502691896258 * 0.5), 1e-12);
  // Moving start: the found duration keeps both limits.
  const Eigen::Vector3d v0(1.5, 0, 0);
  const double t = MinJerkDuration(z, v0, z, Eigen::Vector3d(-2, 1, 0), 2.0, 1.5);
  const MinJerkSegment seg(z, v0, z, Eigen::Vector3d(-2, 1, 0), t);
  EXPECT_LE(seg.MaxSpeed(1000), 2.0 * 1.001);
  EXPECT_LE(seg.MaxAccel(1000), 1.5 * 1.001);
}

TEST(LineTracker, GotoReachesTheGoalWithinLimitsAndReportsSuccess) {
  LineTrackerConfig cfg;
  LineTracker line(cfg);
  const PositionReference start = PositionReference::Hold(Eigen::Vector3d(0, 0, 0.125), 0.0);
  line.Activate(start, StateAt(0.0, start.p_world));
  EXPECT_EQ(line.status(), TrackerStatus::kHolding);
  EXPECT_EQ(line.SetGoal(Eigen::Vector3d(3, -1, 2), 1.0, 1.0, 0.8), "");
  EXPECT_EQ(line.status(), TrackerStatus::kTracking);
  double max_speed = 0.0, max_acc = 0.0, max_yaw_rate = 0.0;
  Eigen::Vector3d prev = start.p_world;
  PositionReference r;
  double t = 0.0;
  for (; t < 30.0 && line.status() != TrackerStatus::kSucceeded; t += kDt) {
    r = line.Update(StateAt(t, prev));
    EXPECT_LT((r.p_world - prev).norm(), 1.0 * kDt * 1.01);  // continuous, at most v_max per step
    prev = r.p_world;
    max_speed = std::max(max_speed, r.v_world.norm());
    max_acc = std::max(max_acc, r.a_world.norm());
    max_yaw_rate = std::max(max_yaw_rate, std::fabs(r.yaw_rate_radps));
  }
  EXPECT_EQ(line.status(), TrackerStatus::kSucceeded);
  EXPECT_TRUE(r.p_world.isApprox(Eigen::Vector3d(3, -1, 2), 1e-9));
  EXPECT_NEAR(r.yaw_rad, 1.0, 1e-12);
  EXPECT_LE(max_speed, 1.0 * 1.001);
  EXPECT_LE(max_acc, 0.8 * 1.001);
  EXPECT_LE(max_yaw_rate, cfg.max_yaw_rate_radps * 1.001);
  EXPECT_NEAR(t, line.duration_s(), 2 * kDt);
}

TEST(LineTracker, NewGoalMidFlightStartsFromTheCurrentReferenceWithoutAJump) {
  LineTracker line(LineTrackerConfig{});
  line.Activate(PositionReference::Hold(Eigen::Vector3d::Zero(), 0.0), StateAt(0.0, Eigen::Vector3d::Zero()));
  ASSERT_EQ(line.SetGoal(Eigen::Vector3d(5, 0, 0), 0.0, 0.0, 0.0), "");  // defaults
  PositionReference r;
  double t = 0.0;
  for (; t < 1.5; t += kDt) r = line.Update(StateAt(t, r.p_world));
  ASSERT_GT(r.v_world.norm(), 0.5);
  ASSERT_EQ(line.SetGoal(Eigen::Vector3d(0, 3, 0), 0.0, 0.0, 0.0), "");
  const PositionReference next = line.Update(StateAt(t, r.p_world));
  EXPECT_LT((next.p_world - r.p_world).norm(), 1e-9);
  EXPECT_LT((next.v_world - r.v_world).norm(), 1e-9);
}

TEST(LineTracker, YawTurnsTheShortWayAcrossPi) {
  LineTracker line(LineTrackerConfig{});
  line.Activate(PositionReference::Hold(Eigen::Vector3d::Zero(), 3.0), StateAt(0.0, Eigen::Vector3d::Zero()));
  ASSERT_EQ(line.SetGoal(Eigen::Vector3d::Zero(), -3.0, 1.0, 1.0), "");
  PositionReference r;
  double max_abs_yaw_change = 0.0, prev = 3.0;
  for (double t = 0.0; t < 5.0; t += kDt) {
    r = line.Update(StateAt(t, Eigen::Vector3d::Zero()));
    EXPECT_GE(std::fabs(r.yaw_rad), 3.0 - 1e-9);  // never swings through 0
    max_abs_yaw_change = std::max(max_abs_yaw_change, std::fabs(quad_core::WrapAngle(r.yaw_rad - prev)));
    prev = r.yaw_rad;
  }
  EXPECT_NEAR(r.yaw_rad, -3.0, 1e-12);
  EXPECT_EQ(line.status(), TrackerStatus::kSucceeded);
  EXPECT_LT(max_abs_yaw_change, 0.01);
}

TEST(LineTracker, RejectsNonFiniteGoals) {
  LineTracker line(LineTrackerConfig{});
  const double nan = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(line.SetGoal(Eigen::Vector3d(nan, 0, 0), 0.0, 1.0, 1.0), "goal position is not finite");
  EXPECT_EQ(line.SetGoal(Eigen::Vector3d::Zero(), nan, 1.0, 1.0), "goal yaw is not finite");
  EXPECT_EQ(line.SetGoal(Eigen::Vector3d::Zero(), 0.0, nan, 1.0), "velocity/acceleration limit not finite");
}

// A straight uniform cubic along x from (0, 0, 1), 1 m/s, starting at t0.
BsplineGoalSpec StraightGoal(double t0, double x0 = 0.0, int n = 10) {
  BsplineGoalSpec g;
  g.order = 3;
  g.traj_id = 7;
  g.start_time_s = t0;
  g.pos_pts.resize(n, 3);
  for (int i = 0; i < n; ++i) g.pos_pts.row(i) << x0 + 0.5 * (i - 1), 0.0, 1.0;
  for (int i = 0; i < n + 4; ++i) g.knots.push_back(0.5 * (i - 3));
  return g;
}

class BsplineTrackerTest : public ::testing::Test {
 protected:
  BsplineTrackerTest() : tracker_(BsplineTrackerConfig{}) {
    tracker_.Activate(PositionReference::Hold(Eigen::Vector3d(0, 0, 1), 0.0),
                      StateAt(10.0, Eigen::Vector3d(0, 0, 1)));
  }
  // Flies until t_end with the odometry on the reference; returns the last reference.
  PositionReference FlyUntil(double t_end) {
    PositionReference r;
    for (; t_ < t_end - 1e-9; t_ += kDt) {
      r = tracker_.Update(StateAt(t_, p_));
      p_ = r.p_world;
    }
    return r;
  }
  BsplineTracker tracker_;
  double t_ = 10.0;
  Eigen::Vector3d p_{0, 0, 1};
};

TEST_F(BsplineTrackerTest, RejectsEveryMalformedGoalWithItsReason) {
  const quad_core::VehicleState s = StateAt(10.0, Eigen::Vector3d(0, 0, 1));
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  auto reason = [&](const BsplineGoalSpec& g) { return tracker_.AddGoal(1, g, 10.0, s); };
  auto expect_reason = [&](const BsplineGoalSpec& g, const std::string& part) {
    const std::string why = reason(g);
    EXPECT_NE(why.find(part), std::string::npos) << "got '" << why << "' expected '" << part << "'";
  };
  BsplineGoalSpec g = StraightGoal(10.0);
  g.knots[5] = g.knots[4] - 0.1;
  expect_reason(g, "knots are not non-decreasing: knot 5");
  g = StraightGoal(10.0);
  g.knots.pop_back();
  expect_reason(g, "knot count 13 != control points + order + 1 = 10 + 3 + 1 = 14");
  g = StraightGoal(10.0);
  g.knots[2] = nan;
  expect_reason(g, "knot 2 is not finite");
  g = StraightGoal(10.0);
  g.pos_pts(4, 2) = inf;
  expect_reason(g, "control point 4 is not finite");
  g = StraightGoal(10.0);
  g.yaw_pts = {0.0, 0.1, nan, 0.3};
  g.yaw_dt_s = 0.5;
  expect_reason(g, "yaw point 2 is not finite");
  g = StraightGoal(10.0);
  g.yaw_dt_s = nan;
  expect_reason(g, "yaw_dt is not finite");
  g = StraightGoal(10.0);
  g.yaw_pts = {0.0, 0.1, 0.2, 0.3};
  g.yaw_dt_s = 0.0;
  expect_reason(g, "yaw_dt = 0.000000 must be > 0 when yaw points are given");
  g = StraightGoal(10.0);
  g.start_time_s = nan;
  expect_reason(g, "start_time is not finite");
  g = StraightGoal(10.0);
  g.order = 0;
  g.knots.resize(11);
  expect_reason(g, "order (degree) 0 is below 1");
  expect_reason(StraightGoal(10.0 + 2.5), "start_time is 2.5 s in the future (limit 2 s)");
  expect_reason(StraightGoal(10.0 - 1.5), "start_time is 1.5 s in the past (limit 1 s)");
  expect_reason(StraightGoal(10.0, 5.0), "m from the vehicle (limit 1.5 m)");
  g = StraightGoal(10.0 - 0.9, 0.0, 4);  // 0.5 s long, started 0.9 s ago
  expect_reason(g, "ends before now");
  // Nothing was queued by the rejected goals.
  EXPECT_TRUE(tracker_.TakeEvents().empty());
  EXPECT_EQ(tracker_.status(), TrackerStatus::kHolding);
}

TEST_F(BsplineTrackerTest, FollowsTheSplineFromItsStartTimeAndReportsSuccessTimeAndDistance) {
  const BsplineGoalSpec spec = StraightGoal(10.5);
  ASSERT_EQ(tracker_.AddGoal(42, spec, 10.0, StateAt(10.0, p_)), "");
  const quad_core::NonUniformBspline ref(spec.pos_pts, 3, spec.knots);
  // Before start_time: holding the activation point.
  PositionReference r = FlyUntil(10.5);
  EXPECT_TRUE(r.p_world.isApprox(Eigen::Vector3d(0, 0, 1)));
  EXPECT_EQ(tracker_.status(), TrackerStatus::kTracking);
  EXPECT_FALSE(tracker_.running_goal().has_value());
  r = FlyUntil(11.7);
  ASSERT_EQ(tracker_.running_goal().value_or(0), 42u);
  const double t_last = t_ - kDt;
  EXPECT_TRUE(r.p_world.isApprox(ref.Evaluate(ref.tmin() + t_last - 10.5), 1e-12));
  EXPECT_TRUE(r.v_world.isApprox(ref.Derivative().Evaluate(ref.tmin() + t_last - 10.5), 1e-12));
  EXPECT_NEAR(tracker_.RemainingTime(t_last), ref.duration() - (t_last - 10.5), 1e-12);
  // Direction-of-travel yaw: along +x.
  EXPECT_NEAR(r.yaw_rad, 0.0, 1e-12);
  r = FlyUntil(10.5 + ref.duration() + 0.5);
  EXPECT_EQ(tracker_.status(), TrackerStatus::kSucceeded);
  EXPECT_TRUE(r.p_world.isApprox(ref.Evaluate(ref.tmax()), 1e-12));
  EXPECT_EQ(r.v_world.norm(), 0.0);
  const auto events = tracker_.TakeEvents();
  ASSERT_EQ(events.size(), 2u);
  EXPECT_EQ(events[0].kind, GoalEventKind::kStarted);
  EXPECT_EQ(events[1].kind, GoalEventKind::kSucceeded);
  EXPECT_EQ(events[1].goal_id, 42u);
  EXPECT_NEAR(events[1].total_time_s, ref.duration(), kDt + 1e-9);
  // The odometry lags the reference by one step here: at most one step at 1 m/s is missing.
  EXPECT_NEAR(events[1].distance_travelled_m, ref.Length(), 1.0 * kDt + 1e-9);
  EXPECT_TRUE(events[1].reason.empty());
}

TEST_F(BsplineTrackerTest, NewerGoalReplacesTheRunningOneAtItsStartTime) {
  ASSERT_EQ(tracker_.AddGoal(1, StraightGoal(10.0), 10.0, StateAt(10.0, p_)), "");
  FlyUntil(11.0);
  ASSERT_EQ(tracker_.running_goal().value_or(0), 1u);
  // Goal 2: starts at 11.5 from where goal 1 will be then, going up.
  const quad_core::NonUniformBspline g1(StraightGoal(10.0).pos_pts, 3, StraightGoal(10.0).knots);
  BsplineGoalSpec spec2 = StraightGoal(11.5);
  const Eigen::Vector3d p_switch = g1.Evaluate(g1.tmin() + 1.5);
  for (int i = 0; i < spec2.pos_pts.rows(); ++i)
    spec2.pos_pts.row(i) << p_switch.x(), 0.0, 1.0 + 0.5 * (i - 1);
  ASSERT_EQ(tracker_.AddGoal(2, spec2, 11.0, StateAt(11.0, p_)), "");
  FlyUntil(11.5);
  EXPECT_EQ(tracker_.running_goal().value_or(0), 1u);  // still flying goal 1 until 11.5
  PositionReference r = FlyUntil(11.5 + kDt);
  EXPECT_EQ(tracker_.running_goal().value_or(0), 2u);
  EXPECT_GT(r.v_world.z(), 0.9);
  const auto events = tracker_.TakeEvents();
  ASSERT_EQ(events.size(), 3u);
  EXPECT_EQ(events[1].goal_id, 1u);
  EXPECT_EQ(events[1].kind, GoalEventKind::kReplaced);
  EXPECT_NEAR(events[1].total_time_s, 1.5, 1e-9);
  EXPECT_NE(events[1].reason.find("replaced by goal 2 (traj_id 7) at its start_time"), std::string::npos);
  EXPECT_EQ(events[2].goal_id, 2u);
  EXPECT_EQ(events[2].kind, GoalEventKind::kStarted);
}

TEST_F(BsplineTrackerTest, APendingGoalIsReplacedByANewerPendingOne) {
  ASSERT_EQ(tracker_.AddGoal(1, StraightGoal(11.0), 10.0, StateAt(10.0, p_)), "");
  ASSERT_EQ(tracker_.AddGoal(2, StraightGoal(11.2), 10.0, StateAt(10.0, p_)), "");
  FlyUntil(11.3);
  const auto events = tracker_.TakeEvents();
  ASSERT_EQ(events.size(), 2u);
  EXPECT_EQ(events[0].goal_id, 1u);
  EXPECT_EQ(events[0].kind, GoalEventKind::kReplaced);
  EXPECT_EQ(events[1].goal_id, 2u);
  EXPECT_EQ(events[1].kind, GoalEventKind::kStarted);
}

TEST_F(BsplineTrackerTest, CancelHoldsTheCurrentReferenceAndDeactivateAborts) {
  ASSERT_EQ(tracker_.AddGoal(1, StraightGoal(10.0), 10.0, StateAt(10.0, p_)), "");
  const PositionReference r = FlyUntil(11.0);
  EXPECT_FALSE(tracker_.Cancel(99));
  EXPECT_TRUE(tracker_.Cancel(1));
  const PositionReference held = FlyUntil(11.5);
  EXPECT_TRUE(held.p_world.isApprox(r.p_world));
  EXPECT_EQ(held.v_world.norm(), 0.0);
  auto events = tracker_.TakeEvents();
  ASSERT_EQ(events.size(), 2u);
  EXPECT_EQ(events[1].kind, GoalEventKind::kCanceled);

  ASSERT_EQ(tracker_.AddGoal(2, StraightGoal(11.5, held.p_world.x() + 0.5), 11.5, StateAt(11.5, p_)), "");
  FlyUntil(12.0);
  tracker_.Deactivate();
  events = tracker_.TakeEvents();
  ASSERT_EQ(events.size(), 2u);
  EXPECT_EQ(events[1].kind, GoalEventKind::kAborted);
  EXPECT_EQ(events[1].reason, "tracker deactivated (switched to another tracker)");
  EXPECT_EQ(tracker_.status(), TrackerStatus::kInactive);
}

TEST_F(BsplineTrackerTest, YawFollowsYawPointsWhenGivenElseTravelDirectionWithRateLimit) {
  // Along +y: the direction-of-travel yaw turns from 0 towards pi/2 at no more than the rate limit.
  BsplineGoalSpec spec = StraightGoal(10.0);
  for (int i = 0; i < spec.pos_pts.rows(); ++i) spec.pos_pts.row(i) << 0.0, 0.5 * (i - 1), 1.0;
  ASSERT_EQ(tracker_.AddGoal(1, spec, 10.0, StateAt(10.0, p_)), "");
  const double rate = BsplineTrackerConfig{}.max_yaw_rate_radps;
  double prev_yaw = 0.0;
  for (; t_ < 12.0; t_ += kDt) {
    const PositionReference r = tracker_.Update(StateAt(t_, p_));
    p_ = r.p_world;
    EXPECT_LE(std::fabs(r.yaw_rad - prev_yaw), rate * kDt + 1e-12);
    prev_yaw = r.yaw_rad;
  }
  EXPECT_NEAR(prev_yaw, M_PI / 2, 1e-9);

  // With yaw points: yaw(t) is the uniform yaw spline at t - start_time.
  BsplineGoalSpec with_yaw = StraightGoal(t_, p_.x());
  for (int i = 0; i < with_yaw.pos_pts.rows(); ++i) with_yaw.pos_pts.row(i) << p_.x(), p_.y(), 1.0;
  with_yaw.yaw_pts = {0.0, 0.2, 0.6, 1.0, 1.2, 1.4};
  with_yaw.yaw_dt_s = 0.5;
  const double t0 = t_;
  ASSERT_EQ(tracker_.AddGoal(2, with_yaw, t_, StateAt(t_, p_)), "");
  const PositionReference r = FlyUntil(t0 + 0.75 + kDt / 2);
  Eigen::MatrixXd yaw_pts(6, 1);
  yaw_pts << 0.0, 0.2, 0.6, 1.0, 1.2, 1.4;
  const auto yaw = quad_core::NonUniformBspline::Uniform(yaw_pts, 3, 0.5, 0.0);
  const double tau = (t_ - kDt) - t0;
  EXPECT_NEAR(r.yaw_rad, yaw.Evaluate(tau)(0), 1e-12);
  EXPECT_NEAR(r.yaw_rate_radps, yaw.Derivative().Evaluate(tau)(0), 1e-12);
}

}  // namespace
}  // namespace kr_tracker
