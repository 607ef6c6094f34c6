#include <gtest/gtest.h>

#include <cmath>
#include <deque>
#include <limits>
#include <memory>
#include <random>
#include <vector>

#include "fast_planner/planner_manager.h"
#include "test_util.h"

namespace fast_planner {
namespace {

Eigen::Vector3d V3(const Eigen::VectorXd& v) { return Eigen::Vector3d(v[0], v[1], v[2]); }

// Points at the voxel centres of an axis-aligned box (the simulator's voxel map format).
std::vector<Eigen::Vector3d> BoxPoints(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, double r = 0.1) {
  std::vector<Eigen::Vector3d> pts;
  for (double x = lo.x() + 0.5 * r; x < hi.x(); x += r) {
    for (double y = lo.y() + 0.5 * r; y < hi.y(); y += r) {
      for (double z = lo.z() + 0.5 * r; z < hi.z(); z += r) pts.emplace_back(x, y, z);
    }
  }
  return pts;
}

// Odometry at 200 Hz from t = 0 with velocity v(t) = v0 + a t.
std::deque<quad_core::VehicleState> AcceleratingHistory(const Eigen::Vector3d& v0, const Eigen::Vector3d& a,
                                                        int n) {
  std::deque<quad_core::VehicleState> h;
  for (int i = 0; i < n; ++i) {
    quad_core::VehicleState o;
    o.t_s = 0.005 * i;
    o.v_world = v0 + a * o.t_s;
    h.push_back(o);
  }
  return h;
}

TEST(AccelerationFromOdometry, RecoversAConstantAcceleration) {
  const Eigen::Vector3d a(1.2, -0.5, 0.3);
  const auto h = AcceleratingHistory(Eigen::Vector3d(2.0, 0.0, 0.0), a, 100);
  // At t = 0.3 s with a 0.05 s window: odometry 0.3 s and 0.25 s.
  EXPECT_LT((AccelerationFromOdometry(h, 0.3, 0.05, 10.0) - a).norm(), 1e-9);
  // A frame between two odometry messages uses the newest one not after it.
  EXPECT_LT((AccelerationFromOdometry(h, 0.3024, 0.05, 10.0) - a).norm(), 1e-9);
}

TEST(AccelerationFromOdometry, IgnoresOdometryAfterTheStamp) {
  auto h = AcceleratingHistory(Eigen::Vector3d::Zero(), Eigen::Vector3d(1.0, 0.0, 0.0), 60);
  quad_core::VehicleState late;
  late.t_s = 0.5;
  late.v_world = Eigen::Vector3d(100.0, 0.0, 0.0);
  h.push_back(late);
  EXPECT_NEAR(AccelerationFromOdometry(h, 0.2, 0.05, 10.0).x(), 1.0, 1e-9);
}

TEST(AccelerationFromOdometry, CapsTheNormAtTheLimit) {
  const auto h = AcceleratingHistory(Eigen::Vector3d::Zero(), Eigen::Vector3d(6.0, 8.0, 0.0), 40);
  const Eigen::Vector3d a = AccelerationFromOdometry(h, 0.1, 0.05, 2.0);
  EXPECT_NEAR(a.norm(), 2.0, 1e-9);
  EXPECT_NEAR(a.x() / a.y(), 0.75, 1e-9);  // direction kept
}

TEST(AccelerationFromOdometry, ZeroWithoutAPairOrWindow) {
  const auto h = AcceleratingHistory(Eigen::Vector3d::Zero(), Eigen::Vector3d(1.0, 0.0, 0.0), 5);
  EXPECT_TRUE(AccelerationFromOdometry(h, 0.02, 0.05, 10.0).isZero());   // history spans 0.02 s only
  EXPECT_TRUE(AccelerationFromOdometry(h, -1.0, 0.05, 10.0).isZero());   // before every odometry
  EXPECT_TRUE(AccelerationFromOdometry(h, 0.02, 0.0, 10.0).isZero());    // window 0: zero (as before)
  EXPECT_TRUE(AccelerationFromOdometry({}, 0.02, 0.05, 10.0).isZero());  // no history
}

PlannerConfig GlobalConfig() {
  PlannerConfig c;
  c.map = test::SmallMapConfig(Eigen::Vector3d(20.0, 10.0, 4.0), 0.1, 0.3, 0.0, 4.0);
  c.map.source = MapSource::kGlobal;
  c.map.local_update_range_m = Eigen::Vector3d(4.0, 4.0, 2.0);
  return c;
}

struct SplineStats {
  double max_speed = 0.0;
  double max_acc = 0.0;
  double min_clearance = std::numeric_limits<double>::infinity();  // ESDF at samples
  bool enters_inflation = false;
};

SplineStats Sample(const quad_core::NonUniformBspline& s, const PlannerManager& m) {
  SplineStats st;
  const auto vel = s.Derivative();
  const auto acc = s.Derivative(2);
  for (double t = s.tmin(); t <= s.tmax(); t += 0.002) {
    st.max_speed = std::max(st.max_speed, vel.Evaluate(t).norm());
    st.max_acc = std::max(st.max_acc, acc.Evaluate(t).norm());
    const Eigen::Vector3d p = V3(s.Evaluate(t));
    st.enters_inflation |= m.map().IsInflated(p);
  }
  return st;
}

TEST(PlannerManagerTest, OpenSpacePlanStartsAtTheStateAndEndsAtTheGoalWithinLimits) {
  PlannerManager m(GlobalConfig());
  m.SetGlobalMap({});
  PlanRequest req;
  req.start_p = Eigen::Vector3d(2.0, 5.0, 1.5);
  req.goal = Eigen::Vector3d(12.0, 4.0, 2.0);
  req.start_time_s = 3.25;
  const PlanResult r = m.Plan(req);
  ASSERT_TRUE(r.ok()) << r.reason;
  EXPECT_TRUE(r.reaches_goal);
  EXPECT_EQ(r.traj_id, 1);
  EXPECT_EQ(r.start_time_s, 3.25);
  const auto& s = *r.spline;
  EXPECT_EQ(s.order(), 3);
  EXPECT_EQ(s.tmin(), 0.0);
  EXPECT_LT((V3(s.Evaluate(0.0)) - req.start_p).norm(), 1e-9);
  EXPECT_LT(V3(s.Derivative().Evaluate(0.0)).norm(), 1e-9);
  EXPECT_LT((V3(s.Evaluate(s.tmax())) - req.goal).norm(), 1e-9);
  EXPECT_LT(V3(s.Derivative().Evaluate(s.tmax())).norm(), 1e-9);
  const SplineStats st = Sample(s, m);
  EXPECT_LE(st.max_speed, 3.0 + 1e-6);
  EXPECT_LE(st.max_acc, 2.0 + 1e-6);
  EXPECT_FALSE(st.enters_inflation);
  EXPECT_GT(r.timings.total_ms, 0.0);
  EXPECT_GE(r.timings.total_ms, r.timings.frontend_ms + r.timings.optimization_ms);
  EXPECT_EQ(r.reason.rfind("success: reached goal", 0), 0u) << r.reason;
}

TEST(PlannerManagerTest, WallGivesASafeDetourAndTheOptimiserKeepsItsDistance) {
  PlannerManager m(GlobalConfig());
  m.SetGlobalMap(BoxPoints(Eigen::Vector3d(6.0, 2.0, 0.0), Eigen::Vector3d(6.4, 8.0, 4.0)));
  PlanRequest req;
  req.start_p = Eigen::Vector3d(3.0, 5.0, 1.5);
  req.goal = Eigen::Vector3d(9.0, 5.0, 1.5);
  const PlanResult r = m.Plan(req);
  ASSERT_TRUE(r.ok()) << r.reason;
  const SplineStats st = Sample(*r.spline, m);
  EXPECT_FALSE(st.enters_inflation);
  EXPECT_LE(st.max_speed, 3.0 + 1e-6);
  EXPECT_LE(st.max_acc, 2.0 + 1e-6);
  double min_d = 1e9;
  for (double t = 0.0; t <= r.spline->tmax(); t += 0.01)
    min_d = std::min(min_d, m.esdf().Distance(V3(r.spline->Evaluate(t))));
  EXPECT_GT(min_d, 0.35);
}

TEST(PlannerManagerTest, ThinWallIsNeverCrossed) {
  PlannerManager m(GlobalConfig());
  m.SetGlobalMap(BoxPoints(Eigen::Vector3d(6.0, 0.0, 0.0), Eigen::Vector3d(6.1, 8.0, 4.0)));
  PlanRequest req;
  req.start_p = Eigen::Vector3d(3.0, 5.0, 1.5);
  req.start_v = Eigen::Vector3d(2.5, 0.0, 0.0);
  req.goal = Eigen::Vector3d(9.0, 5.0, 1.5);
  const PlanResult r = m.Plan(req);
  ASSERT_TRUE(r.ok()) << r.reason;
  const auto& s = *r.spline;
  for (double t = 0.0; t + 1e-3 <= s.tmax(); t += 1e-3) {
    const Eigen::Vector3d a = V3(s.Evaluate(t)), b = V3(s.Evaluate(t + 1e-3));
    if ((a.x() - 6.05) * (b.x() - 6.05) <= 0.0) {
      ASSERT_GT(a.y(), 8.3) << "crossed the thin wall at " << a.transpose();
    }
  }
  EXPECT_FALSE(Sample(s, m).enters_inflation);
}

TEST(PlannerManagerTest, ReplanFromAMovingStateContinuesItsPositionVelocityAndAcceleration) {
  PlannerManager m(GlobalConfig());
  m.SetGlobalMap(BoxPoints(Eigen::Vector3d(9.0, 3.0, 0.0), Eigen::Vector3d(10.0, 6.0, 4.0)));
  PlanRequest req;
  req.start_p = Eigen::Vector3d(3.0, 5.0, 1.5);
  req.start_v = Eigen::Vector3d(2.0, 0.5, 0.0);
  req.start_a = Eigen::Vector3d(0.3, -0.4, 0.2);
  req.goal = Eigen::Vector3d(14.0, 5.0, 1.5);
  const PlanResult r = m.Plan(req);
  ASSERT_TRUE(r.ok()) << r.reason;
  const auto& s = *r.spline;
  EXPECT_LT((V3(s.Evaluate(0.0)) - req.start_p).norm(), 0.01);
  EXPECT_LT((V3(s.Derivative().Evaluate(0.0)) - req.start_v).norm(), 0.05);
  EXPECT_LT((V3(s.Derivative(2).Evaluate(0.0)) - req.start_a).norm(), 0.2);
  const SplineStats st = Sample(s, m);
  EXPECT_FALSE(st.enters_inflation);
  EXPECT_LE(st.max_speed, 3.0 + 1e-6);
  EXPECT_LE(st.max_acc, 2.0 + 1e-6);
}

TEST(PlannerManagerTest, BadGoalsAndStartsAreRejectedWithTheReason) {
  PlannerManager m(GlobalConfig());
  m.SetGlobalMap(BoxPoints(Eigen::Vector3d(9.0, 3.0, 0.0), Eigen::Vector3d(10.0, 6.0, 4.0)));
  PlanRequest req;
  req.start_p = Eigen::Vector3d(3.0, 5.0, 1.5);
  req.goal = Eigen::Vector3d(9.5, 4.5, 1.5);
  PlanResult r = m.Plan(req);
  EXPECT_EQ(r.status, PlanStatus::kInvalidGoal);
  EXPECT_EQ(r.reason,
            "invalid goal: goal is inside an obstacle (or at/below the ground or at/above the ceiling)");
  EXPECT_FALSE(r.spline.has_value());
  req.goal = Eigen::Vector3d(10.2, 4.5, 1.5);
  EXPECT_EQ(m.Plan(req).reason, "invalid goal: goal is within 0.3 m of an obstacle (or the ground/ceiling)");
  req.goal = Eigen::Vector3d(30.0, 4.5, 1.5);
  r = m.Plan(req);
  EXPECT_EQ(r.status, PlanStatus::kInvalidGoal);
  EXPECT_NE(r.reason.find("is outside the map"), std::string::npos) << r.reason;
  req.goal = Eigen::Vector3d(5.0, 4.5, -0.5);
  EXPECT_EQ(m.Plan(req).status, PlanStatus::kInvalidGoal);
  req.goal = Eigen::Vector3d(5.0, 4.5, 1.5);
  req.start_v.x() = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(m.Plan(req).reason, "invalid start: start state is not finite");
  req.start_v.setZero();
  req.start_p = Eigen::Vector3d(9.5, 4.5, 1.5);
  EXPECT_EQ(m.Plan(req).reason, "invalid start: start is inside an obstacle");
}

TEST(PlannerManagerTest, EnclosedGoalFailsInTheFrontEndWithItsReason) {
  PlannerConfig c = GlobalConfig();
  c.search.max_nodes = 2000;
  PlannerManager m(c);
  std::vector<Eigen::Vector3d> pts;
  for (const auto& [lo, hi] :
       std::vector<std::pair<Eigen::Vector3d, Eigen::Vector3d>>{{{6, 3, 0.5}, {9, 7, 0.7}},
                                                                {{6, 3, 2.8}, {9, 7, 3.0}},
                                                                {{6, 3, 0.5}, {6.2, 7, 3}},
                                                                {{8.8, 3, 0.5}, {9, 7, 3}},
                                                                {{6, 3, 0.5}, {9, 3.2, 3}},
                                                                {{6, 6.8, 0.5}, {9, 7, 3}}}) {
    const auto b = BoxPoints(lo, hi);
    pts.insert(pts.end(), b.begin(), b.end());
  }
  m.SetGlobalMap(pts);
  PlanRequest req;
  req.start_p = Eigen::Vector3d(2.0, 5.0, 1.5);
  req.goal = Eigen::Vector3d(7.5, 5.0, 1.75);
  const PlanResult r = m.Plan(req);
  EXPECT_EQ(r.status, PlanStatus::kFrontEndFailed);
  EXPECT_EQ(r.search_status, SearchStatus::kNodeBudgetExhausted);
  EXPECT_EQ(r.reason.rfind("front end failed: node budget exhausted", 0), 0u) << r.reason;
}

TEST(PlannerManagerTest, EmergencyStopBrakesToRestWithinTheLimits) {
  PlannerManager m(GlobalConfig());
  m.SetGlobalMap({});
  const Eigen::Vector3d p(3.0, 5.0, 1.5), v(3.0, 0.0, 0.0), a(0.5, 0.5, 0.0);
  const PlanResult r = m.PlanStop(p, v, a, 7.0);
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(r.reason, "emergency stop");
  const auto& s = *r.spline;
  EXPECT_LT((V3(s.Evaluate(0.0)) - p).norm(), 0.01);
  EXPECT_LT(V3(s.Derivative().Evaluate(s.tmax())).norm(), 1e-9);
  const double stop_dist = (V3(s.Evaluate(s.tmax())) - p).norm();
  EXPECT_GT(stop_dist, 9.0 / 4.0 * 0.9);  // v^2 / (2 a_max) at best
  EXPECT_LT(stop_dist, 9.0 / 4.0 * 2.0);
  const SplineStats st = Sample(s, m);
  EXPECT_LE(st.max_speed, 3.0 + 1e-6);
  EXPECT_LE(st.max_acc, 2.0 + 1e-6);
  // At rest: a short hold at the same place.
  const PlanResult hold = m.PlanStop(p, Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero(), 7.0);
  EXPECT_LT((V3(hold.spline->Evaluate(hold.spline->tmax())) - p).norm(), 1e-9);
}

// Records what the observer (the data collector's hook) received.
class RecordingObserver : public PlanObserver {
 public:
  void OnPlan(const PlanRecord& r) override {
    depths.push_back(r.depth);
    odom_stamps.push_back(r.odometry ? r.odometry->t_s : -1.0);
    goals.push_back(r.goal);
    traj_ids.push_back(r.result->traj_id);
    knots.push_back(r.result->spline->knots());
  }
  std::vector<std::shared_ptr<const DepthFrame>> depths;
  std::vector<double> odom_stamps;
  std::vector<Eigen::Vector3d> goals;
  std::vector<int64_t> traj_ids;
  std::vector<std::vector<double>> knots;
};

TEST(PlannerManagerTest, ObserverGetsTheExactInputsAndOutputOfEverySuccessfulPlan) {
  PlannerConfig c = GlobalConfig();
  c.map.source = MapSource::kDepth;
  c.map.local_update_range_m = Eigen::Vector3d(8.0, 8.0, 2.0);
  PlannerManager m(c);
  auto obs = std::make_shared<RecordingObserver>();
  m.SetObserver(obs);
  auto frame = std::make_shared<DepthFrame>(
      test::ConstantDepthFrame(std::numeric_limits<float>::infinity(), Eigen::Vector3d(2.0, 5.0, 1.5)));
  frame->stamp_s = 4.5;
  const MapUpdateResult mu = m.UpdateDepth(frame);
  EXPECT_GT(mu.stats.rays, 0);
  quad_core::VehicleState odom;
  odom.t_s = 4.495;
  odom.p_world_body = Eigen::Vector3d(2.0, 5.0, 1.5);
  m.UpdateOdometry(odom);
  PlanRequest req;
  req.start_p = odom.p_world_body;
  req.goal = Eigen::Vector3d(6.0, 5.0, 1.5);
  req.start_time_s = 4.5;
  const PlanResult r = m.Plan(req);
  ASSERT_TRUE(r.ok()) << r.reason;
  ASSERT_EQ(obs->depths.size(), 1u);
  EXPECT_EQ(obs->depths[0].get(), frame.get());  // the very frame, not a copy
  EXPECT_EQ(obs->odom_stamps[0], 4.495);
  EXPECT_EQ(obs->goals[0], req.goal);
  EXPECT_EQ(obs->traj_ids[0], r.traj_id);
  EXPECT_EQ(obs->knots[0], r.spline->knots());
  // Failed plans are not reported.
  req.goal = Eigen::Vector3d(60.0, 5.0, 1.5);
  EXPECT_FALSE(m.Plan(req).ok());
  EXPECT_EQ(obs->depths.size(), 1u);
}

TEST(PlannerManagerTest, NonFiniteOdometryAndMalformedDepthAreRejected) {
  PlannerManager m(GlobalConfig());
  quad_core::VehicleState odom;
  odom.v_world.y() = std::numeric_limits<double>::infinity();
  try {
    m.UpdateOdometry(odom);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("odometry velocity is not finite"), std::string::npos);
  }
  EXPECT_FALSE(m.last_odometry().has_value());
  auto frame = std::make_shared<DepthFrame>(test::ConstantDepthFrame(1.0f, Eigen::Vector3d(2, 5, 1.5)));
  frame->image.depth_m.resize(10);
  EXPECT_THROW(m.UpdateDepth(frame), std::invalid_argument);
  EXPECT_EQ(m.last_depth(), nullptr);
}

// Issue 32: the privileged expert's ESDF is computed once per world, in SetGlobalMap, never by a plan; a
// reset followed by the same world again (ExpertSession::StartEpisode) reuses it; another world rebuilds it.
TEST(PlannerManagerTest, GlobalEsdfIsBuiltOnceAndReusedAfterAResetWithTheSameWorld) {
  PlannerManager m(GlobalConfig());
  const auto wall = BoxPoints(Eigen::Vector3d(6.0, 2.0, 0.0), Eigen::Vector3d(6.4, 8.0, 4.0));
  EXPECT_EQ(m.esdf_updates(), 0);
  m.SetGlobalMap(wall);
  EXPECT_EQ(m.esdf_updates(), 1);
  ASSERT_TRUE(m.esdf().valid());
  PlanRequest req;
  req.start_p = Eigen::Vector3d(3.0, 5.0, 1.5);
  req.goal = Eigen::Vector3d(9.0, 5.0, 1.5);
  for (const double x : {3.0, 2.0, 1.0}) {  // plans from other starts (the replanner's) reuse it
    req.start_p.x() = x;
    const PlanResult r = m.Plan(req);
    ASSERT_TRUE(r.ok()) << r.reason;
  }
  EXPECT_EQ(m.esdf_updates(), 1);

  m.Reset();
  EXPECT_FALSE(m.MapReady());
  EXPECT_EQ(m.Plan(req).status, PlanStatus::kMapNotReady);
  const double d_before = m.esdf().Distance(Eigen::Vector3d(5.5, 5.0, 1.5));
  m.SetGlobalMap(wall);  // the same points: kept
  EXPECT_TRUE(m.MapReady());
  EXPECT_EQ(m.esdf_updates(), 1);
  EXPECT_EQ(m.esdf().Distance(Eigen::Vector3d(5.5, 5.0, 1.5)), d_before);
  EXPECT_TRUE(m.map().IsOccupied(Eigen::Vector3d(6.2, 5.0, 1.5)));
  const PlanResult again = m.Plan(req);
  ASSERT_TRUE(again.ok()) << again.reason;
  EXPECT_EQ(again.traj_id, 1);  // the reset forgot the trajectory ids
  EXPECT_EQ(m.esdf_updates(), 1);

  // Another world: rebuilt, and nothing of the old one is left.
  m.SetGlobalMap(BoxPoints(Eigen::Vector3d(12.0, 2.0, 0.0), Eigen::Vector3d(12.4, 8.0, 4.0)));
  EXPECT_EQ(m.esdf_updates(), 2);
  EXPECT_FALSE(m.map().IsOccupied(Eigen::Vector3d(6.2, 5.0, 1.5)));
  EXPECT_TRUE(m.map().IsOccupied(Eigen::Vector3d(12.2, 5.0, 1.5)));
  EXPECT_NEAR(m.esdf().Distance(Eigen::Vector3d(11.55, 5.0, 1.5)), 0.5, 1e-6);
  // No obstacle within the truncation any more: the ground's distance (z 1.5 m between voxel centres 1.45 and
  // 1.55 m, the ground layer's centre at -0.05 m).
  EXPECT_NEAR(m.esdf().Distance(Eigen::Vector3d(6.2, 5.0, 1.5)), 1.55, 1e-6);  // stored as float
}

// The global ESDF covers only the obstacles' x-y box (widened by the truncation): everywhere in the map it
// must give the field of a fresh transform over the whole map (voxel values exactly inside its window;
// interpolated values and gradients anywhere, up to the rounding of the interpolation weights).
TEST(PlannerManagerTest, GlobalEsdfEqualsAFreshTransformOfTheWholeMap) {
  for (const int seed : {1, 2, 3}) {
    PlannerConfig c = GlobalConfig();
    if (seed == 3) {  // ground and ceiling layers inside the map
      c.map.origin_m.z() = -0.3;
      c.map.ceiling_z_m = 3.2;
    }
    PlannerManager m(c);
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> ux(7.0, 13.0), uy(3.0, 7.0), uz(-0.5, 3.5), ext(0.1, 0.8);
    std::vector<Eigen::Vector3d> pts;
    for (int i = 0; i < 12; ++i) {
      const Eigen::Vector3d lo(ux(rng), uy(rng), uz(rng));
      const auto box = BoxPoints(lo, lo + Eigen::Vector3d(ext(rng), ext(rng), ext(rng)));
      pts.insert(pts.end(), box.begin(), box.end());
    }
    m.SetGlobalMap(pts);
    const VoxelMap& map = m.map();
    const Esdf& esdf = m.esdf();
    const Eigen::Vector3i top = map.size_voxels() - Eigen::Vector3i::Ones();
    // The window is smaller than the map in x and y, so the clamping is exercised.
    ASSERT_GT(esdf.window_min().x(), 0);
    ASSERT_LT(esdf.window_max().y(), top.y());
    Esdf full(c.map.esdf_max_distance_m);
    full.Update(map, Eigen::Vector3i::Zero(), top);
    for (int z = esdf.window_min().z(); z <= esdf.window_max().z(); ++z) {
      for (int y = esdf.window_min().y(); y <= esdf.window_max().y(); ++y) {
        for (int x = esdf.window_min().x(); x <= esdf.window_max().x(); ++x) {
          const Eigen::Vector3i v(x, y, z);
          ASSERT_EQ(esdf.VoxelDistance(v), full.VoxelDistance(v))
              << "seed " << seed << " voxel " << v.transpose();
        }
      }
    }
    std::uniform_real_distribution<double> px(-1.0, 21.0), py(-1.0, 11.0), pz(-0.5, 4.5);
    for (int i = 0; i < 20000; ++i) {
      const Eigen::Vector3d p(px(rng), py(rng), pz(rng));
      Eigen::Vector3d g, g_full;
      const double d = esdf.DistanceAndGradient(p, &g);
      const double d_full = full.DistanceAndGradient(p, &g_full);
      ASSERT_NEAR(d, d_full, 1e-9) << "seed " << seed << " at " << p.transpose();
      ASSERT_LT((g - g_full).norm(), 1e-6) << "seed " << seed << " at " << p.transpose();
    }
  }
}

}  // namespace
}  // namespace fast_planner
