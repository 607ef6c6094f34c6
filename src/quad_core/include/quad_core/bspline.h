// Non-uniform B-splines of any degree (ROS-free), shared by the tracker and the planner.
//
// A B-spline of degree p ("order" in Fast-Planner's Bspline.msg, which we keep) with N control points
// P_0..P_{N-1} (rows of an N x D matrix) has N + p + 1 non-decreasing knots u_0..u_{N+p}. It is evaluated
// with de Boor's algorithm on its valid domain [u_p, u_N], where the basis functions sum to one. Derivatives
// are B-splines of degree p - 1 whose control points are p (P_{i+1} - P_i) / (u_{i+p+1} - u_{i+1}) on the
// knots u_1..u_{N+p-1} (Piegl & Tiller, The NURBS Book, eq. 3.8); their valid domain is the same [u_p, u_N].
#pragma once

#include <Eigen/Dense>

#include <string>
#include <vector>

namespace quad_core {

// Why a B-spline description is malformed, or "" when it is fine. Checks, in this order: degree >= 1 (a
// degree-0 spline is not a trajectory), at least degree + 1 control points, knot count == control points +
// degree + 1, finite knots, non-decreasing knots, a valid domain of positive length. Used for goals received
// over the wire.
std::string ValidateBspline(int order, const std::vector<double>& knots, int num_ctrl_pts);
// The same plus finite control points (rows of ctrl_pts).
std::string ValidateBspline(int order, const std::vector<double>& knots, const Eigen::MatrixXd& ctrl_pts);

class NonUniformBspline {
 public:
  // ctrl_pts: N x D, one row per control point. order: degree p >= 0. knots: N + p + 1 non-decreasing values
  // with knots[N] > knots[p]. Throws std::invalid_argument naming the problem (NaN/Inf included).
  NonUniformBspline(const Eigen::MatrixXd& ctrl_pts, int order, const std::vector<double>& knots);

  // Uniform knots u_i = t0_s + (i - p) dt_s, i = 0..N+p (as Fast-Planner's uniform B-spline): the valid
  // domain is [t0_s, t0_s + (N - p) dt_s]. Throws std::invalid_argument if dt_s <= 0 or N <= p.
  static NonUniformBspline Uniform(const Eigen::MatrixXd& ctrl_pts, int order, double dt_s,
                                   double t0_s = 0.0);

  // Value at t (de Boor); t is clamped to [tmin(), tmax()]. NaN t throws std::invalid_argument.
  Eigen::VectorXd Evaluate(double t) const;

  // The derivative as a B-spline of degree order() - 1 on the same valid domain. For degree 0 the derivative
  // is zero almost everywhere: a degree-0 spline with zero control points on the same knots is returned.
  NonUniformBspline Derivative() const;
  // The k-th derivative (k >= 0; k = 0 is a copy).
  NonUniformBspline Derivative(int k) const;

  double tmin() const { return knots_[order_]; }
  double tmax() const { return knots_[num_ctrl_pts()]; }
  double duration() const { return tmax() - tmin(); }

  const Eigen::MatrixXd& ctrl_pts() const { return ctrl_pts_; }
  const std::vector<double>& knots() const { return knots_; }
  int order() const { return order_; }
  int num_ctrl_pts() const { return static_cast<int>(ctrl_pts_.rows()); }
  int dim() const { return static_cast<int>(ctrl_pts_.cols()); }

  // Bounds by the convex-hull property: the largest Euclidean norm and the largest absolute coordinate among
  // the control points that influence the valid domain. Applied to Derivative(), they bound speed and
  // acceleration.
  double MaxCtrlPtNorm() const;
  double MaxCtrlPtAbs() const;

  // The same curve flown `factor` times slower (factor > 1) or faster (< 1): knots are stretched about
  // tmin(), so the k-th derivative scales by factor^-k. Throws std::invalid_argument if factor is not
  // positive and finite.
  NonUniformBspline TimeScaled(double factor) const;

  // The same curve with the parameter shifted by dt_s (all knots + dt_s).
  NonUniformBspline TimeShifted(double dt_s) const;

  // Arc length over [tmin(), tmax()] by composite Simpson integration of the speed on each knot span
  // (samples_per_span >= 2, even).
  double Length(int samples_per_span = 16) const;

 private:
  // The knot span index k in [p, N - 1] with knots[k] <= t < knots[k + 1] (t already clamped).
  int FindSpan(double t) const;

  Eigen::MatrixXd ctrl_pts_;
  int order_;
  std::vector<double> knots_;
};

}  // namespace quad_core
