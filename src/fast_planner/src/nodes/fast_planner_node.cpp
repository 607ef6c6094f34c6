// fast_planner_node: the thin ROS adapter of the expert (docs/fast_planner.md): parameters, subscriptions,
// message conversion (src/ros/conversions.h) and timers around fast_planner::ExpertSession (flight or
// labeller mode, frame/odometry pairing, episodes, the embedded data collector of docs/collect.md). Every
// depth frame is acknowledged on sim/frame_ack after it was handled (the lockstep protocol of
// docs/CONVENTIONS.md); malformed input is skipped with a throttled log line. The dataset is finalised after
// ros::spin() returns (SIGINT).
#include <geometry_msgs/PoseStamped.h>
#include <quad_msgs/EpisodeStatus.h>
#include <quad_msgs/FrameAck.h>
#include <quad_ros/vocabulary.h>
#include <ros/ros.h>
#include <sensor_msgs/image_encodings.h>
#include <std_msgs/String.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/transform_listener.h>

#include <cstdio>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "../ros/conversions.h"
#include "../ros/params.h"
#include "../ros/tracker_link.h"
#include "fast_planner/expert_session.h"

namespace fast_planner {
namespace {

namespace conv = ros_conv;
constexpr double kLogThrottleS = 2.0;
constexpr double kMapSlicePeriodS = 0.5;  // map slice markers at most this often (wall time)

class FastPlannerNode {
 public:
  FastPlannerNode(ros::NodeHandle nh, ros::NodeHandle pnh)
      : nh_(nh),
        expert_(LoadPlannerConfig(conv::RequiredParam<std::string>(pnh, "config")),
                conv::RequiredParam<bool>(pnh, "label_every_frame")),
        consumer_(conv::RequiredParam<std::string>(pnh, "frame_ack_consumer")),
        tracker_(nh, expert_.config().node.tracker_accept_timeout_s),
        tf_listener_(tf_buffer_) {
    const PlannerConfig& cfg = expert_.config();
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
    if (cfg.map.source == MapSource::kGlobal) {
      voxel_sub_ = nh_.subscribe("sim/voxel_map", 1, &FastPlannerNode::OnVoxelMap, this);
    }
    ROS_INFO("fast_planner: map source %s, max %.1f m/s, %.1f m/s^2, horizon %.1f m%s",
             ToString(cfg.map.source), cfg.limits.max_vel_mps, cfg.limits.max_acc_mps2, cfg.search.horizon_m,
             Labeller() ? "; labeller mode (plans every frame, never flies)" : "");
    collector_ = conv::MakeCollector(pnh, kLogThrottleS);
    if (!collector_) return;
    expert_.SetCollector(collector_);
    if (cfg.node.collector_stats_period_s > 0.0) {
      stats_timer_ = nh_.createWallTimer(ros::WallDuration(cfg.node.collector_stats_period_s),
                                         [this](const ros::WallTimerEvent&) {
                                           ROS_INFO("fast_planner: %s", collector_->StatsLine().c_str());
                                         });
    }
  }

  // Completes the dataset, if recording (after ros::spin() returns, when rosconsole is already shut down:
  // prints directly). False on a writer error.
  bool FinalizeCollector() {
    stats_timer_.stop();
    if (!collector_) return true;
    const PlanCollector::Finalized f = collector_->Finalize();
    std::fprintf(f.ok && collector_->started() ? stdout : stderr, "[fast_planner] %s\n", f.text.c_str());
    std::fflush(stdout);
    return f.ok;
  }

  bool collector_failed() const { return collector_failed_; }

 private:
  bool Labeller() const { return expert_.labeller_mode(); }

  void OnOdom(const nav_msgs::Odometry::ConstPtr& msg) {
    if (!Labeller()) tracker_.Connect();
    if (msg->header.stamp < episode_start_) return;  // the previous episode's, arriving after the reset
    try {
      Handle(expert_.OnOdometry(quad_ros::ToVehicleState(*msg)), msg->header.stamp);
    } catch (const std::invalid_argument& e) {
      ROS_WARN_THROTTLE(kLogThrottleS, "fast_planner: skipping odometry: %s", e.what());
      return;
    }
    if (pending_depth_ && expert_.FrameCovered(pending_depth_->header.stamp.toSec())) {
      const auto frame = pending_depth_;
      pending_depth_.reset();
      HandleDepth(frame);
    }
  }

