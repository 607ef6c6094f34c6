#include "quad_core/bspline.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace quad_core {
namespace {

// Shared checks of the constructor (degree >= 0 allowed: derivatives of linear splines) and of wire goals
// (degree >= 1).
std::string CheckStructure(int order, const std::vector<double>& knots, int num_ctrl_pts, int min_order) {
  std::ostringstream why;
  if (order < min_order) {
    why << "order (degree) " << order << " is below " << min_order;
    return why.str();
  }
  if (num_ctrl_pts < order + 1) {
    why << num_ctrl_pts << " control points are fewer than order + 1 = " << order + 1;
    return why.str();
  }
  const size_t expected = static_cast<size_t>(num_ctrl_pts) + static_cast<size_t>(order) + 1;
  if (knots.size() != expected) {
    why << "knot count " << knots.size() << " != control points + order + 1 = " << num_ctrl_pts << " + "
        << order << " + 1 = " << expected;
    return why.str();
  }
  for (size_t i = 0; i < knots.size(); ++i) {
    if (!std::isfinite(knots[i])) {
      why << "knot " << i << " is not finite (" << knots[i] << ")";
      return why.str();
    }
  }
  for (size_t i = 1; i < knots.size(); ++i) {
    if (knots[i] < knots[i - 1]) {
      why << "knots are not non-decreasing: knot " << i << " = " << knots[i] << " < knot " << i - 1 << " = "
          << knots[i - 1];
      return why.str();
    }
  }
  if (!(knots[num_ctrl_pts] > knots[order])) {
    why << "empty valid domain: knot " << order << " = " << knots[order] << " is not below knot "
        << num_ctrl_pts << " = " << knots[num_ctrl_pts];
    return why.str();
  }
  return "";
}

std::string CheckFinite(const Eigen::MatrixXd& ctrl_pts) {
  for (int i = 0; i < ctrl_pts.rows(); ++i) {
    if (!ctrl_pts.row(i).allFinite()) {
      std::ostringstream why;
      why << "control point " << i << " is not finite (" << ctrl_pts.row(i) << ")";
      return why.str();
    }
  }
  return "";
}

}  // namespace

std::string ValidateBspline(int order, const std::vector<double>& knots, int num_ctrl_pts) {
  return CheckStructure(order, knots, num_ctrl_pts, 1);
}

std::string ValidateBspline(int order, const std::vector<double>& knots, const Eigen::MatrixXd& ctrl_pts) {
  const std::string s = CheckStructure(order, knots, static_cast<int>(ctrl_pts.rows()), 1);
  return s.empty() ? CheckFinite(ctrl_pts) : s;
}

NonUniformBspline::NonUniformBspline(const Eigen::MatrixXd& ctrl_pts, int order,
                                     const std::vector<double>& knots)
    : ctrl_pts_(ctrl_pts), order_(order), knots_(knots) {
  if (ctrl_pts.cols() < 1) throw std::invalid_argument("NonUniformBspline: control points have 0 columns");
  std::string why = CheckStructure(order, knots, static_cast<int>(ctrl_pts.rows()), 0);
  if (why.empty()) why = CheckFinite(ctrl_pts);
  if (!why.empty()) throw std::invalid_argument("NonUniformBspline: " + why);
}

NonUniformBspline NonUniformBspline::Uniform(const Eigen::MatrixXd& ctrl_pts, int order, double dt_s,
                                             double t0_s) {
  if (!(dt_s > 0.0) || !std::isfinite(dt_s)) {
    std::ostringstream why;
    why << "NonUniformBspline::Uniform: knot interval dt_s = " << dt_s << " must be positive and finite";
    throw std::invalid_argument(why.str());
  }
  if (!std::isfinite(t0_s)) throw std::invalid_argument("NonUniformBspline::Uniform: t0_s is not finite");
  if (order < 0) throw std::invalid_argument("NonUniformBspline::Uniform: negative order");
  const int n = static_cast<int>(ctrl_pts.rows());
  std::vector<double> knots(static_cast<size_t>(n + order + 1));
  for (int i = 0; i < n + order + 1; ++i) knots[static_cast<size_t>(i)] = t0_s + (i - order) * dt_s;
  return NonUniformBspline(ctrl_pts, order, knots);
}

int NonUniformBspline::FindSpan(double t) const {
  const int n = num_ctrl_pts();
  // First knot in [u_p, u_{N-1}] greater than t, minus one: u_k <= t < u_{k+1} for t inside the domain.
  auto it = std::upper_bound(knots_.begin() + order_, knots_.begin() + n, t);
  int k = static_cast<int>(it - knots_.begin()) - 1;
  k = std::clamp(k, order_, n - 1);
  // At t = tmax with repeated end knots the span found is empty: use the last non-empty one (left limit).
  while (k > order_ && !(knots_[k] < knots_[k + 1])) --k;
  return k;
}

