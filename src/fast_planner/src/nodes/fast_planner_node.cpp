// fast_planner_node: the thin ROS adapter of the expert (docs/fast_planner.md).
//
// Subscribes odom, camera/depth/image (+ camera_info), planner/goal, sim/status (a new episode resets the
// planner) and, with the global map source, sim/voxel_map. Every depth frame updates the map and steps the
// replanning state machine; each new trajectory goes to the tracker's TrackBspline action and out on
// planner/bspline. Publishes planner/timing (one message per plan attempt), planner/status (failures,
// abandoned goals, state changes), planner/markers, and sim/frame_ack after every depth frame (the lockstep
// protocol of docs/CONVENTIONS.md). Malformed input (non-finite odometry, depth frames that are not 32FC1 or
// have the wrong size, goals in another frame) is skipped with a throttled log line; rejected goals are
// logged with the reason.
#include <actionlib/client/simple_action_client.h>
#include <geometry_msgs/PoseStamped.h>
#include <nav_msgs/Odometry.h>
#include <quad_common/strict_yaml.h>
#include <quad_msgs/Bspline.h>
#include <quad_msgs/EpisodeStatus.h>
#include <quad_msgs/FrameAck.h>
#include <quad_msgs/PlanTiming.h>
#include <quad_msgs/TrackBsplineAction.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/PointCloud2.h>
#include <sensor_msgs/image_encodings.h>
#include <sensor_msgs/point_cloud2_iterator.h>
#include <std_msgs/String.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/transform_listener.h>
#include <visualization_msgs/MarkerArray.h>

#include <cmath>
#include <cstring>
#include <deque>
#include <memory>
#include <optional>
#include <string>

#include "fast_planner/replanner.h"

namespace fast_planner {
namespace {

constexpr double kLogThrottleS = 2.0;
// Odometry kept to look up the pose of a depth frame (a second at 200 Hz).
constexpr size_t kOdomBuffer = 200;
// Map slice markers: at most this often (wall time), voxels within this height of the vehicle.
constexpr double kMapSlicePeriodS = 0.5;
constexpr double kMapSliceHalfHeightM = 0.05;

geometry_msgs::Point ToPoint(const Eigen::Vector3d& p) {
  geometry_msgs::Point m;
  m.x = p.x();
  m.y = p.y();
  m.z = p.z();
  return m;
}

class FastPlannerNode {
 public:
  FastPlannerNode(ros::NodeHandle nh, ros::NodeHandle pnh)
      : nh_(nh),
        cfg_(LoadPlannerConfig(pnh.param<std::string>("config", ""))),
        replanner_(cfg_),
        consumer_(pnh.param<std::string>("frame_ack_consumer", "fast_planner")),
        tf_listener_(tf_buffer_) {
    bspline_pub_ = nh_.advertise<quad_msgs::Bspline>("planner/bspline", 10);
    timing_pub_ = nh_.advertise<quad_msgs::PlanTiming>("planner/timing", 10);
    status_pub_ = nh_.advertise<std_msgs::String>("planner/status", 10, true);
    markers_pub_ = nh_.advertise<visualization_msgs::MarkerArray>("planner/markers", 1);
    ack_pub_ = nh_.advertise<quad_msgs::FrameAck>("sim/frame_ack", 100);
    const auto hints = ros::TransportHints().tcpNoDelay();
    odom_sub_ = nh_.subscribe("odom", 100, &FastPlannerNode::OnOdom, this, hints);
    depth_sub_ = nh_.subscribe("camera/depth/image", 5, &FastPlannerNode::OnDepth, this, hints);
    info_sub_ = nh_.subscribe("camera/depth/camera_info", 5, &FastPlannerNode::OnInfo, this);
    goal_sub_ = nh_.subscribe("planner/goal", 5, &FastPlannerNode::OnGoal, this);
    status_sub_ = nh_.subscribe("sim/status", 5, &FastPlannerNode::OnEpisode, this);
    if (cfg_.map.source == MapSource::kGlobal) {
      voxel_sub_ = nh_.subscribe("sim/voxel_map", 1, &FastPlannerNode::OnVoxelMap, this);
    }
    ROS_INFO("fast_planner: map source %s, max %.1f m/s, %.1f m/s^2, horizon %.1f m",
             ToString(cfg_.map.source), cfg_.limits.max_vel_mps, cfg_.limits.max_acc_mps2,
             cfg_.search.horizon_m);
  }

