#include "conversions.h"

#include <sensor_msgs/image_encodings.h>
#include <sensor_msgs/point_cloud2_iterator.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>

namespace fast_planner::ros_conv {

namespace {

// Map slice markers: voxels within this height of the vehicle.
constexpr double kMapSliceHalfHeightM = 0.05;
// Trajectory and front-end path markers: one point every this much time.
constexpr double kMarkerStepS = 0.05;

geometry_msgs::Point ToPoint(const Eigen::Vector3d& p) {
  geometry_msgs::Point m;
  m.x = p.x();
  m.y = p.y();
  m.z = p.z();
  return m;
}

visualization_msgs::Marker NewMarker(const std::string& ns, int type, double scale, float r, float g,
                                     float b) {
  visualization_msgs::Marker m;
  m.header.frame_id = "world";
  m.header.stamp = ros::Time::now();
  m.ns = ns;
  m.id = 0;
  m.type = type;
  m.action = visualization_msgs::Marker::ADD;
  m.pose.orientation.w = 1.0;
  m.scale.x = m.scale.y = m.scale.z = scale;
  m.color.r = r;
  m.color.g = g;
  m.color.b = b;
  m.color.a = 1.0f;
  return m;
}

}  // namespace

CameraMount ToCameraMount(const geometry_msgs::TransformStamped& t) {
  const auto& tr = t.transform.translation;
  const auto& r = t.transform.rotation;
  return CameraMount{Eigen::Vector3d(tr.x, tr.y, tr.z), Eigen::Quaterniond(r.w, r.x, r.y, r.z)};
}

std::string DepthFrameProblem(const sensor_msgs::Image& msg, const quad_core::CameraIntrinsics* k) {
  if (msg.encoding != sensor_msgs::image_encodings::TYPE_32FC1) {
    return "skipping depth frame with encoding '" + msg.encoding + "' (expected 32FC1)";
  }
  if (!k) return "skipping depth frame: no camera_info yet";
  const size_t n = static_cast<size_t>(msg.width) * msg.height;
  if (msg.step != msg.width * sizeof(float) || msg.data.size() != n * sizeof(float) ||
      static_cast<int>(msg.width) != k->width || static_cast<int>(msg.height) != k->height ||
      msg.is_bigendian) {
    char buf[256];
    std::snprintf(
        buf, sizeof(buf),
        "skipping depth frame %ux%u (step %u, %zu bytes): layout or size does not match camera_info "
        "%dx%d little-endian 32FC1",
        msg.width, msg.height, msg.step, msg.data.size(), k->width, k->height);
    return buf;
  }
  return "";
}

std::shared_ptr<DepthFrame> ToDepthFrame(const sensor_msgs::Image& msg,
                                         const quad_core::CameraIntrinsics& k) {
  auto frame = std::make_shared<DepthFrame>();
  frame->stamp_s = msg.header.stamp.toSec();
  frame->seq = msg.header.seq;
  frame->intrinsics = k;
  const size_t n = static_cast<size_t>(msg.width) * msg.height;
  frame->image.width = static_cast<int>(msg.width);
  frame->image.height = static_cast<int>(msg.height);
  frame->image.depth_m.resize(n);
  std::memcpy(frame->image.depth_m.data(), msg.data.data(), std::min(n * sizeof(float), msg.data.size()));
  return frame;
}

std::vector<Eigen::Vector3d> ToPoints(const sensor_msgs::PointCloud2& msg) {
  std::vector<Eigen::Vector3d> pts;
  pts.reserve(static_cast<size_t>(msg.width) * msg.height);
  for (sensor_msgs::PointCloud2ConstIterator<float> x(msg, "x"), y(msg, "y"), z(msg, "z"); x != x.end();
       ++x, ++y, ++z) {
    pts.emplace_back(*x, *y, *z);
  }
  return pts;
}

quad_msgs::Bspline ToBsplineMessage(const PlanResult& plan, const ros::Time& start_time) {
  quad_msgs::Bspline b;
  b.order = plan.spline->order();
  b.traj_id = plan.traj_id;
  b.start_time = start_time;
  b.knots = plan.spline->knots();
  const Eigen::MatrixXd& q = plan.spline->ctrl_pts();
  b.pos_pts.reserve(q.rows());
  for (int i = 0; i < q.rows(); ++i) b.pos_pts.push_back(ToPoint(q.row(i).transpose()));
  b.yaw_dt = 0.0;
  return b;
}

quad_msgs::Bspline EmptyBsplineMessage(const ros::Time& start_time) {
  quad_msgs::Bspline b;
  b.start_time = start_time;
  b.order = 3;
  b.yaw_dt = 0.0;
  return b;
}

quad_msgs::PlanTiming ToPlanTiming(const PlanResult& plan, const ros::Time& stamp,
                                   double frame_map_update_ms) {
  quad_msgs::PlanTiming t;
  t.header.stamp = stamp;
  t.header.frame_id = "world";
  t.traj_id = plan.traj_id;
  t.map_update_ms = frame_map_update_ms + plan.timings.map_prep_ms;
  t.frontend_ms = plan.timings.frontend_ms;
  t.optimization_ms = plan.timings.optimization_ms;
  t.total_ms = plan.timings.total_ms;
  t.status = plan.reason;
  return t;
}

visualization_msgs::MarkerArray PlanMarkers(const PlanResult& plan) {
  visualization_msgs::MarkerArray a;
  auto path = NewMarker("frontend_path", visualization_msgs::Marker::LINE_STRIP, 0.03, 0.2f, 0.4f, 1.0f);
  for (double t = 0.0; t <= plan.frontend_path.duration_s(); t += kMarkerStepS) {
    path.points.push_back(ToPoint(plan.frontend_path.Position(t)));
  }
  auto traj = NewMarker("trajectory", visualization_msgs::Marker::LINE_STRIP, 0.05, 1.0f, 0.3f, 0.1f);
  for (double t = 0.0; t <= plan.spline->tmax(); t += kMarkerStepS) {
    const Eigen::VectorXd p = plan.spline->Evaluate(t);
    traj.points.push_back(ToPoint(Eigen::Vector3d(p[0], p[1], p[2])));
  }
  auto ctrl = NewMarker("control_points", visualization_msgs::Marker::SPHERE_LIST, 0.1, 0.1f, 0.8f, 0.2f);
  const Eigen::MatrixXd& q = plan.spline->ctrl_pts();
  for (int i = 0; i < q.rows(); ++i) ctrl.points.push_back(ToPoint(q.row(i).transpose()));
  a.markers = {path, traj, ctrl};
  return a;
}

visualization_msgs::MarkerArray MapSliceMarkers(const VoxelMap& map, const Eigen::Vector3d& p_world_body) {
  Eigen::Vector3i lo, hi;
  map.LocalWindow(p_world_body, &lo, &hi);
  const int z = map.ToIndex(p_world_body).z();
  auto occ = NewMarker("map_slice_occupied", visualization_msgs::Marker::CUBE_LIST, map.resolution(), 0.9f,
                       0.1f, 0.1f);
  auto infl = NewMarker("map_slice_inflated", visualization_msgs::Marker::CUBE_LIST, map.resolution(), 0.9f,
                        0.7f, 0.2f);
  infl.color.a = 0.3f;
  const int dz = static_cast<int>(std::round(kMapSliceHalfHeightM / map.resolution()));
  for (int iz = std::max(lo.z(), z - dz); iz <= std::min(hi.z(), z + dz); ++iz) {
    for (int iy = lo.y(); iy <= hi.y(); ++iy) {
      for (int ix = lo.x(); ix <= hi.x(); ++ix) {
        const Eigen::Vector3i idx(ix, iy, iz);
        if (map.IsOccupied(idx)) {
          occ.points.push_back(ToPoint(map.ToPosition(idx)));
        } else if (map.IsInflated(idx)) {
          infl.points.push_back(ToPoint(map.ToPosition(idx)));
        }
      }
    }
  }
  visualization_msgs::MarkerArray a;
  a.markers = {occ, infl};
  return a;
}

}  // namespace fast_planner::ros_conv
