// What the expert planner hands to DatasetWriter::Record after a plan: exactly the inputs it planned from and
// the plan it produced. ROS-free plain data; the planner's node converts its messages into this.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <string_view>
#include <vector>

#include "quad_core/depth_image.h"

namespace cpp_data_collector {

// The odometry sample the plan started from (frames and units: docs/CONVENTIONS.md). Not a second vehicle
// state: this is the record's layout type, mirroring the on-disk fields of a record (docs/data_format.md:
// plain arrays, quaternion normalised and stored x, y, z, w). The planner converts its
// quad_core::VehicleState into it (fast_planner::ToOdometrySample).
struct OdometrySample {
  double stamp_s = 0.0;
  std::array<double, 3> p_world_body{};
  std::array<double, 3> v_world{};
  std::array<double, 4> q_world_body{0.0, 0.0, 0.0, 1.0};  // x, y, z, w
  std::array<double, 3> w_body{};                          // rad/s in body axes
};

// The planned B-spline, as in quad_msgs/Bspline (Fast-Planner's message): degree `order`, knots in seconds
// (num_knots = num_ctrl_pts + order + 1, non-decreasing), and start_time_s = the time at which the parameter
// u = knots[order] is flown. Yaw: control points of a uniform spline with knot spacing yaw_dt_s.
struct BsplineData {
  int32_t order = 3;
  int64_t traj_id = 0;
  double start_time_s = 0.0;
  std::vector<double> knots;
  std::vector<std::array<double, 3>> ctrl_pts_world;
  std::vector<double> yaw_pts;
  double yaw_dt_s = 0.0;
};

// The planner's outcome: its own status enum value and a short printable reason (truncated to 47 bytes).
struct PlanStatus {
  int32_t code = 0;
  std::string_view text;  // non-owning, copied during Record
};

struct PlanTimings {
  double map_update_ms = 0.0;
  double frontend_ms = 0.0;
  double optimization_ms = 0.0;
  double total_ms = 0.0;
};

struct PlanRecord {
  int64_t episode_id = 0;
  uint64_t world_seed = 0;
  double sim_time_s = 0.0;  // sim time at which the plan was made
  // Non-owning: the pixels must stay valid only during the DatasetWriter::Record call, which copies them.
  quad_core::DepthImageView depth;
  double depth_stamp_s = 0.0;  // the image's own stamp (sim time)
  OdometrySample odom;
  std::array<double, 3> goal_world{};
  BsplineData bspline;
  PlanStatus status;
  PlanTimings timings;
};

}  // namespace cpp_data_collector
