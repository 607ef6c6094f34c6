// Iterative time re-allocation of a B-spline (Zhou et al. 2019, Sec. V).
//
// The optimised uniform B-spline is made non-uniform: the control points stay, the knot spans whose velocity
// or acceleration control points exceed the limits are stretched (velocity control point V_i spans knots
// u_{i+1}..u_{i+p+1}; acceleration control point A_j spans u_{j+2}..u_{j+p+1}) by the ratio of the excess
// (|V_i| / v_max, sqrt(|A_j| / a_max)) times a margin, and the check is repeated. By the convex-hull
// property, control points within the limits bound the curve's speed and acceleration norms everywhere. If
// the local stretching has not converged after the configured iterations, the whole spline is slowed
// uniformly by the largest remaining ratio, which always succeeds (a time scaling by r divides velocities by
// r and accelerations by r^2). The result starts at t = 0 (its knots are shifted so that knots[degree] = 0).
// The geometry of the curve changes slightly with its knots; callers check collisions afterwards.
#pragma once

#include <quad_core/bspline.h>

#include <string>

#include "fast_planner/planner_config.h"

namespace fast_planner {

// Whether the state at the start of the spline may change (see ReallocateTime).
enum class StartPolicy { kMayChange, kKeep };

struct ReallocationResult {
  quad_core::NonUniformBspline spline;
  int iterations = 0;
  bool used_uniform_fallback = false;
  bool start_kept = true;  // false if keeping the start state had to be given up to meet the limits
  double max_vel_ratio_before = 0.0;  // largest |V_i| / v_max before re-allocation
  double max_acc_ratio_before = 0.0;  // largest |A_j| / a_max before re-allocation
};

// Throws std::invalid_argument if the spline's degree is below 2 or margin < 1.
//
// StartPolicy::kKeep: stretching the first knot spans would change the state at the start of the spline (and
// make the vehicle's commanded state jump when a replan takes over). With kKeep (the spline starts in the
// state of a feasible trajectory being flown), the spans that shape the start (u_0..u_{2p-1}) are never
// stretched, so position, velocity and acceleration at the start stay exactly as they are; the derivative
// control points fixed by the start state alone (V_0, V_1, A_0) are then not checked, so within the first two
// knot spans the limits hold only as well as the start state does. If that does not converge, the start is
// given up (start_kept = false) and the plain procedure guarantees the limits everywhere.
ReallocationResult ReallocateTime(const quad_core::NonUniformBspline& spline, const LimitsConfig& limits,
                                  int max_iterations, double margin,
                                  StartPolicy start_policy = StartPolicy::kMayChange);

// Largest |V_i| / v_max and |A_j| / a_max over the derivative control points (the convex-hull bounds).
double MaxVelocityRatio(const quad_core::NonUniformBspline& spline, double max_vel_mps);
double MaxAccelerationRatio(const quad_core::NonUniformBspline& spline, double max_acc_mps2);

}  // namespace fast_planner
