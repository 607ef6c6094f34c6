// The minimum time-effort boundary value problem of a 3-D double integrator (p'' = u), in closed form.
//
// Zhou et al. 2019, Sec. III-B (after Mueller et al., "A computationally efficient motion primitive for
// quadrocopter trajectory generation"): minimise J = integral_0^T |u|^2 dt + rho T from (p0, v0) to (p1, v1).
// For a fixed T each axis is a cubic and
//   J(T) = rho T + 12 a / T^3 - 12 b / T^2 + 4 c / T,
//   a = sum dp^2, b = sum dp (v0 + v1), c = sum (v0^2 + v0 v1 + v1^2), dp = p1 - p0,
// and dJ/dT = 0 is the depressed quartic rho T^4 - 4 c T^2 + 24 b T - 36 a = 0, solved with Ferrari's method.
// The front end uses J* as its heuristic and the optimal cubic as its analytic expansion ("shot") to the
// goal.
#pragma once

#include <Eigen/Core>

#include "fast_planner/poly_path.h"

namespace fast_planner {

// Real roots of y^4 + p y^2 + q y + r = 0 (Ferrari), polished by Newton's method; returns their count (<= 4).
int SolveDepressedQuartic(double p, double q, double r, double roots[4]);
// The largest real root of x^3 + a x^2 + b x + c = 0 (Cardano / trigonometric form), polished by Newton.
double LargestCubicRoot(double a, double b, double c);

struct ObvpSolution {
  double duration_s = 0.0;
  double cost = 0.0;
};

// J(T) for a fixed T > 0.
double ObvpCost(const Eigen::Vector3d& p0, const Eigen::Vector3d& v0, const Eigen::Vector3d& p1,
                const Eigen::Vector3d& v1, double T, double rho);

// The T >= t_min minimising J (t_min >= 0; Fast-Planner bounds T below by the time to cover the largest axis
// distance at full speed). When p0 = p1 and v0 = v1 = 0 the answer is T = t_min with cost rho t_min.
ObvpSolution SolveObvp(const Eigen::Vector3d& p0, const Eigen::Vector3d& v0, const Eigen::Vector3d& p1,
                       const Eigen::Vector3d& v1, double rho, double t_min);

// The minimum-effort cubic from (p0, v0) to (p1, v1) in exactly T seconds (T > 0).
PolySegment ObvpSegment(const Eigen::Vector3d& p0, const Eigen::Vector3d& v0, const Eigen::Vector3d& p1,
                        const Eigen::Vector3d& v1, double T);

}  // namespace fast_planner
