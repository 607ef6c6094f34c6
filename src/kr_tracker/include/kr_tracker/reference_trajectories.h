// Reference trajectories for closed-loop checks (ROS-free).
#pragma once

#include <Eigen/Core>

#include "quad_core/bspline.h"

namespace kr_tracker {

struct FigureEightSpec {
  Eigen::Vector3d center_world = Eigen::Vector3d(0.0, 0.0, 1.5);  // the crossing point; flight starts here
  double half_length_m = 4.0;                                     // x extent: +-half_length
  double half_width_m = 2.0;                                      // y extent: +-half_width
  int laps = 2;
  double peak_speed_mps = 2.0;  // the spline is time-scaled so that its sampled peak speed is this
  double ctrl_pt_dt_s = 0.1;    // knot interval before the time scaling
  double ramp_fraction = 0.15;  // share of each end spent accelerating from / decelerating to rest
};

// A uniform cubic B-spline through a lemniscate of Gerono, x = a sin(theta), y = b sin(2 theta), traversed
// with a smooth speed ramp (it starts and ends at rest at center_world; the first and last control points are
// tripled so that velocity and acceleration are zero there). Knots start at t0_s. Throws
// std::invalid_argument for non-positive sizes/speeds.
quad_core::NonUniformBspline MakeFigureEight(const FigureEightSpec& spec, double t0_s = 0.0);

// Largest speed of a 3-D spline, sampled every dt_s.
double SampledPeakSpeed(const quad_core::NonUniformBspline& pos, double dt_s = 0.001);

}  // namespace kr_tracker
