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
//
// Data collection (issue 6, docs/collect.md): with ~collector_output_dir set, every successful plan is
// recorded by an embedded cpp_data_collector::DatasetWriter right after planning (PlanObserver), with exactly
// the depth frame and odometry the plan used, the goal, the B-spline, status, timings, episode id and world
// seed (from sim/status). The dataset is finalised after ros::spin() returns (SIGINT); writer statistics are
// logged periodically and at exit.
//
// Labeller mode (~label_every_frame true; issue 9, docs/imitation_learning.md): the expert does not fly. On
// every depth frame it updates the map and plans from the vehicle's state at that frame (the newest odometry
// not after the frame's stamp, moved on at its velocity to the stamp, with the acceleration of the odometry's
// last ~label_acc_window_s (default 0.05 s; 0: zero acceleration), AccelerationFromOdometry) to the current
// goal, publishes the plan on planner/bspline with start_time = the frame's header.stamp exactly (the pairing
// key of the imitation collector), or an empty Bspline with that start_time when it has no plan, sends
// nothing to the tracker, and still acknowledges every frame (after publishing). Goals are checked and
// answered on planner/status as in flight mode; the replanning state machine is not used.
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

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <deque>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "cpp_data_collector/dataset_writer.h"
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

// The embedded data collector: a PlanObserver that converts each successful plan into a
// cpp_data_collector::PlanRecord and hands it to the DatasetWriter (which copies it and writes on its own
// thread). Owned by the node; the planner manager holds a shared_ptr to it.
class PlanCollector : public PlanObserver {
 public:
  // `config_path`: a writer YAML (config/collector.yaml); `output_dir` overrides its output_dir. The writer
  // itself is created at the first camera_info (the intrinsics go into every shard header).
  PlanCollector(const std::string& config_path, const std::string& output_dir, const std::string& commit,
                std::vector<std::pair<std::string, std::string>> run_info, cpp_data_collector::OpenMode mode)
      : run_info_(std::move(run_info)), mode_(mode) {
    config_ = config_path.empty() ? cpp_data_collector::WriterConfig()
                                  : cpp_data_collector::LoadWriterConfigFile(config_path);
    config_.output_dir = output_dir;
    if (!commit.empty()) config_.software_commit = commit;
    config_.Validate();
    // Refuse an existing dataset now (the writer would too, but only at the first camera_info).
    namespace fs = std::filesystem;
    if (mode_ == cpp_data_collector::OpenMode::kCreate &&
        fs::exists(fs::path(output_dir) / "manifest.yaml")) {
      throw std::runtime_error("collector output directory " + output_dir +
                               " already holds a dataset (manifest.yaml); choose another output_dir");
    }
    bspline_.knots.reserve(config_.max_ctrl_pts + 8);
    bspline_.ctrl_pts_world.reserve(config_.max_ctrl_pts);
    record_us_.reserve(1 << 16);
  }

  bool started() const { return writer_ != nullptr; }

  void Start(const CameraIntrinsics& k) {
    if (writer_) return;
    config_.image_width = static_cast<uint32_t>(k.width);
    config_.image_height = static_cast<uint32_t>(k.height);
    config_.camera_fx_px = k.fx;
    config_.camera_fy_px = k.fy;
    config_.camera_cx_px = k.cx;
    config_.camera_cy_px = k.cy;
    writer_ = std::make_unique<cpp_data_collector::DatasetWriter>(config_, cpp_data_collector::WriterHooks{},
                                                                  mode_);
    for (const auto& [key, value] : run_info_) writer_->SetRunInfo(key, value);
    ROS_INFO("fast_planner: recording every plan to %s (%ux%u, queue %u, policy %s, commit %s)",
             config_.output_dir.c_str(), config_.image_width, config_.image_height, config_.queue_capacity,
             cpp_data_collector::ToString(config_.full_queue_policy), config_.software_commit.c_str());
  }

  void SetEpisode(int64_t episode_id, uint64_t world_seed) {
    episode_id_ = episode_id;
    world_seed_ = world_seed;
  }
  void SetMapUpdateMs(double ms) { map_update_ms_ = ms; }