  void OnInfo(const sensor_msgs::CameraInfo::ConstPtr& msg) {
    intrinsics_ = quad_ros::ToIntrinsics(*msg);
    if (!collector_ || collector_->started()) return;
    try {
      ROS_INFO("fast_planner: %s", collector_->Start(*intrinsics_).c_str());
    } catch (const std::exception& e) {
      ROS_FATAL("fast_planner: cannot start the data collector: %s", e.what());
      collector_failed_ = true;
      ros::shutdown();
    }
  }

  // A frame waits until the odometry of its control period has arrived; a newer frame arriving meanwhile
  // (odometry lost or not lockstepped) releases the waiting one with the odometry there is.
  void OnDepth(const sensor_msgs::Image::ConstPtr& msg) {
    if (pending_depth_) {
      const auto waiting = pending_depth_;
      pending_depth_.reset();
      HandleDepth(waiting);
    }
    // Only a frame that can be used waits (a malformed one is skipped with its log line at once).
    if (msg->header.stamp >= episode_start_ && msg->encoding == sensor_msgs::image_encodings::TYPE_32FC1 &&
        !expert_.FrameCovered(msg->header.stamp.toSec())) {
      pending_depth_ = msg;
      return;
    }
    HandleDepth(msg);
  }

  void HandleDepth(const sensor_msgs::Image::ConstPtr& msg) {
    if (!Labeller()) tracker_.Connect();
    tracker_.SendPending();
    labelled_ = false;
    // A frame of the previous episode arriving after the reset is acknowledged but not used.
    if (msg->header.stamp >= episode_start_) {
      ProcessDepth(*msg);
      last_depth_stamp_ = std::max(last_depth_stamp_, msg->header.stamp);
    }
    // Labeller: every frame gets an answer before its acknowledgement (an empty B-spline = no plan).
    if (Labeller() && !labelled_) PublishLabel(conv::EmptyBsplineMessage(msg->header.stamp));
    // Every frame is acknowledged, also a skipped one: the simulator must not wait on a frame we cannot use.
    quad_msgs::FrameAck ack;
    ack.consumer = consumer_;
    ack.frame_seq = msg->header.seq;
    ack.stamp = msg->header.stamp;
    ack_pub_.publish(ack);
  }

  void ProcessDepth(const sensor_msgs::Image& msg) {
    const std::string problem = conv::DepthFrameProblem(msg, intrinsics_ ? &*intrinsics_ : nullptr);
    if (!problem.empty()) {
      ROS_WARN_THROTTLE(kLogThrottleS, "fast_planner: %s", problem.c_str());
      return;
    }
    auto frame = conv::ToDepthFrame(msg, *intrinsics_);
    if (!CameraMountOf(msg.header.frame_id)) return;
    if (!expert_.SetCameraPose(*mount_, frame.get())) {
      ROS_WARN_THROTTLE(kLogThrottleS, "fast_planner: skipping depth frame: no odometry before it yet");
      return;
    }
    ExpertSession::FrameOutput out;
    try {
      out = expert_.OnDepth(frame);
    } catch (const std::invalid_argument& e) {
      ROS_WARN_THROTTLE(kLogThrottleS, "fast_planner: skipping depth frame: %s", e.what());
      return;
    }
    Handle(out.flight, msg.header.stamp);
    if (out.label) {  // labeller: a plan attempt (without goal or odometry: the empty answer)
      timing_pub_.publish(conv::ToPlanTiming(*out.label, msg.header.stamp, expert_.last_map_update_ms()));
      if (out.label->ok()) {
        PublishLabel(conv::ToBsplineMessage(*out.label, msg.header.stamp));
        PublishMarkers(*out.label);
      } else {
        ROS_WARN_THROTTLE(kLogThrottleS, "fast_planner: label plan failed: %s", out.label->reason.c_str());
      }
    }
    PublishMapSlice();
  }