 private:
  void OnOdom(const nav_msgs::Odometry::ConstPtr& msg) {
    ConnectTracker();
    Odometry o;
    o.stamp_s = msg->header.stamp.toSec();
    const auto& p = msg->pose.pose.position;
    const auto& q = msg->pose.pose.orientation;
    const auto& v = msg->twist.twist.linear;
    const auto& w = msg->twist.twist.angular;
    o.p_world_body = Eigen::Vector3d(p.x, p.y, p.z);
    o.q_world_body = Eigen::Quaterniond(q.w, q.x, q.y, q.z);
    o.v_world = Eigen::Vector3d(v.x, v.y, v.z);  // twist in the world frame (docs/CONVENTIONS.md)
    o.w_body = Eigen::Vector3d(w.x, w.y, w.z);
    try {
      Handle(replanner_.OnOdometry(o), msg->header.stamp);
    } catch (const std::invalid_argument& e) {
      ROS_WARN_THROTTLE(kLogThrottleS, "fast_planner: skipping odometry: %s", e.what());
      return;
    }
    odom_.push_back(o);
    if (odom_.size() > kOdomBuffer) odom_.pop_front();
  }

  void OnInfo(const sensor_msgs::CameraInfo::ConstPtr& msg) {
    CameraIntrinsics k{static_cast<int>(msg->width),
                       static_cast<int>(msg->height),
                       msg->K[0],
                       msg->K[4],
                       msg->K[2],
                       msg->K[5]};
    intrinsics_ = k;
  }

  // The camera pose at `stamp`: the newest odometry not after it, moved on at its velocity (in lockstep the
  // odometry after a frame is only published once the frame is acknowledged), times the base_link -> camera
  // mount.
  bool CameraPose(const ros::Time& stamp, const std::string& camera_frame, Eigen::Vector3d* p,
                  Eigen::Quaterniond* q) {
    if (!mount_) {
      try {
        const auto t =
            tf_buffer_.lookupTransform("base_link", camera_frame, ros::Time(0), ros::Duration(0.5));
        const auto& tr = t.transform.translation;
        const auto& r = t.transform.rotation;
        mount_ = std::make_pair(Eigen::Vector3d(tr.x, tr.y, tr.z), Eigen::Quaterniond(r.w, r.x, r.y, r.z));
      } catch (const tf2::TransformException& e) {
        ROS_WARN_THROTTLE(kLogThrottleS, "fast_planner: no base_link -> %s transform yet: %s",
                          camera_frame.c_str(), e.what());
        return false;
      }
    }
    const double t = stamp.toSec();
    const Odometry* best = nullptr;
    for (const auto& o : odom_) {
      if (o.stamp_s <= t + 1e-9) best = &o;
    }
    if (!best) return false;
    const Eigen::Vector3d p_body = best->p_world_body + best->v_world * (t - best->stamp_s);
    const Eigen::Quaterniond q_body = best->q_world_body.normalized();
    *p = p_body + q_body * mount_->first;
    *q = q_body * mount_->second;
    return true;
  }

  // The action client waits for a valid time when it is built: with sim time, only once /clock has arrived
  // (in lockstep the simulator may be waiting for this node meanwhile, so it must not be built in the
  // constructor).
  void ConnectTracker() {
    if (!tracker_ && !ros::Time::now().isZero()) {
      tracker_ = std::make_unique<actionlib::SimpleActionClient<quad_msgs::TrackBsplineAction>>(
          nh_, "tracker/track_bspline", true);
    }
  }