  void OnPlan(const PlanRecord& plan) override {
    if (!plan.result || !plan.result->spline) return;
    if (!writer_ || !plan.depth || !plan.odometry) {
      ++not_recorded_;
      ROS_WARN_THROTTLE(kLogThrottleS, "fast_planner: plan not recorded (%s); %lu so far",
                        !writer_ ? "collector not started: no camera_info yet"
                                 : (!plan.depth ? "no depth frame" : "no odometry"),
                        static_cast<unsigned long>(not_recorded_));
      return;
    }
    const auto t0 = std::chrono::steady_clock::now();
    const PlanResult& res = *plan.result;
    const DepthFrame& d = *plan.depth;
    const Odometry& o = *plan.odometry;
    cpp_data_collector::PlanRecord r;
    r.episode_id = episode_id_;
    r.world_seed = world_seed_;
    r.sim_time_s = plan.request.start_time_s;
    r.depth.data_m = d.depth_m.data();
    r.depth.width = static_cast<uint32_t>(d.intrinsics.width);
    r.depth.height = static_cast<uint32_t>(d.intrinsics.height);
    r.depth.row_stride_bytes = 0;
    r.depth.stamp_s = d.stamp_s;
    r.odom.stamp_s = o.stamp_s;
    r.odom.p_world_body = {o.p_world_body.x(), o.p_world_body.y(), o.p_world_body.z()};
    r.odom.v_world = {o.v_world.x(), o.v_world.y(), o.v_world.z()};
    const Eigen::Quaterniond q = o.q_world_body.normalized();
    r.odom.q_world_body = {q.x(), q.y(), q.z(), q.w()};
    r.odom.w_body = {o.w_body.x(), o.w_body.y(), o.w_body.z()};
    r.goal_world = {plan.goal.x(), plan.goal.y(), plan.goal.z()};
    const kr_tracker::NonUniformBspline& sp = *res.spline;
    bspline_.order = sp.order();
    bspline_.traj_id = res.traj_id;
    bspline_.start_time_s = res.start_time_s;
    bspline_.knots.assign(sp.knots().begin(), sp.knots().end());
    const Eigen::MatrixXd& cp = sp.ctrl_pts();
    bspline_.ctrl_pts_world.resize(static_cast<size_t>(cp.rows()));
    for (Eigen::Index i = 0; i < cp.rows(); ++i) {
      bspline_.ctrl_pts_world[static_cast<size_t>(i)] = {cp(i, 0), cp(i, 1), cp(i, 2)};
    }
    bspline_.yaw_pts.clear();  // no yaw points: the tracker faces the direction of travel
    bspline_.yaw_dt_s = 0.0;
    r.bspline = std::move(bspline_);
    // The front end's outcome (reached goal / horizon / safe stop): every recorded plan succeeded.
    r.status.code = static_cast<int32_t>(res.search_status);
    r.status.text = res.reason;
    r.timings = {map_update_ms_, res.timings.frontend_ms, res.timings.optimization_ms, res.timings.total_ms};
    const cpp_data_collector::RecordResult rr = writer_->Record(r);
    bspline_ = std::move(r.bspline);  // keep the vectors' capacity
    const double us =
        std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - t0).count();
    if (record_us_.size() < record_us_.capacity()) record_us_.push_back(us);
    if (!rr.ok()) {
      ROS_WARN_THROTTLE(kLogThrottleS, "fast_planner: record %s%s%s (written %lu, dropped %lu, rejected %lu)",
                        cpp_data_collector::ToString(rr.status), rr.reason.empty() ? "" : ": ",
                        rr.reason.c_str(), static_cast<unsigned long>(writer_->stats().written),
                        static_cast<unsigned long>(writer_->stats().dropped),
                        static_cast<unsigned long>(writer_->stats().rejected));
    }
  }

  std::string StatsLine() const {
    if (!writer_) return "collector not started (no camera_info received)";
    const cpp_data_collector::WriterStats s = writer_->stats();
    char buf[512];
    std::snprintf(
        buf, sizeof(buf),
        "collector %s: submitted %lu, written %lu, dropped %lu, rejected %lu, lost %lu, not recorded "
        "%lu, shards %lu, %.1f MB, queue high water %u, blocked calls %lu%s%s; Record() %s",
        config_.output_dir.c_str(), static_cast<unsigned long>(s.submitted),
        static_cast<unsigned long>(s.written), static_cast<unsigned long>(s.dropped),
        static_cast<unsigned long>(s.rejected), static_cast<unsigned long>(s.lost),
        static_cast<unsigned long>(not_recorded_), static_cast<unsigned long>(s.shards_completed),
        static_cast<double>(s.bytes_written) / 1e6, s.queue_high_water,
        static_cast<unsigned long>(s.blocked_calls), s.failed ? ", writer error: " : "", s.last_error.c_str(),
        RecordCostText().c_str());
    return buf;
  }

  // Completes the dataset (drains the queue, final manifest). Returns false on a writer error. Runs after
  // ros::spin() has returned, when rosconsole is already shut down: prints to stdout/stderr directly.
  bool Finalize() {
    if (!writer_) {
      std::fprintf(stderr, "[fast_planner] %s\n", StatsLine().c_str());
      return true;
    }
    const cpp_data_collector::FinalizeResult f = writer_->Finalize();
    if (f.ok) {
      std::fprintf(stdout, "[fast_planner] dataset finalised: %s\n", StatsLine().c_str());
    } else {
      std::fprintf(stderr, "[fast_planner] dataset finalised with an error (%s): %s\n", f.error.c_str(),
                   StatsLine().c_str());
    }
    std::fflush(stdout);
    return f.ok;
  }

 private:
  std::string RecordCostText() const {
    if (record_us_.empty()) return "not called";
    std::vector<double> v = record_us_;
    std::sort(v.begin(), v.end());
    const auto q = [&](double f) { return v[std::min(v.size() - 1, static_cast<size_t>(f * v.size()))]; };
    char buf[128];
    std::snprintf(buf, sizeof(buf), "median %.1f us, p99 %.1f us over %zu plans", q(0.5), q(0.99), v.size());
    return buf;
  }

  cpp_data_collector::WriterConfig config_;
  std::vector<std::pair<std::string, std::string>> run_info_;
  cpp_data_collector::OpenMode mode_;
  std::unique_ptr<cpp_data_collector::DatasetWriter> writer_;
  cpp_data_collector::BsplineData bspline_;
  int64_t episode_id_ = -1;
  uint64_t world_seed_ = 0;
  double map_update_ms_ = 0.0;
  uint64_t not_recorded_ = 0;
  std::vector<double> record_us_;
};