  // The base_link -> camera mount, looked up once (tf).
  bool CameraMountOf(const std::string& camera_frame) {
    if (mount_) return true;
    try {
      mount_ = conv::ToCameraMount(
          tf_buffer_.lookupTransform("base_link", camera_frame, ros::Time(0), ros::Duration(0.5)));
    } catch (const tf2::TransformException& e) {
      ROS_WARN_THROTTLE(kLogThrottleS, "fast_planner: no base_link -> %s transform yet: %s",
                        camera_frame.c_str(), e.what());
    }
    return mount_.has_value();
  }

  void PublishLabel(const quad_msgs::Bspline& b) {
    bspline_pub_.publish(b);
    labelled_ = true;
  }

  void OnGoal(const geometry_msgs::PoseStamped::ConstPtr& msg) {
    if (!msg->header.frame_id.empty() && msg->header.frame_id != "world") {
      ROS_WARN("fast_planner: goal rejected: frame '%s' is not 'world'", msg->header.frame_id.c_str());
      Status("goal rejected: frame '" + msg->header.frame_id + "' is not 'world'");
      return;
    }
    const auto& p = msg->pose.position;
    // The plan's time is the newest sensor stamp received (the depth frame or odometry it plans from), not
    // the clock: in lockstep this makes a goal's plan independent of when the message arrived.
    ros::Time now = last_depth_stamp_;
    if (!Labeller() && !expert_.odometry().empty())
      now = std::max(now, ros::Time(expert_.odometry().newest().t_s));
    if (!Labeller() && now.isZero()) now = ros::Time::now();
    ReplannerOutput out;
    const std::string why = expert_.SetGoal(Eigen::Vector3d(p.x, p.y, p.z), now.toSec(), &out);
    if (!why.empty()) {
      ROS_WARN("fast_planner: goal (%.2f, %.2f, %.2f) rejected: %s", p.x, p.y, p.z, why.c_str());
      Status("goal rejected: " + why);
      return;
    }
    if (!Labeller()) ROS_INFO("fast_planner: new goal (%.2f, %.2f, %.2f)", p.x, p.y, p.z);
    Handle(out, now);  // an episode manager may advance the simulator on the answer below
    char buf[160];
    std::snprintf(buf, sizeof(buf), "goal accepted: (%.3f, %.3f, %.3f) at %.3f%s", p.x, p.y, p.z, now.toSec(),
                  Labeller() ? " (labeller)" : "");
    Status(buf);
  }

  void OnEpisode(const quad_msgs::EpisodeStatus::ConstPtr& msg) {
    if (collector_) collector_->SetEpisode(msg->episode_id, msg->world_seed);
    if (episode_id_ && *episode_id_ == msg->episode_id) return;
    if (episode_id_) {
      ROS_INFO("fast_planner: episode %u (world seed %lu): resetting the planner", msg->episode_id,
               static_cast<unsigned long>(msg->world_seed));
      // The new episode's first status is stamped with its start: older odometry and frames still in the
      // queues belong to the previous episode and are ignored from now on.
      if (last_depth_stamp_ >= msg->header.stamp) {
        ROS_ERROR(
            "fast_planner: a depth frame of episode %u (stamp %.3f) was processed before its status "
            "(start %.3f): this episode's map is not reproducible",
            msg->episode_id, last_depth_stamp_.toSec(), msg->header.stamp.toSec());
      }
      episode_start_ = msg->header.stamp;
      tracker_.Drop();
      last_depth_stamp_ = ros::Time();
      for (const auto& [t_s, out] : expert_.StartEpisode(episode_start_.toSec())) Handle(out, ros::Time(t_s));
    }
    episode_id_ = msg->episode_id;
  }

  void OnVoxelMap(const sensor_msgs::PointCloud2::ConstPtr& msg) {
    std::vector<Eigen::Vector3d> points;
    try {
      points = conv::ToPoints(*msg);
    } catch (const std::runtime_error& e) {
      ROS_WARN("fast_planner: voxel map without x/y/z float fields ignored: %s", e.what());
      return;
    }
    ROS_INFO("fast_planner: global map with %zu occupied voxels", points.size());
    expert_.SetGlobalMap(std::move(points));
  }

