#include <gtest/gtest.h>
#include <quad_core/bspline.h>

#include <cmath>
#include <random>

#include "fast_planner/bspline_optimizer.h"
#include "fast_planner/obvp.h"
#include "test_util.h"

namespace fast_planner {
namespace {

Eigen::Vector3d Row(const Eigen::VectorXd& v) { return Eigen::Vector3d(v[0], v[1], v[2]); }

TEST(BsplineFitTest, ControlPointsFromStateReproduceTheState) {
  const Eigen::Vector3d p(1, 2, 3), v(0.5, -1, 2), a(-0.3, 0.2, 1.5);
  const double ts = 0.2;
  Eigen::MatrixXd q(6, 3);
  q.topRows(3) = ControlPointsFromState(p, v, a, ts);
  q.bottomRows(3) = Eigen::MatrixXd::Random(3, 3);
  const auto s = quad_core::NonUniformBspline::Uniform(q, 3, ts);
  EXPECT_LT((Row(s.Evaluate(0.0)) - p).norm(), 1e-12);
  EXPECT_LT((Row(s.Derivative().Evaluate(0.0)) - v).norm(), 1e-12);
  EXPECT_LT((Row(s.Derivative(2).Evaluate(0.0)) - a).norm(), 1e-9);
}

PolyPath RandomPath(std::mt19937* rng) {
  std::uniform_real_distribution<double> u(-1.5, 1.5);
  PolyPath path;
  Eigen::Vector3d p(0, 0, 1), v(1, 0, 0);
  for (int i = 0; i < 6; ++i) {
    const Eigen::Vector3d acc(u(*rng), u(*rng), 0.3 * u(*rng));
    const PolySegment s = PolySegment::Primitive(p, v, acc, 0.6);
    path.Append(s);
    p = s.Position(0.6);
    v = s.Velocity(0.6);
  }
  path.Append(ObvpSegment(p, v, p + Eigen::Vector3d(2, 1, 0), Eigen::Vector3d::Zero(), 2.0));
  return path;
}

TEST(BsplineFitTest, FitMeetsTheStateExactlyAndFollowsThePath) {
  std::mt19937 rng(2);
  for (int trial = 0; trial < 20; ++trial) {
    const PolyPath path = RandomPath(&rng);
    const Eigen::Vector3d a0(0.4, -0.2, 0.1);
    for (const bool fix_end : {false, true}) {
      double ts = 0.0;
      const Eigen::MatrixXd q = FitUniformBspline(path, 0.5 / 3.0, a0, fix_end, &ts);
      const auto s = quad_core::NonUniformBspline::Uniform(q, 3, ts);
      ASSERT_NEAR(s.duration(), path.duration_s(), 1e-9);
      EXPECT_LE(ts, 0.5 / 3.0 + 1e-12);
      EXPECT_LT((Row(s.Evaluate(0.0)) - path.Position(0.0)).norm(), 1e-12);
      EXPECT_LT((Row(s.Derivative().Evaluate(0.0)) - path.Velocity(0.0)).norm(), 1e-12);
      EXPECT_LT((Row(s.Derivative(2).Evaluate(0.0)) - a0).norm(), 1e-9);
      for (double t = 0.0; t <= path.duration_s(); t += 0.05) {
        EXPECT_LT((Row(s.Evaluate(t)) - path.Position(t)).norm(), 0.03) << "t=" << t;
      }
      const double T = path.duration_s();
      EXPECT_LT((Row(s.Evaluate(T)) - path.Position(T)).norm(), fix_end ? 1e-9 : 0.01);
      if (fix_end) {
        EXPECT_LT(Row(s.Derivative().Evaluate(T)).norm(), 1e-9);
        EXPECT_LT(Row(s.Derivative(2).Evaluate(T)).norm(), 1e-9);
      }
    }
  }
}

TEST(BsplineFitTest, EmptyPathIsRejected) {
  double ts = 0.0;
  EXPECT_THROW(FitUniformBspline(PolyPath(), 0.2, Eigen::Vector3d::Zero(), false, &ts),
               std::invalid_argument);
}

// A map with two boxes and its ESDF, shared by the cost tests.
class CostTest : public ::testing::Test {
 protected:
  CostTest() : map_(test::SmallMapConfig(Eigen::Vector3d(6.0, 4.0, 3.0))) {
    test::AddBox(&map_, Eigen::Vector3d(2.0, 1.5, 0.0), Eigen::Vector3d(2.6, 2.3, 3.0));
    test::AddBox(&map_, Eigen::Vector3d(3.8, 0.0, 0.0), Eigen::Vector3d(4.2, 1.7, 2.0));
    esdf_.Update(map_, Eigen::Vector3i::Zero(), map_.size_voxels() - Eigen::Vector3i::Ones());
  }
  // A wavy line of control points from x = 0.5 to 5.5 at y ~ 2 (through the first box's clearance zone).
  Eigen::MatrixXd Wavy(std::mt19937* rng, int n) const {
    std::uniform_real_distribution<double> u(-0.25, 0.25);
    Eigen::MatrixXd q(n, 3);
    for (int i = 0; i < n; ++i) q.row(i) << 0.5 + 5.0 * i / (n - 1) + u(*rng), 1.9 + u(*rng), 1.5 + u(*rng);
    return q;
  }
  BsplineCostParams Params(bool fix_end) const {
    BsplineCostParams p;
    p.ts_s = 0.08;  // fast: the feasibility terms are active
    p.w_smooth = 1.3;
    p.w_distance = 20.0;
    p.w_feasibility = 0.01;
    p.w_endpoint = 5.0;
    p.safe_distance_m = 0.7;
    p.max_vel_mps = 3.0;
    p.max_acc_mps2 = 2.0;
    p.fix_end = fix_end;
    p.end_target = Eigen::Vector3d(5.6, 2.2, 1.4);
    return p;
  }
  VoxelMap map_;
  Esdf esdf_;
};

TEST_F(CostTest, AnalyticGradientEqualsFiniteDifferences) {
  std::mt19937 rng(17);
  int checked = 0;
  for (int trial = 0; trial < 30; ++trial) {
    const bool fix_end = trial % 2 == 1;
    const BsplineCostParams prm = Params(fix_end);
    const Eigen::MatrixXd q = Wavy(&rng, 16);
    Eigen::MatrixXd grad;
    const BsplineCost c = EvaluateBsplineCost(prm, esdf_, q, &grad);
    ASSERT_GT(c.distance, 0.0);
    ASSERT_GT(c.feasibility, 0.0);
    ASSERT_GT(c.smooth, 0.0);
    ASSERT_EQ(c.endpoint > 0.0, !fix_end);
    const double h = 1e-6;
    for (int i = 0; i < q.rows(); ++i) {
      for (int a = 0; a < 3; ++a) {
        const bool fixed = i < 3 || (fix_end && i >= q.rows() - 3);
        if (fixed) {
          EXPECT_EQ(grad(i, a), 0.0);
          continue;
        }
        Eigen::MatrixXd qp = q, qm = q;
        qp(i, a) += h;
        qm(i, a) -= h;
        const double fd = (EvaluateBsplineCost(prm, esdf_, qp, nullptr).total -
                           EvaluateBsplineCost(prm, esdf_, qm, nullptr).total) /
                          (2 * h);
        EXPECT_NEAR(grad(i, a), fd, 1e-4 * (1.0 + std::abs(fd)))
            << "trial " << trial << " point " << i << " axis " << a;
        ++checked;
      }
    }
  }
  EXPECT_GT(checked, 1000);
}

TEST_F(CostTest, EachTermHasItsClosedFormValue) {
  // Four collinear, evenly spaced points far from obstacles: no jerk, no obstacle, 1 m/s, no acceleration.
  Eigen::MatrixXd q(4, 3);
  for (int i = 0; i < 4; ++i) q.row(i) << 0.5 + 0.1 * i, 3.5, 2.8;
  BsplineCostParams prm = Params(false);
  prm.ts_s = 0.1;
  prm.end_target =
      Eigen::Vector3d(0.7, 3.5, 2.8);  // the spline's end is (q1 + 4 q2 + q3) / 6 = (0.7, 3.5, 2.8)
  BsplineCost c = EvaluateBsplineCost(prm, esdf_, q, nullptr);
  EXPECT_NEAR(c.smooth, 0.0, 1e-20);
  EXPECT_NEAR(c.feasibility, 0.0, 1e-20);
  EXPECT_NEAR(c.endpoint, 0.0, 1e-20);
  EXPECT_EQ(c.distance, 0.0);
  // Ten times faster: |V| = 10 m/s, i.e. ((100 - 9) / 9)^2 per velocity control point.
  prm.ts_s = 0.01;
  c = EvaluateBsplineCost(prm, esdf_, q, nullptr);
  const double e = 91.0 / 9.0;
  EXPECT_NEAR(c.feasibility, 3 * e * e, 1e-9);
  EXPECT_NEAR(c.total, prm.w_feasibility * 3 * e * e + prm.w_endpoint * c.endpoint, 1e-9);
}

TEST_F(CostTest, OptimisationLowersTheCostMovesOnlyFreePointsAndClearsTheObstacle) {
  std::mt19937 rng(4);
  OptimizerConfig oc;
  oc.w_distance = 20.0;
  oc.safe_distance_m = 0.7;
  const BsplineOptimizer opt(oc, LimitsConfig{});
  Eigen::MatrixXd q(21, 3);
  // Straight past the first box at 0.2 m and over the second at 0.5 m: both closer than the safe distance.
  for (int i = 0; i < 21; ++i) q.row(i) << 0.5 + 0.25 * i, 1.3, 2.5;
  for (const bool fix_end : {false, true}) {
    const OptimizationResult r = opt.Optimize(q, 0.5 / 3.0, esdf_, fix_end, q.row(20).transpose());
    EXPECT_LT(r.final.total, 0.2 * r.initial.total) << r.nlopt_result;
    EXPECT_GT(r.evaluations, 1);
    EXPECT_EQ(r.ctrl_pts.topRows(3), q.topRows(3));
    if (fix_end) {
      EXPECT_EQ(r.ctrl_pts.bottomRows(3), q.bottomRows(3));
    }
    double min_d = 1e9;
    for (int i = 3; i < 18; ++i) min_d = std::min(min_d, esdf_.Distance(r.ctrl_pts.row(i).transpose()));
    EXPECT_GT(min_d, 0.5) << "closest free control point " << min_d;
  }
}

TEST(BsplineOptimizerTest, NonFiniteControlPointsAndBadConfigsAreRejected) {
  const BsplineOptimizer opt(OptimizerConfig{}, LimitsConfig{});
  Esdf esdf;
  Eigen::MatrixXd q = Eigen::MatrixXd::Zero(8, 3);
  q(5, 1) = std::nan("");
  EXPECT_THROW(opt.Optimize(q, 0.1, esdf, false, Eigen::Vector3d::Zero()), std::invalid_argument);
  OptimizerConfig bad;
  bad.w_distance = -1.0;
  try {
    BsplineOptimizer o(bad, LimitsConfig{});
    FAIL();
  } catch (const std::exception& e) {
    EXPECT_NE(std::string(e.what()).find("optimizer.w_distance"), std::string::npos);
  }
}

}  // namespace
}  // namespace fast_planner