class FastPlannerNode {
 public:
  FastPlannerNode(ros::NodeHandle nh, ros::NodeHandle pnh)
      : nh_(nh),
        cfg_(LoadPlannerConfig(pnh.param<std::string>("config", ""))),
        replanner_(cfg_),
        consumer_(pnh.param<std::string>("frame_ack_consumer", "fast_planner")),
        tracker_accept_timeout_s_(pnh.param<double>("tracker_accept_timeout_s", 1.0)),
        label_every_frame_(pnh.param<bool>("label_every_frame", false)),
        label_acc_window_s_(pnh.param<double>("label_acc_window_s", 0.05)),
        odom_period_s_(pnh.param<double>("odom_period_s", 0.005)),
        tf_listener_(tf_buffer_) {
    if (!(std::isfinite(label_acc_window_s_) && label_acc_window_s_ >= 0.0)) {
      throw std::invalid_argument("fast_planner: ~label_acc_window_s must be finite and >= 0, got " +
                                  std::to_string(label_acc_window_s_));
    }
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
    ROS_INFO("fast_planner: map source %s, max %.1f m/s, %.1f m/s^2, horizon %.1f m%s",
             ToString(cfg_.map.source), cfg_.limits.max_vel_mps, cfg_.limits.max_acc_mps2,
             cfg_.search.horizon_m,
             label_every_frame_ ? "; labeller mode (plans every frame, never flies)" : "");
    const std::string out_dir = pnh.param<std::string>("collector_output_dir", "");
    if (!out_dir.empty()) {
      collector_ = std::make_shared<PlanCollector>(
          pnh.param<std::string>("collector_config", ""), out_dir,
          pnh.param<std::string>("collector_commit", ""), ReadRunInfo(pnh),
          // collect.launch resume:=true (docs/collect.md, "Resuming")
          pnh.param<bool>("collector_append", false) ? cpp_data_collector::OpenMode::kAppend
                                                     : cpp_data_collector::OpenMode::kCreate);
      replanner_.manager().SetObserver(collector_);
      const double period = pnh.param<double>("collector_stats_period_s", 30.0);
      if (period > 0.0) {
        stats_timer_ = nh_.createWallTimer(ros::WallDuration(period), [this](const ros::WallTimerEvent&) {
          ROS_INFO("fast_planner: %s", collector_->StatsLine().c_str());
        });
      }
    }
  }