  // A trajectory planned before the tracker's action server was connected is sent once it is.
  void SendPending() {
    if (!pending_ || !tracker_ || !tracker_->isServerConnected()) return;
    quad_msgs::TrackBsplineGoal goal;
    goal.bspline = *pending_;
    tracker_->sendGoal(goal);
    pending_.reset();
  }

  void OnDepth(const sensor_msgs::Image::ConstPtr& msg) {
    ConnectTracker();
    SendPending();
    ProcessDepth(*msg);
    // Acknowledge every frame, also one that was skipped: the simulator must not wait on a frame we cannot
    // use.
    quad_msgs::FrameAck ack;
    ack.consumer = consumer_;
    ack.frame_seq = msg->header.seq;
    ack.stamp = msg->header.stamp;
    ack_pub_.publish(ack);
  }

  void ProcessDepth(const sensor_msgs::Image& msg) {
    if (msg.encoding != sensor_msgs::image_encodings::TYPE_32FC1) {
      ROS_WARN_THROTTLE(kLogThrottleS,
                        "fast_planner: skipping depth frame with encoding '%s' (expected 32FC1)",
                        msg.encoding.c_str());
      return;
    }
    if (!intrinsics_) {
      ROS_WARN_THROTTLE(kLogThrottleS, "fast_planner: skipping depth frame: no camera_info yet");
      return;
    }
    const size_t n = static_cast<size_t>(msg.width) * msg.height;
    if (msg.step != msg.width * sizeof(float) || msg.data.size() != n * sizeof(float) ||
        static_cast<int>(msg.width) != intrinsics_->width ||
        static_cast<int>(msg.height) != intrinsics_->height || msg.is_bigendian) {
      ROS_WARN_THROTTLE(kLogThrottleS,
                        "fast_planner: skipping depth frame %ux%u (step %u, %zu bytes): layout or size "
                        "does not match camera_info %dx%d little-endian 32FC1",
                        msg.width, msg.height, msg.step, msg.data.size(), intrinsics_->width,
                        intrinsics_->height);
      return;
    }
    auto frame = std::make_shared<DepthFrame>();
    frame->stamp_s = msg.header.stamp.toSec();
    frame->seq = msg.header.seq;
    frame->intrinsics = *intrinsics_;
    frame->depth_m.resize(n);
    std::memcpy(frame->depth_m.data(), msg.data.data(), n * sizeof(float));
    if (!CameraPose(msg.header.stamp, msg.header.frame_id, &frame->p_world_camera, &frame->q_world_camera)) {
      ROS_WARN_THROTTLE(kLogThrottleS, "fast_planner: skipping depth frame: no odometry before it yet");
      return;
    }
    MapUpdateResult map_update;
    ReplannerOutput out;
    try {
      out = replanner_.OnDepth(frame, &map_update);
    } catch (const std::invalid_argument& e) {
      ROS_WARN_THROTTLE(kLogThrottleS, "fast_planner: skipping depth frame: %s", e.what());
      return;
    }
    last_map_update_ms_ = map_update.total_ms;
    Handle(out, msg.header.stamp);
    PublishMapSlice();
  }

  void OnGoal(const geometry_msgs::PoseStamped::ConstPtr& msg) {
    if (!msg->header.frame_id.empty() && msg->header.frame_id != "world") {
      ROS_WARN("fast_planner: goal rejected: frame '%s' is not 'world'", msg->header.frame_id.c_str());
      Status("goal rejected: frame '" + msg->header.frame_id + "' is not 'world'");
      return;
    }
    const auto& p = msg->pose.position;
    ReplannerOutput out;
    const double now = ros::Time::now().toSec();
    const std::string why = replanner_.SetGoal(Eigen::Vector3d(p.x, p.y, p.z), now, &out);
    if (!why.empty()) {
      ROS_WARN("fast_planner: goal (%.2f, %.2f, %.2f) rejected: %s", p.x, p.y, p.z, why.c_str());
      Status("goal rejected: " + why);
      return;
    }
    ROS_INFO("fast_planner: new goal (%.2f, %.2f, %.2f)", p.x, p.y, p.z);
    Handle(out, ros::Time::now());
  }

