#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <optional>
#include <random>

#include "quad_policy/trajectory.h"

namespace quad_policy {
namespace {

UniformBspline RandomSpline(uint64_t seed, int k = 10, double dt = 0.25) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-3.0, 3.0);
  UniformBspline s;
  s.start_time_s = 7.0;
  s.knot_dt_s = dt;
  s.ctrl_world.resize(k, 3);
  for (int i = 0; i < k; ++i) {
    for (int j = 0; j < 3; ++j) s.ctrl_world(i, j) = u(rng);
  }
  return s;
}

TEST(UniformBspline, KnotsAreUniformWithTheDomainStartingAtKnotThree) {
  const UniformBspline s = RandomSpline(1);
  const std::vector<double> k = s.Knots();
  ASSERT_EQ(k.size(), 14u);  // control points + order + 1
  EXPECT_DOUBLE_EQ(k[3], 0.0);
  EXPECT_DOUBLE_EQ(k[10], s.duration_s());
  for (std::size_t i = 1; i < k.size(); ++i) EXPECT_NEAR(k[i] - k[i - 1], 0.25, 1e-12);
}

TEST(UniformBspline, DerivativesMatchFiniteDifferences) {
  const UniformBspline s = RandomSpline(2);
  const double h = 1e-5;
  for (double t = 0.01; t < s.duration_s() - 0.01; t += 0.0913) {
    const Eigen::Vector3d v_fd = (s.Position(t + h) - s.Position(t - h)) / (2 * h);
    const Eigen::Vector3d a_fd = (s.Velocity(t + h) - s.Velocity(t - h)) / (2 * h);
    EXPECT_LT((s.Velocity(t) - v_fd).norm(), 1e-6) << "t = " << t;
    EXPECT_LT((s.Acceleration(t) - a_fd).norm(), 1e-5) << "t = " << t;
  }
}

TEST(UniformBspline, ReproducesACubicFromGrevilleControlPoints) {
  // c_i = P(tau_i) - dt^2 / 6 P''(tau_i) at tau_i = (i - 1) dt (the polar form of a cubic at uniform knots).
  const auto P = [](double t) { return Eigen::Vector3d(1 + 2 * t - t * t + 0.5 * t * t * t, -t * t, 3 * t); };
  const auto P2 = [](double t) { return Eigen::Vector3d(-2 + 3 * t, -2, 0); };
  UniformBspline s;
  s.knot_dt_s = 0.3;
  s.ctrl_world.resize(8, 3);
  for (int i = 0; i < 8; ++i) {
    const double tau = (i - 1) * s.knot_dt_s;
    s.ctrl_world.row(i) = (P(tau) - s.knot_dt_s * s.knot_dt_s / 6 * P2(tau)).transpose();
  }
  for (double t = 0.0; t <= s.duration_s(); t += 0.05) EXPECT_LT((s.Position(t) - P(t)).norm(), 1e-12);
}

TEST(UniformBspline, DerivativeControlPointsBoundSpeedAndAcceleration) {
  const UniformBspline s = RandomSpline(4);
  double vmax = 0, amax = 0;
  for (int i = 0; i < s.VelocityCtrlPts().rows(); ++i)
    vmax = std::max(vmax, s.VelocityCtrlPts().row(i).norm());
  for (int i = 0; i < s.AccelerationCtrlPts().rows(); ++i) {
    amax = std::max(amax, s.AccelerationCtrlPts().row(i).norm());
  }
  for (double t = 0.0; t <= s.duration_s(); t += 0.01) {
    EXPECT_LE(s.Velocity(t).norm(), vmax + 1e-9);
    EXPECT_LE(s.Acceleration(t).norm(), amax + 1e-9);
  }
}

TEST(BrakingTrajectory, StartsAtTheStateAndStopsWithinTheDecelerationLimit) {
  const Eigen::Vector3d p0(1.0, 2.0, 1.5), v0(3.0, -1.0, 0.5);
  const double decel = 2.5;
  const UniformBspline s = BrakingTrajectory(p0, v0, decel, 0.5, 12.0);
  EXPECT_EQ(s.num_ctrl_pts(), 4);
  EXPECT_DOUBLE_EQ(s.start_time_s, 12.0);
  EXPECT_NEAR(s.duration_s(), 2.0 * v0.norm() / decel, 1e-12);
  EXPECT_LT((s.Position(0.0) - p0).norm(), 1e-12);
  EXPECT_LT((s.Velocity(0.0) - v0).norm(), 1e-12);
  EXPECT_LT(s.Velocity(s.duration_s()).norm(), 1e-12);
  // Stops after |v0| T / 3 along the initial direction.
  EXPECT_LT((s.Position(s.duration_s()) - (p0 + v0 * s.duration_s() / 3)).norm(), 1e-12);
  for (double t = 0.0; t <= s.duration_s(); t += 0.01) {
    EXPECT_LE(s.Acceleration(t).norm(), decel + 1e-9);
    EXPECT_GE(s.Velocity(t).dot(v0), -1e-12);  // never reverses
  }
}

