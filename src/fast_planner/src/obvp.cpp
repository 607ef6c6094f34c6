#include "fast_planner/obvp.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace fast_planner {

namespace {

double Quartic(double p, double q, double r, double y) { return ((y * y + p) * y + q) * y + r; }
double QuarticDerivative(double p, double q, double y) { return (4.0 * y * y + 2.0 * p) * y + q; }

double Polish(double p, double q, double r, double y) {
  for (int i = 0; i < 3; ++i) {
    const double d = QuarticDerivative(p, q, y);
    if (std::abs(d) < 1e-300) break;
    const double next = y - Quartic(p, q, r, y) / d;
    if (!std::isfinite(next)) break;
    y = next;
  }
  return y;
}

int AddQuadraticRoots(double b, double c, double* out) {
  // y^2 + b y + c = 0, numerically stable form.
  const double disc = b * b - 4.0 * c;
  if (disc < 0.0) return 0;
  const double s = std::sqrt(disc);
  const double q = -0.5 * (b + (b >= 0.0 ? s : -s));
  int n = 0;
  if (q != 0.0) {
    out[n++] = q;
    out[n++] = c / q;
  } else {
    out[n++] = 0.0;
    out[n++] = -b;
  }
  return n;
}

}  // namespace

double LargestCubicRoot(double a, double b, double c) {
  // x = t - a/3: t^3 + P t + Q = 0.
  const double P = b - a * a / 3.0;
  const double Q = 2.0 * a * a * a / 27.0 - a * b / 3.0 + c;
  const double disc = 0.25 * Q * Q + P * P * P / 27.0;
  double t;
  if (disc > 0.0) {
    const double s = std::sqrt(disc);
    t = std::cbrt(-0.5 * Q + s) + std::cbrt(-0.5 * Q - s);
  } else if (P < 0.0) {
    const double m = 2.0 * std::sqrt(-P / 3.0);
    const double arg = std::clamp(3.0 * Q / (P * m), -1.0, 1.0);
    t = m * std::cos(std::acos(arg) / 3.0);  // k = 0 gives the largest of the three
  } else {
    t = std::cbrt(-Q);
  }
  double x = t - a / 3.0;
  for (int i = 0; i < 3; ++i) {
    const double f = ((x + a) * x + b) * x + c;
    const double d = (3.0 * x + 2.0 * a) * x + b;
    if (std::abs(d) < 1e-300) break;
    const double next = x - f / d;
    if (!std::isfinite(next)) break;
    x = next;
  }
  return x;
}

int SolveDepressedQuartic(double p, double q, double r, double roots[4]) {
  int n = 0;
  const double scale = std::max({1.0, std::abs(p), std::sqrt(std::abs(r))});
  if (std::abs(q) < 1e-12 * scale * scale) {
    // Biquadratic: z = y^2.
    double z[2];
    const int nz = AddQuadraticRoots(p, r, z);
    for (int i = 0; i < nz; ++i) {
      if (z[i] < 0.0) continue;
      const double y = std::sqrt(z[i]);
      roots[n++] = y;
      if (y > 0.0) roots[n++] = -y;
    }
  } else {
    // Resolvent cubic m^3 + p m^2 + (p^2/4 - r) m - q^2/8 = 0 has a positive root since q != 0.
    const double m = LargestCubicRoot(p, 0.25 * p * p - r, -0.125 * q * q);
    if (!(m > 0.0)) return 0;
    const double s = std::sqrt(2.0 * m);
    n += AddQuadraticRoots(-s, 0.5 * p + m + q / (2.0 * s), roots + n);
    n += AddQuadraticRoots(s, 0.5 * p + m - q / (2.0 * s), roots + n);
  }
  for (int i = 0; i < n; ++i) roots[i] = Polish(p, q, r, roots[i]);
  return n;
}

double ObvpCost(const Eigen::Vector3d& p0, const Eigen::Vector3d& v0, const Eigen::Vector3d& p1,
                const Eigen::Vector3d& v1, double T, double rho) {
  const Eigen::Vector3d dp = p1 - p0;
  const double a = dp.squaredNorm();
  const double b = dp.dot(v0 + v1);
  const double c = v0.squaredNorm() + v0.dot(v1) + v1.squaredNorm();
  return rho * T + 12.0 * a / (T * T * T) - 12.0 * b / (T * T) + 4.0 * c / T;
}

ObvpSolution SolveObvp(const Eigen::Vector3d& p0, const Eigen::Vector3d& v0, const Eigen::Vector3d& p1,
                       const Eigen::Vector3d& v1, double rho, double t_min) {
  const Eigen::Vector3d dp = p1 - p0;
  const double a = dp.squaredNorm();
  const double b = dp.dot(v0 + v1);
  const double c = v0.squaredNorm() + v0.dot(v1) + v1.squaredNorm();
  ObvpSolution best;
  best.duration_s = t_min;
  best.cost = t_min > 0.0 ? ObvpCost(p0, v0, p1, v1, t_min, rho) : std::numeric_limits<double>::infinity();
  if (a == 0.0 && b == 0.0 && c == 0.0) {
    best.cost = rho * t_min;
    return best;
  }
  double roots[4];
  const int n = SolveDepressedQuartic(-4.0 * c / rho, 24.0 * b / rho, -36.0 * a / rho, roots);
  for (int i = 0; i < n; ++i) {
    const double T = roots[i];
    if (!(T > 0.0) || T < t_min) continue;
    const double cost = ObvpCost(p0, v0, p1, v1, T, rho);
    if (cost < best.cost) {
      best.cost = cost;
      best.duration_s = T;
    }
  }
  return best;
}

PolySegment ObvpSegment(const Eigen::Vector3d& p0, const Eigen::Vector3d& v0, const Eigen::Vector3d& p1,
                        const Eigen::Vector3d& v1, double T) {
  // Per axis p(t) = p0 + v0 t + c2 t^2 + c3 t^3 with p(T) = p1, p'(T) = v1.
  const Eigen::Vector3d dp = p1 - p0 - v0 * T;
  const Eigen::Vector3d dv = v1 - v0;
  PolySegment s;
  s.coeffs.col(0) = p0;
  s.coeffs.col(1) = v0;
  s.coeffs.col(2) = (3.0 * dp - dv * T) / (T * T);
  s.coeffs.col(3) = (dv * T - 2.0 * dp) / (T * T * T);
  s.duration_s = T;
  return s;
}

}  // namespace fast_planner