  void Handle(const ReplannerOutput& out, const ros::Time& stamp) {
    for (const auto& t : out.transitions) ROS_DEBUG("fast_planner: %s", t.c_str());
    if (!out.transitions.empty()) Status("state: " + out.transitions.back());
    for (const auto& f : out.failed_plans) {
      ROS_WARN_THROTTLE(kLogThrottleS, "fast_planner: plan failed: %s", f.reason.c_str());
      Status("plan failed: " + f.reason);
      timing_pub_.publish(conv::ToPlanTiming(f, stamp, expert_.last_map_update_ms()));
    }
    if (out.abandoned) {
      ROS_WARN("fast_planner: goal abandoned: %s", out.abandoned->c_str());
      Status("goal abandoned: " + *out.abandoned);
    }
    if (out.trajectory) Send(*out.trajectory, stamp);
  }

  void Send(const PlanResult& plan, const ros::Time& stamp) {
    const quad_msgs::Bspline b = conv::ToBsplineMessage(plan, ros::Time(plan.start_time_s));
    bspline_pub_.publish(b);
    tracker_.Send(b);
    if (tracker_.waiting()) {
      ROS_WARN_THROTTLE(kLogThrottleS,
                        "fast_planner: tracker action server not connected yet: trajectory %ld waits",
                        static_cast<long>(plan.traj_id));
    }
    if (plan.reason == "emergency stop") Status("emergency stop");
    timing_pub_.publish(conv::ToPlanTiming(plan, stamp, expert_.last_map_update_ms()));
    PublishMarkers(plan);
  }

  void Status(const std::string& s) {
    std_msgs::String m;
    m.data = s;
    status_pub_.publish(m);
  }

  void PublishMarkers(const PlanResult& plan) {
    if (markers_pub_.getNumSubscribers() > 0) markers_pub_.publish(conv::PlanMarkers(plan));
  }

  void PublishMapSlice() {
    if (markers_pub_.getNumSubscribers() == 0 || expert_.odometry().empty()) return;
    const ros::WallTime now = ros::WallTime::now();
    if ((now - last_slice_).toSec() < kMapSlicePeriodS) return;
    last_slice_ = now;
    markers_pub_.publish(
        conv::MapSliceMarkers(expert_.replanner().manager().map(), expert_.odometry().newest().p_world_body));
  }

  ros::NodeHandle nh_;
  ExpertSession expert_;
  std::string consumer_;
  conv::TrackerLink tracker_;
  sensor_msgs::Image::ConstPtr pending_depth_;  // a frame waiting for its odometry
  bool labelled_ = false;                       // labeller: this frame's answer was published
  tf2_ros::Buffer tf_buffer_;
  tf2_ros::TransformListener tf_listener_;
  ros::Publisher bspline_pub_, timing_pub_, status_pub_, markers_pub_, ack_pub_;
  ros::Subscriber odom_sub_, depth_sub_, info_sub_, goal_sub_, status_sub_, voxel_sub_;
  std::optional<quad_core::CameraIntrinsics> intrinsics_;
  std::optional<CameraMount> mount_;
  std::optional<uint32_t> episode_id_;
  ros::WallTime last_slice_;
  ros::Time episode_start_;     // stamp of the current episode's start (messages before it are stale)
  ros::Time last_depth_stamp_;  // newest depth frame processed in this episode
  std::shared_ptr<PlanCollector> collector_;
  ros::WallTimer stats_timer_;
  bool collector_failed_ = false;
};

}  // namespace
}  // namespace fast_planner

int main(int argc, char** argv) {
  ros::init(argc, argv, "fast_planner");
  ros::NodeHandle nh, pnh("~");
  try {
    fast_planner::FastPlannerNode node(nh, pnh);
    // roscpp's SIGINT handler only requests shutdown: spin returns, then the dataset is finalised here.
    ros::spin();
    const bool ok = node.FinalizeCollector();
    return ok && !node.collector_failed() ? 0 : 1;
  } catch (const std::exception& e) {
    ROS_FATAL("fast_planner: %s", e.what());
    return 1;
  }
}