  // Completes the dataset, if recording (after ros::spin() returns). False on a writer error.
  bool FinalizeCollector() {
    stats_timer_.stop();
    return !collector_ || collector_->Finalize();
  }

 private:
  // ~collector_run_info: a mapping of scalars for the manifest's run_info (seeds, episodes, ...).
  static std::vector<std::pair<std::string, std::string>> ReadRunInfo(const ros::NodeHandle& pnh) {
    std::vector<std::pair<std::string, std::string>> out;
    XmlRpc::XmlRpcValue v;
    if (!pnh.getParam("collector_run_info", v)) return out;
    if (v.getType() != XmlRpc::XmlRpcValue::TypeStruct) {
      throw std::runtime_error("~collector_run_info must be a mapping of key: value");
    }
    for (auto it = v.begin(); it != v.end(); ++it) {
      XmlRpc::XmlRpcValue& x = it->second;
      std::string text;
      switch (x.getType()) {
        case XmlRpc::XmlRpcValue::TypeString:
          text = static_cast<std::string>(x);
          break;
        case XmlRpc::XmlRpcValue::TypeInt:
          text = std::to_string(static_cast<int>(x));
          break;
        case XmlRpc::XmlRpcValue::TypeBoolean:
          text = static_cast<bool>(x) ? "true" : "false";
          break;
        case XmlRpc::XmlRpcValue::TypeDouble: {
          char buf[64];
          std::snprintf(buf, sizeof(buf), "%.17g", static_cast<double>(x));
          text = buf;
          break;
        }
        default:
          text = x.toXml();
      }
      out.emplace_back(it->first, text);
    }
    return out;
  }