TEST(BrakingTrajectory, AtRestHoldsThePositionForTheMinimumDuration) {
  const UniformBspline s =
      BrakingTrajectory(Eigen::Vector3d(1, 1, 1), Eigen::Vector3d::Zero(), 2.0, 0.5, 0.0);
  EXPECT_DOUBLE_EQ(s.duration_s(), 0.5);
  for (int i = 0; i < 4; ++i) EXPECT_LT((s.ctrl_world.row(i) - Eigen::RowVector3d(1, 1, 1)).norm(), 1e-15);
}

TEST(BrakingTrajectory, RejectsNonFiniteStatesAndBadLimits) {
  EXPECT_THROW(BrakingTrajectory(Eigen::Vector3d(NAN, 0, 0), Eigen::Vector3d::Zero(), 2.0, 0.5, 0.0),
               std::invalid_argument);
  EXPECT_THROW(BrakingTrajectory(Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero(), 0.0, 0.5, 0.0),
               std::invalid_argument);
}

TEST(FinalApproach, EndsAtRestOnTheGoalWithinTheAccelerationLimit) {
  const Eigen::Vector3d p0(1, 2, 1.5), v0(1.5, -0.5, 0.8), goal(1.6, 2.8, 2.3);
  const std::optional<UniformBspline> s = FinalApproach(p0, v0, goal, 2.0, 0.5, 4.0);
  ASSERT_TRUE(s.has_value());
  ASSERT_EQ(s->num_ctrl_pts(), 4);
  const double T = s->knot_dt_s;
  EXPECT_GE(T, 0.5);
  EXPECT_DOUBLE_EQ(s->start_time_s, 4.0);
  EXPECT_NEAR((s->Position(0.0) - p0).norm(), 0.0, 1e-12);
  EXPECT_NEAR((s->Velocity(0.0) - v0).norm(), 0.0, 1e-12);
  EXPECT_NEAR((s->Position(T) - goal).norm(), 0.0, 1e-12);
  EXPECT_NEAR(s->Velocity(T).norm(), 0.0, 1e-12);
  double peak = 0.0;
  for (int i = 0; i <= 100; ++i) peak = std::max(peak, s->Acceleration(T * i / 100.0).norm());
  EXPECT_LE(peak, 2.0 + 1e-9);
  // The first duration on the 0.02 s grid: 0.02 s shorter exceeds the limit at an end.
  const double shorter = T - 0.02;
  ASSERT_GT(shorter, 0.5);
  const Eigen::Vector3d b = goal - p0 - v0 * (shorter / 3.0);
  EXPECT_GT(std::max((-2.0 * v0 / shorter + 6.0 * b / (shorter * shorter)).norm(),
                     (6.0 * b / (shorter * shorter)).norm()),
            2.0);
  // At rest 5 cm from the goal (6 * 0.05 / 0.5^2 = 1.2 m/s^2): the minimum duration.
  EXPECT_DOUBLE_EQ(
      FinalApproach(p0, Eigen::Vector3d::Zero(), p0 + Eigen::Vector3d(0.05, 0, 0), 2.0, 0.5, 0.0)->knot_dt_s,
      0.5);
  // 5 m/s away from a goal 1 m behind with 1e-4 m/s^2: no duration up to 40 s turns it round.
  EXPECT_FALSE(FinalApproach(Eigen::Vector3d::Zero(), Eigen::Vector3d(5, 0, 0), Eigen::Vector3d(-1, 0, 0),
                             1e-4, 0.5, 0.0)
                   .has_value());
  EXPECT_THROW(FinalApproach(p0, v0, Eigen::Vector3d(NAN, 0, 0), 2.0, 0.5, 0.0), std::invalid_argument);
  EXPECT_THROW(FinalApproach(p0, v0, goal, 0.0, 0.5, 0.0), std::invalid_argument);
}

TEST(PolicyTrajectory, UsesTheMetadataHorizon) {
  PolicyMeta m;
  m.num_ctrl_pts = 10;
  m.horizon_s = 2.1;
  const UniformBspline s = PolicyTrajectory(CtrlPoints::Zero(10, 3), m, 4.0);
  EXPECT_DOUBLE_EQ(s.knot_dt_s, 0.3);
  EXPECT_DOUBLE_EQ(s.duration_s(), 2.1);
  EXPECT_THROW(PolicyTrajectory(CtrlPoints::Zero(9, 3), m, 4.0), std::invalid_argument);
}

}  // namespace
}  // namespace quad_policy
