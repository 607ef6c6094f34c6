// B-spline library: de Boor values against closed forms and an independent Cox-de Boor basis, derivatives
// against finite differences for several degrees and random non-uniform knots, and input validation.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>

#include "quad_core/bspline.h"

namespace quad_core {
namespace {

// Cox-de Boor recursion for the basis function N_{i,p}(t) (0/0 := 0), independent of the de Boor code under
// test.
double Basis(int i, int p, double t, const std::vector<double>& u) {
  if (p == 0) {
    // Half-open spans, except that t equal to the last non-empty knot belongs to the span ending there.
    return (u[i] <= t && t < u[i + 1]) ? 1.0 : 0.0;
  }
  double a = 0.0;
  double b = 0.0;
  if (u[i + p] > u[i]) a = (t - u[i]) / (u[i + p] - u[i]) * Basis(i, p - 1, t, u);
  if (u[i + p + 1] > u[i + 1]) b = (u[i + p + 1] - t) / (u[i + p + 1] - u[i + 1]) * Basis(i + 1, p - 1, t, u);
  return a + b;
}

Eigen::VectorXd EvaluateByBasis(const Eigen::MatrixXd& pts, int p, const std::vector<double>& u, double t) {
  Eigen::VectorXd out = Eigen::VectorXd::Zero(pts.cols());
  for (int i = 0; i < pts.rows(); ++i) out += Basis(i, p, t, u) * pts.row(i).transpose();
  return out;
}

std::vector<double> RandomKnots(int count, std::mt19937* rng) {
  std::uniform_real_distribution<double> gap(0.05, 1.0);
  std::vector<double> u(static_cast<size_t>(count));
  u[0] = -0.7;
  for (int i = 1; i < count; ++i) u[i] = u[i - 1] + gap(*rng);
  return u;
}

Eigen::MatrixXd RandomPoints(int n, int dim, std::mt19937* rng) {
  std::uniform_real_distribution<double> coord(-3.0, 3.0);
  Eigen::MatrixXd pts(n, dim);
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < dim; ++j) pts(i, j) = coord(*rng);
  return pts;
}

TEST(BsplineValues, UniformCubicMatchesClosedFormAtKnotsAndMidpoints) {
  Eigen::MatrixXd pts(5, 2);
  pts << 0, 0, 1, 2, 3, 1, 4, 4, 6, 2;
  const double dt = 0.5;
  const auto s = NonUniformBspline::Uniform(pts, 3, dt, 2.0);
  EXPECT_DOUBLE_EQ(s.tmin(), 2.0);
  EXPECT_DOUBLE_EQ(s.tmax(), 2.0 + 2 * dt);
  EXPECT_DOUBLE_EQ(s.duration(), 2 * dt);
  ASSERT_EQ(s.knots().size(), 9u);
  EXPECT_DOUBLE_EQ(s.knots()[0], 2.0 - 3 * dt);
  for (int seg = 0; seg < 2; ++seg) {
    const Eigen::RowVectorXd p0 = pts.row(seg), p1 = pts.row(seg + 1), p2 = pts.row(seg + 2),
                             p3 = pts.row(seg + 3);
    // At a knot: (P0 + 4 P1 + P2) / 6; at mid-span: (P0 + 23 P1 + 23 P2 + P3) / 48.
    const Eigen::RowVectorXd at_knot = (p0 + 4 * p1 + p2) / 6.0;
    const Eigen::RowVectorXd at_mid = (p0 + 23 * p1 + 23 * p2 + p3) / 48.0;
    EXPECT_TRUE(s.Evaluate(2.0 + seg * dt).transpose().isApprox(at_knot, 1e-12)) << seg;
    EXPECT_TRUE(s.Evaluate(2.0 + (seg + 0.5) * dt).transpose().isApprox(at_mid, 1e-12)) << seg;
    // Velocity (P2 - P0) / (2 dt) and acceleration (P0 - 2 P1 + P2) / dt^2 at the knot.
    const Eigen::RowVectorXd v = (p2 - p0) / (2 * dt);
    const Eigen::RowVectorXd a = (p0 - 2 * p1 + p2) / (dt * dt);
    EXPECT_TRUE(s.Derivative().Evaluate(2.0 + seg * dt).transpose().isApprox(v, 1e-12)) << seg;
    EXPECT_TRUE(s.Derivative(2).Evaluate(2.0 + seg * dt).transpose().isApprox(a, 1e-12)) << seg;
    // Jerk of a uniform cubic is constant per span: (-P0 + 3 P1 - 3 P2 + P3) / dt^3.
    const Eigen::RowVectorXd j = (-p0 + 3 * p1 - 3 * p2 + p3) / (dt * dt * dt);
    EXPECT_TRUE(s.Derivative(3).Evaluate(2.0 + (seg + 0.3) * dt).transpose().isApprox(j, 1e-9)) << seg;
  }
  // The end of the domain is the knot formula of the last span.
  const Eigen::RowVectorXd at_end = (pts.row(2) + 4 * pts.row(3) + pts.row(4)) / 6.0;
  EXPECT_TRUE(s.Evaluate(s.tmax()).transpose().isApprox(at_end, 1e-12));
}

TEST(BsplineValues, EvaluationIsClampedToTheValidDomain) {
  Eigen::MatrixXd pts(4, 1);
  pts << 0, 1, 5, 2;
  const auto s = NonUniformBspline::Uniform(pts, 3, 1.0);
  EXPECT_DOUBLE_EQ(s.Evaluate(-10.0)(0), s.Evaluate(s.tmin())(0));
  EXPECT_DOUBLE_EQ(s.Evaluate(99.0)(0), s.Evaluate(s.tmax())(0));
  EXPECT_THROW(s.Evaluate(std::numeric_limits<double>::quiet_NaN()), std::invalid_argument);
}

TEST(BsplineValues, NonUniformAnyDegreeMatchesCoxDeBoorBasis) {
  std::mt19937 rng(7);
  for (int p = 0; p <= 6; ++p) {
    const int n = p + 1 + 5;
    const auto u = RandomKnots(n + p + 1, &rng);
    const Eigen::MatrixXd pts = RandomPoints(n, 3, &rng);
    const NonUniformBspline s(pts, p, u);
    std::uniform_real_distribution<double> t_dist(s.tmin(), s.tmax());
    for (int k = 0; k < 50; ++k) {
      const double t = t_dist(rng);
      EXPECT_TRUE(s.Evaluate(t).isApprox(EvaluateByBasis(pts, p, u, t), 1e-10)) << "p=" << p << " t=" << t;
    }
  }
}

TEST(BsplineValues, BasisIsAPartitionOfUnityOnTheValidDomain) {
  std::mt19937 rng(11);
  for (int p = 1; p <= 5; ++p) {
    const int n = p + 4;
    const Eigen::MatrixXd pts = Eigen::MatrixXd::Constant(n, 2, 1.25);
    const NonUniformBspline s(pts, p, RandomKnots(n + p + 1, &rng));
    for (double f : {0.0, 0.1, 0.5, 0.77, 1.0}) {
      EXPECT_NEAR(s.Evaluate(s.tmin() + f * s.duration())(0), 1.25, 1e-12) << p;
    }
  }
}

TEST(BsplineValues, ClampedKnotsInterpolateTheEndPointsAndRepeatedInnerKnotsWork) {
  Eigen::MatrixXd pts(6, 2);
  pts << 0, 0, 1, 3, 2, -1, 4, 4, 5, 0, 7, 2;
  // Cubic, clamped at both ends, with a double inner knot.
  const std::vector<double> u = {0, 0, 0, 0, 1, 1, 3, 3, 3, 3};
  const NonUniformBspline s(pts, 3, u);
  EXPECT_TRUE(s.Evaluate(0.0).isApprox(pts.row(0).transpose(), 1e-12));
  EXPECT_TRUE(s.Evaluate(3.0).isApprox(pts.row(5).transpose(), 1e-12));
  for (double t : {0.3, 0.999, 1.0, 1.5, 2.9}) {
    EXPECT_TRUE(s.Evaluate(t).isApprox(EvaluateByBasis(pts, 3, u, t), 1e-10)) << t;
  }
}

// Central differences of order 2 at interior points away from knots (where derivatives are smooth).
TEST(BsplineDerivatives, MatchFiniteDifferencesForDegreesOneToSixOnRandomKnots) {
  std::mt19937 rng(3);
  const double h = 1e-6;
  for (int p = 1; p <= 6; ++p) {
    const int n = p + 6;
    const auto u = RandomKnots(n + p + 1, &rng);
    const NonUniformBspline s(RandomPoints(n, 3, &rng), p, u);
    for (int d = 1; d <= p; ++d) {
      const NonUniformBspline lower = s.Derivative(d - 1);
      const NonUniformBspline deriv = s.Derivative(d);
      EXPECT_EQ(deriv.order(), p - d);
      EXPECT_DOUBLE_EQ(deriv.tmin(), s.tmin());
      EXPECT_DOUBLE_EQ(deriv.tmax(), s.tmax());
      std::uniform_real_distribution<double> t_dist(s.tmin() + 2 * h, s.tmax() - 2 * h);
      int checked = 0;
      while (checked < 20) {
        const double t = t_dist(rng);
        bool near_knot = false;
        for (double k : u) near_knot = near_knot || std::fabs(t - k) < 1e-4;
        if (near_knot) continue;
        const Eigen::VectorXd fd = (lower.Evaluate(t + h) - lower.Evaluate(t - h)) / (2 * h);
        const Eigen::VectorXd an = deriv.Evaluate(t);
        EXPECT_LT((fd - an).norm(), 1e-5 * (1.0 + an.norm())) << "p=" << p << " d=" << d << " t=" << t;
        ++checked;
      }
    }
  }
}

TEST(BsplineDerivatives, DegreeZeroDerivativeIsZero) {
  Eigen::MatrixXd pts(3, 1);
  pts << 1, 2, 3;
  const NonUniformBspline s(pts, 0, {0.0, 1.0, 2.0, 3.0});
  EXPECT_DOUBLE_EQ(s.Evaluate(1.5)(0), 2.0);
  const auto d = s.Derivative();
  EXPECT_EQ(d.order(), 0);
  EXPECT_DOUBLE_EQ(d.Evaluate(1.5)(0), 0.0);
}

TEST(BsplineHelpers, TimeScalingDividesTheKthDerivativeByFactorToTheK) {
  std::mt19937 rng(5);
  const NonUniformBspline s(RandomPoints(8, 3, &rng), 3, RandomKnots(12, &rng));
  const double f = 1.7;
  const auto slow = s.TimeScaled(f);
  EXPECT_DOUBLE_EQ(slow.tmin(), s.tmin());
  EXPECT_NEAR(slow.duration(), f * s.duration(), 1e-12);
  for (double x : {0.1, 0.45, 0.9}) {
    const double t = s.tmin() + x * s.duration();
    const double ts = slow.tmin() + x * slow.duration();
    EXPECT_TRUE(slow.Evaluate(ts).isApprox(s.Evaluate(t), 1e-10));
    EXPECT_TRUE(slow.Derivative().Evaluate(ts).isApprox(s.Derivative().Evaluate(t) / f, 1e-10));
    EXPECT_TRUE(slow.Derivative(2).Evaluate(ts).isApprox(s.Derivative(2).Evaluate(t) / (f * f), 1e-10));
  }
  EXPECT_THROW(s.TimeScaled(0.0), std::invalid_argument);
  const auto shifted = s.TimeShifted(2.5);
  EXPECT_TRUE(shifted.Evaluate(s.tmin() + 2.5 + 0.3).isApprox(s.Evaluate(s.tmin() + 0.3), 1e-12));
}

TEST(BsplineHelpers, ControlPointBoundsBoundSampledSpeedAndLengthOfAStraightLine) {
  std::mt19937 rng(9);
  const NonUniformBspline s(RandomPoints(9, 3, &rng), 4, RandomKnots(14, &rng));
  const auto vel = s.Derivative();
  const double bound = vel.MaxCtrlPtNorm();
  const double bound_abs = vel.MaxCtrlPtAbs();
  for (int i = 0; i <= 200; ++i) {
    const Eigen::VectorXd v = vel.Evaluate(s.tmin() + i * s.duration() / 200);
    EXPECT_LE(v.norm(), bound + 1e-9);
    EXPECT_LE(v.cwiseAbs().maxCoeff(), bound_abs + 1e-9);
  }
  // Collinear, evenly spaced control points on a uniform spline: a straight segment of known length.
  Eigen::MatrixXd line(6, 3);
  for (int i = 0; i < 6; ++i) line.row(i) << i * 1.0, i * 2.0, 0.0;
  const auto l = NonUniformBspline::Uniform(line, 3, 0.4);
  const double expected = (l.Evaluate(l.tmax()) - l.Evaluate(l.tmin())).norm();
  EXPECT_NEAR(l.Length(), expected, 1e-9);
}

TEST(BsplineValidation, ReportsEachMalformedCaseWithItsReason) {
  const Eigen::MatrixXd pts = Eigen::MatrixXd::Zero(5, 3);
  const std::vector<double> good = {0, 1, 2, 3, 4, 5, 6, 7, 8};
  EXPECT_EQ(ValidateBspline(3, good, pts), "");
  EXPECT_NE(ValidateBspline(0, {0, 1, 2, 3, 4, 5}, 5).find("order (degree) 0 is below 1"), std::string::npos);
  EXPECT_NE(ValidateBspline(-2, good, 5).find("below 1"), std::string::npos);
  EXPECT_NE(
      ValidateBspline(3, {0, 1, 2, 3, 4, 5, 6, 7}, 5).find("knot count 8 != control points + order + 1"),
      std::string::npos);
  EXPECT_NE(ValidateBspline(3, {0, 1, 2, 3, 4, 3.5, 6, 7, 8}, 5).find("not non-decreasing: knot 5"),
            std::string::npos);
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  EXPECT_NE(ValidateBspline(3, {0, 1, 2, nan, 4, 5, 6, 7, 8}, 5).find("knot 3 is not finite"),
            std::string::npos);
  EXPECT_NE(ValidateBspline(3, {0, 1, 2, 3, 4, 5, 6, 7, inf}, 5).find("knot 8 is not finite"),
            std::string::npos);
  Eigen::MatrixXd bad = pts;
  bad(2, 1) = nan;
  EXPECT_NE(ValidateBspline(3, good, bad).find("control point 2 is not finite"), std::string::npos);
  EXPECT_NE(
      ValidateBspline(3, {0, 1, 2, 3, 4, 5, 6}, 3).find("3 control points are fewer than order + 1 = 4"),
      std::string::npos);
  EXPECT_NE(ValidateBspline(3, {0, 0, 0, 0, 0, 0, 0, 0, 0}, 5).find("empty valid domain"), std::string::npos);
}

TEST(BsplineValidation, ConstructorAndUniformThrowNamingTheProblem) {
  const Eigen::MatrixXd pts = Eigen::MatrixXd::Zero(5, 3);
  try {
    NonUniformBspline(pts, 3, {0, 1, 2, 3});
    FAIL() << "no exception";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("knot count 4"), std::string::npos) << e.what();
  }
  EXPECT_THROW(NonUniformBspline::Uniform(pts, 3, 0.0), std::invalid_argument);
  EXPECT_THROW(NonUniformBspline::Uniform(pts, 3, -1.0), std::invalid_argument);
  EXPECT_THROW(NonUniformBspline::Uniform(pts, 5, 0.1), std::invalid_argument);  // 5 points, degree 5
  Eigen::MatrixXd inf_pts = pts;
  inf_pts(0, 0) = std::numeric_limits<double>::infinity();
  EXPECT_THROW(NonUniformBspline::Uniform(inf_pts, 3, 0.1), std::invalid_argument);
}

}  // namespace
}  // namespace quad_core