  void OnEpisode(const quad_msgs::EpisodeStatus::ConstPtr& msg) {
    if (episode_id_ && *episode_id_ == msg->episode_id) return;
    if (episode_id_) {
      ROS_INFO("fast_planner: episode %u: resetting the planner", msg->episode_id);
      replanner_.Reset();
      odom_.clear();
      if (global_points_) replanner_.manager().SetGlobalMap(*global_points_);
    }
    episode_id_ = msg->episode_id;
  }

  void OnVoxelMap(const sensor_msgs::PointCloud2::ConstPtr& msg) {
    std::vector<Eigen::Vector3d> pts;
    pts.reserve(static_cast<size_t>(msg->width) * msg->height);
    try {
      for (sensor_msgs::PointCloud2ConstIterator<float> x(*msg, "x"), y(*msg, "y"), z(*msg, "z");
           x != x.end(); ++x, ++y, ++z) {
        pts.emplace_back(*x, *y, *z);
      }
    } catch (const std::runtime_error& e) {
      ROS_WARN("fast_planner: voxel map without x/y/z float fields ignored: %s", e.what());
      return;
    }
    replanner_.manager().SetGlobalMap(pts);
    global_points_ = std::move(pts);
    ROS_INFO("fast_planner: global map with %zu occupied voxels", global_points_->size());
  }

  void Handle(const ReplannerOutput& out, const ros::Time& stamp) {
    for (const auto& t : out.transitions) ROS_DEBUG("fast_planner: %s", t.c_str());
    if (!out.transitions.empty()) Status("state: " + out.transitions.back());
    for (const auto& f : out.failed_plans) {
      ROS_WARN_THROTTLE(kLogThrottleS, "fast_planner: plan failed: %s", f.reason.c_str());
      Status("plan failed: " + f.reason);
      PublishTiming(f, stamp);
    }
    if (out.abandoned) {
      ROS_WARN("fast_planner: goal abandoned: %s", out.abandoned->c_str());
      Status("goal abandoned: " + *out.abandoned);
    }
    if (out.trajectory) Send(*out.trajectory, stamp);
  }

  void Send(const PlanResult& plan, const ros::Time& stamp) {
    quad_msgs::Bspline b;
    b.order = plan.spline->order();
    b.traj_id = plan.traj_id;
    b.start_time = ros::Time(plan.start_time_s);
    b.knots = plan.spline->knots();
    const Eigen::MatrixXd& q = plan.spline->ctrl_pts();
    b.pos_pts.reserve(q.rows());
    for (int i = 0; i < q.rows(); ++i) b.pos_pts.push_back(ToPoint(q.row(i).transpose()));
    b.yaw_dt = 0.0;  // no yaw points: the tracker faces the direction of travel (so does the camera)
    bspline_pub_.publish(b);
    pending_ = b;
    SendPending();
    if (pending_) {
      ROS_WARN_THROTTLE(kLogThrottleS,
                        "fast_planner: tracker action server not connected yet: trajectory %ld waits",
                        static_cast<long>(plan.traj_id));
    }
    if (plan.reason == "emergency stop") {
      Status("emergency stop");
    }
    PublishTiming(plan, stamp);
    PublishMarkers(plan);
  }

  void PublishTiming(const PlanResult& plan, const ros::Time& stamp) {
    quad_msgs::PlanTiming t;
    t.header.stamp = stamp;
    t.header.frame_id = "world";
    t.traj_id = plan.traj_id;
    t.map_update_ms = last_map_update_ms_;
    t.frontend_ms = plan.timings.frontend_ms;
    t.optimization_ms = plan.timings.optimization_ms;
    t.total_ms = plan.timings.total_ms;
    t.status = plan.reason;
    timing_pub_.publish(t);
  }

