#include "conversions.h"

#include <geometry_msgs/TransformStamped.h>
#include <sensor_msgs/point_cloud2_iterator.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <string>

namespace quad_sim_ros {
namespace {

geometry_msgs::Quaternion ToQuat(const Eigen::Quaterniond& q) {
  geometry_msgs::Quaternion m;
  m.x = q.x();
  m.y = q.y();
  m.z = q.z();
  m.w = q.w();
  return m;
}

Eigen::Vector3d FromVec(const geometry_msgs::Vector3& v) { return Eigen::Vector3d(v.x, v.y, v.z); }

Eigen::Vector3d FromArray(const boost::array<double, 3>& a) { return Eigen::Vector3d(a[0], a[1], a[2]); }

void SetGains(const boost::array<double, 3>& kR, const boost::array<double, 3>& kOm, Eigen::Vector3d* kR_out,
              Eigen::Vector3d* kOm_out) {
  if (FromArray(kR).isZero(0.0) && FromArray(kOm).isZero(0.0)) return;
  *kR_out = FromArray(kR);
  *kOm_out = FromArray(kOm);
}

}  // namespace

ros::Time StampOf(uint64_t stamp_ns) {
  ros::Time t;
  t.fromNSec(stamp_ns);
  return t;
}

geometry_msgs::Point ToPoint(const Eigen::Vector3d& v) {
  geometry_msgs::Point p;
  p.x = v.x();
  p.y = v.y();
  p.z = v.z();
  return p;
}

rosgraph_msgs::Clock ToClock(const ros::Time& now) {
  rosgraph_msgs::Clock c;
  c.clock = now;
  return c;
}

std_msgs::Float64 ToFloat64(double value) {
  std_msgs::Float64 m;
  m.data = value;
  return m;
}

tf2_msgs::TFMessage ToTf(const nav_msgs::Odometry& odom) {
  geometry_msgs::TransformStamped tf;
  tf.header = odom.header;
  tf.child_frame_id = odom.child_frame_id;
  tf.transform.translation.x = odom.pose.pose.position.x;
  tf.transform.translation.y = odom.pose.pose.position.y;
  tf.transform.translation.z = odom.pose.pose.position.z;
  tf.transform.rotation = odom.pose.pose.orientation;
  tf2_msgs::TFMessage m;
  m.transforms.push_back(tf);
  return m;
}

tf2_msgs::TFMessage CameraMountTf(const quad_sim::DepthCameraConfig& camera, const ros::Time& stamp) {
  geometry_msgs::TransformStamped tf;
  tf.header.stamp = stamp;
  tf.header.frame_id = "base_link";
  tf.child_frame_id = "camera";
  tf.transform.translation.x = camera.p_body_camera_m.x();
  tf.transform.translation.y = camera.p_body_camera_m.y();
  tf.transform.translation.z = camera.p_body_camera_m.z();
  tf.transform.rotation = ToQuat(camera.q_body_camera);
  tf2_msgs::TFMessage m;
  m.transforms.push_back(tf);
  return m;
}

quad_msgs::EpisodeStatus ToEpisodeStatus(const quad_sim::Simulator& sim, const ros::Time& now,
                                         const ros::Time& episode_start, uint64_t command_timeouts,
                                         uint64_t ack_timeouts) {
  const quad_sim::EpisodeState& e = sim.episode();
  quad_msgs::EpisodeStatus s;
  s.header.stamp = now;
  s.header.frame_id = "world";
  s.episode_id = e.episode_id;
  s.world_seed = sim.world().seed;
  s.sim_time = now;
  s.collided = e.collision.collided;
  s.collision_box_id =
      e.collision.collided ? e.collision.box_index : quad_msgs::EpisodeStatus::COLLISION_NONE;
  if (e.collision.collided) {
    s.collision_time =
        StampOf(episode_start.toNSec() + static_cast<uint64_t>(std::llround(e.collision.time_s * 1e9)));
    s.collision_point = ToPoint(e.collision.point_world_m);
  }
  s.reached_goal = e.reached_goal;
  s.active = e.active;
  s.goal = ToPoint(sim.goal_world());
  s.reason = e.reason;
  if (command_timeouts + ack_timeouts > 0) {
    s.reason += "; lockstep timeouts: " + std::to_string(command_timeouts) + " command, " +
                std::to_string(ack_timeouts) + " ack";
  }
  return s;
}

quad_msgs::SimStats ToSimStats(const quad_sim::Simulator& sim, const ros::Time& now,
                               const SimCounts& counts) {
  quad_msgs::SimStats m;
  m.header.stamp = now;
  m.episode_id = sim.episode().episode_id;
  m.episode_time_s = sim.time_s();
  m.real_time_factor = counts.real_time_factor;
  m.lockstep_command_timeouts = counts.command_timeouts;
  m.lockstep_ack_timeouts = counts.ack_timeouts;
  m.rejected_commands = counts.rejected_commands;
  m.odometry_count = counts.odometry;
  m.depth_frame_count = counts.depth_frames;
  return m;
}

visualization_msgs::MarkerArray WorldMarkers(const quad_sim::Simulator& sim, const ros::Time& stamp) {
  const quad_sim::World& w = sim.world();
  const quad_sim::SimConfig& config = sim.config();
  visualization_msgs::MarkerArray arr;
  visualization_msgs::Marker clear;
  clear.action = visualization_msgs::Marker::DELETEALL;
  arr.markers.push_back(clear);
  auto base = [&](const std::string& ns, int id, int type) {
    visualization_msgs::Marker m;
    m.header.frame_id = "world";
    m.header.stamp = stamp;
    m.ns = ns;
    m.id = id;
    m.type = type;
    m.action = visualization_msgs::Marker::ADD;
    m.pose.orientation.w = 1.0;
    m.color.a = 1.0;
    return m;
  };
  for (size_t i = 0; i < w.boxes.size(); ++i) {
    const quad_sim::OrientedBox& b = w.boxes[i];
    visualization_msgs::Marker m = base("boxes", static_cast<int>(i), visualization_msgs::Marker::CUBE);
    m.pose.position = ToPoint(b.center_world_m);
    m.pose.orientation = ToQuat(b.q_world_box);
    m.scale.x = b.size_m.x();
    m.scale.y = b.size_m.y();
    m.scale.z = b.size_m.z();
    // Colour by height, as a cue in rviz.
    const double h = std::clamp(b.center_world_m.z() / std::max(1e-3, w.bounds_max_m.z()), 0.0, 1.0);
    m.color.r = 0.3 + 0.5 * h;
    m.color.g = 0.45;
    m.color.b = 0.8 - 0.5 * h;
    m.color.a = 0.9;
    arr.markers.push_back(m);
  }
  visualization_msgs::Marker ground = base("ground", 0, visualization_msgs::Marker::CUBE);
  const Eigen::Vector3d c = 0.5 * (w.bounds_min_m + w.bounds_max_m);
  ground.pose.position = ToPoint(Eigen::Vector3d(c.x(), c.y(), -0.005));
  ground.scale.x = w.bounds_max_m.x() - w.bounds_min_m.x();
  ground.scale.y = w.bounds_max_m.y() - w.bounds_min_m.y();
  ground.scale.z = 0.01;
  ground.color.r = ground.color.g = ground.color.b = 0.35;
  arr.markers.push_back(ground);
  visualization_msgs::Marker goal = base("goal", 0, visualization_msgs::Marker::SPHERE);
  goal.pose.position = ToPoint(sim.goal_world());
  goal.scale.x = goal.scale.y = goal.scale.z = 2.0 * config.episode.goal_tolerance_m;
  goal.color.g = 0.9;
  goal.color.a = 0.5;
  arr.markers.push_back(goal);
  visualization_msgs::Marker vehicle = base("vehicle", 0, visualization_msgs::Marker::CUBE);
  vehicle.header.frame_id = "base_link";
  vehicle.frame_locked = true;
  vehicle.scale.x = config.vehicle.collision_box_m.x();
  vehicle.scale.y = config.vehicle.collision_box_m.y();
  vehicle.scale.z = config.vehicle.collision_box_m.z();
  vehicle.color.r = 1.0;
  vehicle.color.g = 0.5;
  vehicle.color.a = 0.8;
  arr.markers.push_back(vehicle);
  return arr;
}

sensor_msgs::PointCloud2 ToCloud(const std::vector<Eigen::Vector3f>& points, const ros::Time& stamp) {
  sensor_msgs::PointCloud2 cloud;
  cloud.header.frame_id = "world";
  cloud.header.stamp = stamp;
  sensor_msgs::PointCloud2Modifier mod(cloud);
  mod.setPointCloud2FieldsByString(1, "xyz");
  mod.resize(points.size());
  sensor_msgs::PointCloud2Iterator<float> x(cloud, "x"), y(cloud, "y"), z(cloud, "z");
  for (const Eigen::Vector3f& p : points) {
    *x = p.x();
    *y = p.y();
    *z = p.z();
    ++x, ++y, ++z;
  }
  return cloud;
}

quad_sim::So3Command FromMsg(const quad_msgs::SO3Command& msg) {
  quad_sim::So3Command c;
  c.force_world_N = FromVec(msg.force);
  c.q_world_des =
      Eigen::Quaterniond(msg.orientation.w, msg.orientation.x, msg.orientation.y, msg.orientation.z);
  c.w_body_des_radps = FromVec(msg.angular_velocity);
  SetGains(msg.kR, msg.kOm, &c.kR, &c.kOm);
  c.enable_motors = msg.aux.enable_motors;
  return c;
}

quad_sim::TrpyCommand FromMsg(const quad_msgs::TRPYCommand& msg) {
  quad_sim::TrpyCommand c;
  c.thrust_N = msg.thrust;
  c.roll_rad = msg.roll;
  c.pitch_rad = msg.pitch;
  c.yaw_rad = msg.yaw;
  c.w_body_des_radps = FromVec(msg.angular_velocity);
  SetGains(msg.kR, msg.kOm, &c.kR, &c.kOm);
  c.enable_motors = msg.aux.enable_motors;
  return c;
}

quad_sim::EpisodeRequest FromMsg(const quad_msgs::ResetEpisode::Request& req) {
  quad_sim::EpisodeRequest r;
  r.seed = req.seed;
  r.world_file = req.world_file;
  const auto& o = req.start.orientation;
  r.q_start_wxyz = Eigen::Vector4d(o.w, o.x, o.y, o.z);
  r.start_world_m = Eigen::Vector3d(req.start.position.x, req.start.position.y, req.start.position.z);
  r.goal_world_m = Eigen::Vector3d(req.goal.x, req.goal.y, req.goal.z);
  r.keyed = req.keyed;
  r.episode_index = req.episode_index;
  return r;
}

}  // namespace quad_sim_ros