  void OnOdom(const nav_msgs::Odometry::ConstPtr& msg) {
    ConnectTracker();
    if (msg->header.stamp < episode_start_) return;  // the previous episode's, arriving after the reset
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
      if (label_every_frame_) {
        replanner_.manager().UpdateOdometry(o);  // validates; the plan sets the one it used again
      } else {
        Handle(replanner_.OnOdometry(o), msg->header.stamp);
      }
    } catch (const std::invalid_argument& e) {
      ROS_WARN_THROTTLE(kLogThrottleS, "fast_planner: skipping odometry: %s", e.what());
      return;
    }
    odom_.push_back(o);
    if (odom_.size() > kOdomBuffer) odom_.pop_front();
    if (pending_depth_ && OdometryCovers(pending_depth_->header.stamp)) {
      const auto frame = pending_depth_;
      pending_depth_.reset();
      HandleDepth(frame);
    }
  }

  void OnInfo(const sensor_msgs::CameraInfo::ConstPtr& msg) {
    CameraIntrinsics k{static_cast<int>(msg->width),
                       static_cast<int>(msg->height),
                       msg->K[0],
                       msg->K[4],
                       msg->K[2],
                       msg->K[5]};
    intrinsics_ = k;
    if (collector_ && !collector_->started()) {
      try {
        collector_->Start(k);
      } catch (const std::exception& e) {
        ROS_FATAL("fast_planner: cannot start the data collector: %s", e.what());
        collector_failed_ = true;
        ros::shutdown();
      }
    }
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
    if (!tracker_ && !label_every_frame_ && !ros::Time::now().isZero()) {
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
    WaitForTrackerAccept(goal.bspline.traj_id);
  }

  // Waits (wall time, bounded) until the tracker has taken the goal just sent. The action client spins its
  // own thread. In lockstep this makes the new trajectory take effect before the simulator advances (the
  // frame is acknowledged after this returns), so the flight does not depend on message timing.
  void WaitForTrackerAccept(int64_t traj_id) {
    if (tracker_accept_timeout_s_ <= 0.0) return;
    const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(tracker_accept_timeout_s_);
    while (tracker_->getState() == actionlib::SimpleClientGoalState::PENDING) {
      if (ros::WallTime::now() > deadline || !ros::ok()) {
        ++tracker_accept_timeouts_;
        ROS_WARN("fast_planner: the tracker did not take trajectory %ld within %.2f s (%lu times so far)",
                 static_cast<long>(traj_id), tracker_accept_timeout_s_,
                 static_cast<unsigned long>(tracker_accept_timeouts_));
        return;
      }
      ros::WallDuration(0.0002).sleep();
    }
  }

  // Odometry and depth arrive on separate connections, so a frame may overtake the odometry it belongs to. In
  // lockstep the simulator publishes nothing newer until this frame is acknowledged, so waiting for the
  // odometry of the frame's control period (newest odometry within one period before the stamp) makes what
  // every frame is planned from, and so every record, independent of message timing. A newer frame arriving
  // meanwhile (odometry lost or not lockstepped) releases the waiting one with the odometry there is.
  bool OdometryCovers(const ros::Time& stamp) const {
    return !odom_.empty() && odom_.back().stamp_s > stamp.toSec() - odom_period_s_ + 1e-6;
  }

  void OnDepth(const sensor_msgs::Image::ConstPtr& msg) {
    if (pending_depth_) {
      const auto waiting = pending_depth_;
      pending_depth_.reset();
      HandleDepth(waiting);
    }
    // Only a frame that can be used waits (a malformed one is skipped with its log line at once).
    if (msg->header.stamp >= episode_start_ && msg->encoding == sensor_msgs::image_encodings::TYPE_32FC1 &&
        !OdometryCovers(msg->header.stamp)) {
      pending_depth_ = msg;
      return;
    }
    HandleDepth(msg);
  }

  void HandleDepth(const sensor_msgs::Image::ConstPtr& msg) {
    ConnectTracker();
    SendPending();
    // A frame of the previous episode arriving after the reset is acknowledged but not used.
    labelled_ = false;
    if (msg->header.stamp >= episode_start_) {
      ProcessDepth(*msg);
      last_depth_stamp_ = std::max(last_depth_stamp_, msg->header.stamp);
    }
    // Labeller: every frame gets an answer before its acknowledgement (an empty B-spline = no plan).
    if (label_every_frame_ && !labelled_) PublishLabel(nullptr, msg->header.stamp);
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
    if (label_every_frame_) {
      LabelFrame(frame, msg.header.stamp);
      PublishMapSlice();
      return;
    }
    try {
      out = replanner_.OnDepth(frame, &map_update);
    } catch (const std::invalid_argument& e) {
      ROS_WARN_THROTTLE(kLogThrottleS, "fast_planner: skipping depth frame: %s", e.what());
      return;
    }
    last_map_update_ms_ = map_update.total_ms;
    if (collector_) collector_->SetMapUpdateMs(map_update.total_ms);
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
    if (label_every_frame_) {
      const Eigen::Vector3d g(p.x, p.y, p.z);
      const std::string why = replanner_.manager().CheckGoal(g);
      if (!why.empty()) {
        ROS_WARN("fast_planner: goal (%.2f, %.2f, %.2f) rejected: %s", p.x, p.y, p.z, why.c_str());
        Status("goal rejected: " + why);
        return;
      }
      label_goal_ = g;
      char buf[128];
      std::snprintf(buf, sizeof(buf), "goal accepted: (%.3f, %.3f, %.3f) at %.3f (labeller)", p.x, p.y, p.z,
                    last_depth_stamp_.toSec());
      Status(buf);
      return;
    }
    ReplannerOutput out;
    // The plan's time is the newest sensor stamp received (the depth frame or odometry it plans from), not
    // the clock: in lockstep this makes a goal's plan independent of when the message arrived.
    ros::Time now = last_depth_stamp_;
    if (!odom_.empty()) now = std::max(now, ros::Time(odom_.back().stamp_s));
    if (now.isZero()) now = ros::Time::now();
    const std::string why = replanner_.SetGoal(Eigen::Vector3d(p.x, p.y, p.z), now.toSec(), &out);
    if (!why.empty()) {
      ROS_WARN("fast_planner: goal (%.2f, %.2f, %.2f) rejected: %s", p.x, p.y, p.z, why.c_str());
      Status("goal rejected: " + why);
      return;
    }
    ROS_INFO("fast_planner: new goal (%.2f, %.2f, %.2f)", p.x, p.y, p.z);
    Handle(out, now);
    // After the plan (and the tracker taking it): an episode manager may advance the simulator on this.
    char buf[128];
    std::snprintf(buf, sizeof(buf), "goal accepted: (%.3f, %.3f, %.3f) at %.3f", p.x, p.y, p.z, now.toSec());
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
      // Odometry of the new episode that arrived before this status (another connection) is kept.
      std::deque<Odometry> early;
      for (const Odometry& o : odom_) {
        if (o.stamp_s >= episode_start_.toSec()) early.push_back(o);
      }
      replanner_.Reset();
      label_goal_.reset();
      odom_.clear();
      pending_.reset();
      last_depth_stamp_ = ros::Time();
      if (global_points_) replanner_.manager().SetGlobalMap(*global_points_);
      for (const Odometry& o : early) {
        if (label_every_frame_) {
          replanner_.manager().UpdateOdometry(o);
        } else {
          Handle(replanner_.OnOdometry(o), ros::Time(o.stamp_s));
        }
        odom_.push_back(o);
      }
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

  // Labeller mode: map update, then one plan from the state at the frame's stamp to the goal.
  void LabelFrame(const std::shared_ptr<DepthFrame>& frame, const ros::Time& stamp) {
    PlannerManager& m = replanner_.manager();
    try {
      last_map_update_ms_ = m.UpdateDepth(frame).total_ms;
    } catch (const std::invalid_argument& e) {
      ROS_WARN_THROTTLE(kLogThrottleS, "fast_planner: skipping depth frame: %s", e.what());
      return;
    }
    if (collector_) collector_->SetMapUpdateMs(last_map_update_ms_);
    if (!label_goal_) return;  // answered with an empty B-spline
    const double t = stamp.toSec();
    const Odometry* best = nullptr;
    for (const auto& o : odom_) {
      if (o.stamp_s <= t + 1e-9) best = &o;
    }
    if (!best) return;
    m.UpdateOdometry(*best);  // the collector records exactly the odometry this plan starts from
    PlanRequest req;
    req.start_p = best->p_world_body + best->v_world * (t - best->stamp_s);
    req.start_v = best->v_world;
    // The vehicle's own acceleration, within the planner's limit: a plan from zero acceleration, flown for
    // one frame and replaced, would never let the vehicle speed up (the learner trained on such labels
    // crept).
    req.start_a = AccelerationFromOdometry(odom_, t, label_acc_window_s_, cfg_.limits.max_acc_mps2);
    req.goal = *label_goal_;
    req.start_time_s = t;
    const PlanResult plan = m.Plan(req);
    PublishTiming(plan, stamp);
    if (plan.status != PlanStatus::kSuccess || !plan.spline) {
      ROS_WARN_THROTTLE(kLogThrottleS, "fast_planner: label plan failed: %s", plan.reason.c_str());
      return;
    }
    PublishLabel(&plan, stamp);
    PublishMarkers(plan);
  }

  // planner/bspline in labeller mode: the plan with start_time = the frame's stamp, or an empty B-spline.
  void PublishLabel(const PlanResult* plan, const ros::Time& stamp) {
    quad_msgs::Bspline b;
    b.start_time = stamp;
    if (plan) {
      b.order = plan->spline->order();
      b.traj_id = plan->traj_id;
      b.knots = plan->spline->knots();
      const Eigen::MatrixXd& q = plan->spline->ctrl_pts();
      b.pos_pts.reserve(q.rows());
      for (int i = 0; i < q.rows(); ++i) b.pos_pts.push_back(ToPoint(q.row(i).transpose()));
    } else {
      b.order = 3;
    }
    b.yaw_dt = 0.0;
    bspline_pub_.publish(b);
    labelled_ = true;
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
    // The ESDF computed on demand for this plan (map.esdf_on_demand) is map work too.
    t.map_update_ms = last_map_update_ms_ + plan.timings.map_prep_ms;
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
  double tracker_accept_timeout_s_ = 1.0;
  uint64_t tracker_accept_timeouts_ = 0;
  bool label_every_frame_ = false;
  double label_acc_window_s_ = 0.05;
  // The simulator's odometry period: a depth frame is processed once the odometry of its control period has
  // been received (see OnDepth).
  double odom_period_s_ = 0.005;
  sensor_msgs::Image::ConstPtr pending_depth_;
  bool labelled_ = false;                      // labeller: this frame's answer was published
  std::optional<Eigen::Vector3d> label_goal_;  // labeller: the episode's goal
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
  ros::Time episode_start_;     // stamp of the current episode's start (messages before it are stale)
  ros::Time last_depth_stamp_;  // newest depth frame processed in this episode
  std::shared_ptr<PlanCollector> collector_;
  ros::WallTimer stats_timer_;

 public:
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
    return ok && !node.collector_failed_ ? 0 : 1;
  } catch (const std::exception& e) {
    ROS_FATAL("fast_planner: %s", e.what());
    return 1;
  }
}