  void Status(const std::string& s) {
    std_msgs::String m;
    m.data = s;
    status_pub_.publish(m);
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

  void PublishMarkers(const PlanResult& plan) {
    if (markers_pub_.getNumSubscribers() == 0) return;
    visualization_msgs::MarkerArray a;
    auto path = NewMarker("frontend_path", visualization_msgs::Marker::LINE_STRIP, 0.03, 0.2f, 0.4f, 1.0f);
    for (double t = 0.0; t <= plan.frontend_path.duration_s(); t += 0.05) {
      path.points.push_back(ToPoint(plan.frontend_path.Position(t)));
    }
    auto traj = NewMarker("trajectory", visualization_msgs::Marker::LINE_STRIP, 0.05, 1.0f, 0.3f, 0.1f);
    for (double t = 0.0; t <= plan.spline->tmax(); t += 0.05) {
      const Eigen::VectorXd p = plan.spline->Evaluate(t);
      traj.points.push_back(ToPoint(Eigen::Vector3d(p[0], p[1], p[2])));
    }
    auto ctrl = NewMarker("control_points", visualization_msgs::Marker::SPHERE_LIST, 0.1, 0.1f, 0.8f, 0.2f);
    const Eigen::MatrixXd& q = plan.spline->ctrl_pts();
    for (int i = 0; i < q.rows(); ++i) ctrl.points.push_back(ToPoint(q.row(i).transpose()));
    a.markers = {path, traj, ctrl};
    markers_pub_.publish(a);
  }

  // The occupied (and inflated) voxels of the local window in a horizontal slice at the vehicle's height.
  void PublishMapSlice() {
    if (markers_pub_.getNumSubscribers() == 0 || odom_.empty()) return;
    const ros::WallTime now = ros::WallTime::now();
    if ((now - last_slice_).toSec() < kMapSlicePeriodS) return;
    last_slice_ = now;
    const VoxelMap& map = replanner_.manager().map();
    Eigen::Vector3i lo, hi;
    map.LocalWindow(odom_.back().p_world_body, &lo, &hi);
    const int z = map.ToIndex(odom_.back().p_world_body).z();
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
    markers_pub_.publish(a);
  }

  ros::NodeHandle nh_;
  PlannerConfig cfg_;
  Replanner replanner_;
  std::string consumer_;
  std::unique_ptr<actionlib::SimpleActionClient<quad_msgs::TrackBsplineAction>> tracker_;
  std::optional<quad_msgs::Bspline> pending_;
  tf2_ros::Buffer tf_buffer_;
  tf2_ros::TransformListener tf_listener_;
  ros::Publisher bspline_pub_, timing_pub_, status_pub_, markers_pub_, ack_pub_;
  ros::Subscriber odom_sub_, depth_sub_, info_sub_, goal_sub_, status_sub_, voxel_sub_;
  std::optional<CameraIntrinsics> intrinsics_;
  std::optional<std::pair<Eigen::Vector3d, Eigen::Quaterniond>> mount_;
  std::deque<Odometry> odom_;
  std::optional<uint32_t> episode_id_;
  std::optional<std::vector<Eigen::Vector3d>> global_points_;
  double last_map_update_ms_ = 0.0;
  ros::WallTime last_slice_;
};

}  // namespace
}  // namespace fast_planner

int main(int argc, char** argv) {
  ros::init(argc, argv, "fast_planner");
  ros::NodeHandle nh, pnh("~");
  try {
    fast_planner::FastPlannerNode node(nh, pnh);
    ros::spin();
  } catch (const std::exception& e) {
    ROS_FATAL("fast_planner: %s", e.what());
    return 1;
  }
  return 0;
}