Eigen::VectorXd NonUniformBspline::Evaluate(double t) const {
  if (std::isnan(t)) throw std::invalid_argument("NonUniformBspline::Evaluate: t is NaN");
  t = std::clamp(t, tmin(), tmax());
  const int p = order_;
  const int k = FindSpan(t);
  // de Boor: d_j = P_{j+k-p}, j = 0..p, blended p times.
  std::vector<Eigen::VectorXd> d(static_cast<size_t>(p + 1));
  for (int j = 0; j <= p; ++j) d[j] = ctrl_pts_.row(j + k - p).transpose();
  for (int r = 1; r <= p; ++r) {
    for (int j = p; j >= r; --j) {
      const double lo = knots_[j + k - p];
      const double hi = knots_[j + 1 + k - r];
      // hi - lo >= the length of the (non-empty) span k, so it is positive.
      const double alpha = (t - lo) / (hi - lo);
      d[j] = (1.0 - alpha) * d[j - 1] + alpha * d[j];
    }
  }
  return d[p];
}

NonUniformBspline NonUniformBspline::Derivative() const {
  const int n = num_ctrl_pts();
  const int p = order_;
  if (p == 0) return NonUniformBspline(Eigen::MatrixXd::Zero(n, dim()), 0, knots_);
  Eigen::MatrixXd q(n - 1, dim());
  for (int i = 0; i < n - 1; ++i) {
    const double span = knots_[i + p + 1] - knots_[i + 1];
    // A zero span means the basis function of this difference vanishes: its coefficient does not matter.
    q.row(i) = span > 0.0 ? (p * (ctrl_pts_.row(i + 1) - ctrl_pts_.row(i)) / span).eval()
                          : Eigen::RowVectorXd::Zero(dim()).eval();
  }
  std::vector<double> knots(knots_.begin() + 1, knots_.end() - 1);
  return NonUniformBspline(q, p - 1, knots);
}

NonUniformBspline NonUniformBspline::Derivative(int k) const {
  if (k < 0) throw std::invalid_argument("NonUniformBspline::Derivative: negative derivative order");
  NonUniformBspline out = *this;
  for (int i = 0; i < k; ++i) out = out.Derivative();
  return out;
}

double NonUniformBspline::MaxCtrlPtNorm() const { return ctrl_pts_.rowwise().norm().maxCoeff(); }

double NonUniformBspline::MaxCtrlPtAbs() const { return ctrl_pts_.cwiseAbs().maxCoeff(); }

NonUniformBspline NonUniformBspline::TimeScaled(double factor) const {
  if (!(factor > 0.0) || !std::isfinite(factor)) {
    std::ostringstream why;
    why << "NonUniformBspline::TimeScaled: factor " << factor << " must be positive and finite";
    throw std::invalid_argument(why.str());
  }
  std::vector<double> knots = knots_;
  const double t0 = tmin();
  for (double& u : knots) u = t0 + (u - t0) * factor;
  return NonUniformBspline(ctrl_pts_, order_, knots);
}

NonUniformBspline NonUniformBspline::TimeShifted(double dt_s) const {
  if (!std::isfinite(dt_s)) throw std::invalid_argument("NonUniformBspline::TimeShifted: dt_s is not finite");
  std::vector<double> knots = knots_;
  for (double& u : knots) u += dt_s;
  return NonUniformBspline(ctrl_pts_, order_, knots);
}

double NonUniformBspline::Length(int samples_per_span) const {
  if (samples_per_span < 2 || samples_per_span % 2 != 0) {
    throw std::invalid_argument("NonUniformBspline::Length: samples_per_span must be even and >= 2");
  }
  const NonUniformBspline vel = Derivative();
  double length = 0.0;
  for (int k = order_; k < num_ctrl_pts(); ++k) {
    const double a = knots_[k];
    const double b = knots_[k + 1];
    if (!(b > a)) continue;
    const double h = (b - a) / samples_per_span;
    double sum = vel.Evaluate(a).norm() + vel.Evaluate(b).norm();
    for (int i = 1; i < samples_per_span; ++i) {
      sum += (i % 2 == 1 ? 4.0 : 2.0) * vel.Evaluate(a + i * h).norm();
    }
    length += sum * h / 3.0;
  }
  return length;
}

}  // namespace quad_core
