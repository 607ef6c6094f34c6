#include <gtest/gtest.h>

#include <random>

#include "fast_planner/bspline_optimizer.h"
#include "fast_planner/time_reallocation.h"

namespace fast_planner {
namespace {

// Speed and |acceleration| sampled densely over the whole domain.
void MaxSampled(const quad_core::NonUniformBspline& s, double* v_max, double* a_max) {
  const auto vel = s.Derivative();
  const auto acc = s.Derivative(2);
  *v_max = 0.0;
  *a_max = 0.0;
  const int n = 4000;
  for (int i = 0; i <= n; ++i) {
    const double t = s.tmin() + s.duration() * i / n;
    *v_max = std::max(*v_max, vel.Evaluate(t).norm());
    *a_max = std::max(*a_max, acc.Evaluate(t).norm());
  }
}

Eigen::MatrixXd RandomWalk(std::mt19937* rng, int n, double step) {
  std::normal_distribution<double> g(0.0, step);
  Eigen::MatrixXd q(n, 3);
  q.row(0).setZero();
  for (int i = 1; i < n; ++i)
    q.row(i) = q.row(i - 1) + Eigen::RowVector3d(std::abs(g(*rng)) + step, g(*rng), g(*rng));
  return q;
}

class ReallocationRandomTest : public ::testing::TestWithParam<int> {};

TEST_P(ReallocationRandomTest, VelocityAndAccelerationEndWithinLimits) {
  std::mt19937 rng(GetParam());
  const LimitsConfig limits;  // 3 m/s, 2 m/s^2
  const Eigen::MatrixXd q = RandomWalk(&rng, 12 + GetParam() % 20, 0.5);
  const auto input = quad_core::NonUniformBspline::Uniform(q, 3, 0.08 + 0.02 * (GetParam() % 5), 12.5);
  double v0, a0;
  MaxSampled(input, &v0, &a0);
  ASSERT_TRUE(v0 > 3.0 || a0 > 2.0) << "the input must violate a limit for the test to mean anything";
  const ReallocationResult r = ReallocateTime(input, limits, 20, 1.02);
  double v1, a1;
  MaxSampled(r.spline, &v1, &a1);
  EXPECT_LE(v1, 3.0 * (1 + 1e-9));
  EXPECT_LE(a1, 2.0 * (1 + 1e-9));
  EXPECT_LE(MaxVelocityRatio(r.spline, 3.0), 1.0 + 1e-9);
  EXPECT_LE(MaxAccelerationRatio(r.spline, 2.0), 1.0 + 1e-9);
  EXPECT_EQ(r.spline.ctrl_pts(), q);  // geometry comes from the same control points
  EXPECT_EQ(r.spline.tmin(), 0.0);
  EXPECT_GT(r.spline.duration(), input.duration());
  EXPECT_NEAR(r.max_vel_ratio_before, MaxVelocityRatio(input, 3.0), 1e-12);
}

INSTANTIATE_TEST_SUITE_P(Seeds, ReallocationRandomTest, ::testing::Range(1, 41));

class KeepStartTest : public ::testing::TestWithParam<int> {};

// The contract of StartPolicy::kKeep on random near-feasible inputs: whenever the start is kept, the start
// state is exactly the input's and the limits hold beyond the first two knot spans; when it is given up, the
// limits hold everywhere.
TEST_P(KeepStartTest, StartIsKeptExactlyOrGivenUpAndTheLimitsHold) {
  std::mt19937 rng(100 + GetParam());
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  // A feasible start state, then control points whose acceleration control points wander up to 20 % beyond
  // the limit (as an optimised spline's may, its feasibility cost being soft).
  const Eigen::Vector3d p0(u(rng), u(rng), u(rng));
  const Eigen::Vector3d v0 = Eigen::Vector3d(u(rng), u(rng), u(rng)).normalized() * 2.0;
  const Eigen::Vector3d a0 = Eigen::Vector3d(u(rng), u(rng), u(rng)).normalized() * 1.5;
  const double ts = 0.1 + 0.02 * (GetParam() % 4);
  Eigen::MatrixXd q(20, 3);
  q.topRows(3) = ControlPointsFromState(p0, v0, a0, ts);
  Eigen::Vector3d v_i = (q.row(2) - q.row(1)).transpose() / ts, a_i = a0;
  for (int i = 3; i < 20; ++i) {
    a_i =
        (a_i + 0.7 * Eigen::Vector3d(u(rng), u(rng), u(rng))).normalized() * std::min(2.4, a_i.norm() + 0.4);
    if (i == 3) a_i = a0;  // A_1: the optimiser's feasibility cost keeps it near the start's
    v_i += a_i * ts;
    q.row(i) = q.row(i - 1) + v_i.transpose() * ts;
  }
  const auto input = quad_core::NonUniformBspline::Uniform(q, 3, ts);
  const ReallocationResult r = ReallocateTime(input, LimitsConfig{}, 20, 1.02, StartPolicy::kKeep);
  ASSERT_TRUE(r.max_vel_ratio_before > 1.0 || r.max_acc_ratio_before > 1.0) << "nothing to re-allocate";
  const auto& s = r.spline;
  const auto vel = s.Derivative();
  const auto acc = s.Derivative(2);
  const double checked_from = r.start_kept ? s.knots()[5] : 0.0;
  for (double t = checked_from; t <= s.tmax(); t += 1e-3) {
    ASSERT_LE(vel.Evaluate(t).norm(), 3.0 * (1 + 1e-9)) << "t=" << t;
    ASSERT_LE(acc.Evaluate(t).norm(), 2.0 * (1 + 1e-9)) << "t=" << t;
  }
  EXPECT_EQ(s.ctrl_pts(), q);
  if (r.start_kept) {
    EXPECT_LT((s.Evaluate(0.0) - p0).norm(), 1e-9);
    EXPECT_LT((s.Derivative().Evaluate(0.0) - v0).norm(), 1e-9);
    EXPECT_LT((s.Derivative(2).Evaluate(0.0) - a0).norm(), 1e-8);
    EXPECT_NEAR(s.knots()[5] - s.knots()[3], 2 * ts, 1e-12);  // the spans that shape the start are untouched
  }
}

INSTANTIATE_TEST_SUITE_P(Seeds, KeepStartTest, ::testing::Range(1, 21));

TEST(ReallocationTest, ANearlyFeasibleSplineKeepsItsStartExactly) {
  // Cruising at 2 m/s, then a section 15 % too fast well after the start.
  const Eigen::Vector3d p(0, 0, 1), v(2.0, 0, 0), a(0.0, 1.0, 0);
  const double ts = 0.15;
  Eigen::MatrixXd q(16, 3);
  q.topRows(3) = ControlPointsFromState(p, v, a, ts);
  for (int i = 3; i < 16; ++i) {
    const double speed = i < 8 ? 2.0 : 3.45;
    q.row(i) = q.row(i - 1) + Eigen::RowVector3d(speed * ts, 0.0, 0.0);
  }
  const auto input = quad_core::NonUniformBspline::Uniform(q, 3, ts);
  const ReallocationResult r = ReallocateTime(input, LimitsConfig{}, 20, 1.02, StartPolicy::kKeep);
  ASSERT_TRUE(r.start_kept);
  EXPECT_LT((r.spline.Evaluate(0.0) - p).norm(), 1e-9);
  EXPECT_LT((r.spline.Derivative().Evaluate(0.0) - v).norm(), 1e-9);
  EXPECT_LT((r.spline.Derivative(2).Evaluate(0.0) - a).norm(), 1e-9);
  double v1, a1;
  MaxSampled(r.spline, &v1, &a1);
  EXPECT_LE(v1, 3.0 * (1 + 1e-9));
  EXPECT_LE(a1, 2.0 * (1 + 1e-9));
}

TEST(ReallocationTest, AStartThatCannotBeKeptIsGivenUpAndTheLimitsStillHold) {
  // The control point after the start turns at 4 m/s^2 (A_1): only the spans the start state fixes could slow
  // that turn down.
  const Eigen::Vector3d p(0, 0, 1), v(2.5, 0, 0), a(0.0, 0.0, 0.0);
  const double ts = 0.15;
  Eigen::MatrixXd q(12, 3);
  q.topRows(3) = ControlPointsFromState(p, v, a, ts);
  q.row(3) = 2 * q.row(2) - q.row(1) + Eigen::RowVector3d(0.0, 4.0, 0.0) * ts * ts;
  for (int i = 4; i < 12; ++i) q.row(i) = 2 * q.row(i - 1) - q.row(i - 2);
  const auto input = quad_core::NonUniformBspline::Uniform(q, 3, ts);
  const ReallocationResult r = ReallocateTime(input, LimitsConfig{}, 20, 1.02, StartPolicy::kKeep);
  EXPECT_FALSE(r.start_kept);
  double v1, a1;
  MaxSampled(r.spline, &v1, &a1);
  EXPECT_LE(v1, 3.0 * (1 + 1e-9));
  EXPECT_LE(a1, 2.0 * (1 + 1e-9));
}

TEST(ReallocationTest, FeasibleSplineIsOnlyShiftedToStartAtZero) {
  std::mt19937 rng(3);
  const Eigen::MatrixXd q = RandomWalk(&rng, 10, 0.1);
  const auto input = quad_core::NonUniformBspline::Uniform(q, 3, 1.0, 4.0);
  ASSERT_LE(MaxVelocityRatio(input, 3.0), 1.0);
  ASSERT_LE(MaxAccelerationRatio(input, 2.0), 1.0);
  const ReallocationResult r = ReallocateTime(input, LimitsConfig{}, 20, 1.02);
  EXPECT_EQ(r.iterations, 0);
  EXPECT_FALSE(r.used_uniform_fallback);
  EXPECT_NEAR(r.spline.duration(), input.duration(), 1e-12);
  EXPECT_EQ(r.spline.tmin(), 0.0);
}

TEST(ReallocationTest, OneFastSectionIsSlowedLocallyNotTheWholeSpline) {
  // Slow everywhere except one long jump in the middle.
  Eigen::MatrixXd q(20, 3);
  for (int i = 0; i < 20; ++i) q.row(i) << 0.1 * i + (i >= 10 ? 2.0 : 0.0), 0.0, 0.0;
  const auto input = quad_core::NonUniformBspline::Uniform(q, 3, 0.2);
  const ReallocationResult r = ReallocateTime(input, LimitsConfig{}, 20, 1.02);
  ASSERT_FALSE(r.used_uniform_fallback);
  double v1, a1;
  MaxSampled(r.spline, &v1, &a1);
  EXPECT_LE(v1, 3.0 * (1 + 1e-9));
  EXPECT_LE(a1, 2.0 * (1 + 1e-9));
  // Uniform slowing by the worst ratio would take far longer.
  const double uniform =
      input.duration() * std::max(MaxVelocityRatio(input, 3.0), std::sqrt(MaxAccelerationRatio(input, 2.0)));
  EXPECT_LT(r.spline.duration(), 0.8 * uniform);
}

TEST(ReallocationTest, UniformFallbackStillMeetsTheLimits) {
  std::mt19937 rng(8);
  const Eigen::MatrixXd q = RandomWalk(&rng, 15, 1.0);
  const auto input = quad_core::NonUniformBspline::Uniform(q, 3, 0.02);
  const ReallocationResult r = ReallocateTime(input, LimitsConfig{}, 1, 1.02);
  EXPECT_TRUE(r.used_uniform_fallback);
  double v1, a1;
  MaxSampled(r.spline, &v1, &a1);
  EXPECT_LE(v1, 3.0 * (1 + 1e-9));
  EXPECT_LE(a1, 2.0 * (1 + 1e-9));
}

TEST(ReallocationTest, BadArgumentsThrow) {
  Eigen::MatrixXd q = Eigen::MatrixXd::Random(5, 3);
  const auto linear = quad_core::NonUniformBspline::Uniform(q, 1, 0.1);
  EXPECT_THROW(ReallocateTime(linear, LimitsConfig{}, 5, 1.02), std::invalid_argument);
  const auto cubic = quad_core::NonUniformBspline::Uniform(q, 3, 0.1);
  EXPECT_THROW(ReallocateTime(cubic, LimitsConfig{}, 5, 0.9), std::invalid_argument);
}

}  // namespace
}  // namespace fast_planner
