// quad_sim_node: the thin ROS wrapper of quad_sim::Simulator. It owns sim time (/clock), publishes odometry,
// depth, TF, the world and the voxel map, takes SO3/TRPY commands, serves /sim/reset and implements the time
// modes and the lockstep protocol of docs/CONVENTIONS.md. All physics, geometry and rendering live in
// quad_sim_core.
//
// Private parameters: ~config (path of sim.yaml, required), ~world_seed (int, -1: world.seed of the config).
#include "quad_sim/lockstep_peers.h"
#include "quad_sim/math_utils.h"
#include "quad_sim/simulator.h"

#include <geometry_msgs/TransformStamped.h>
#include <nav_msgs/Odometry.h>
#include <quad_common/strict_yaml.h>
#include <quad_msgs/EpisodeStatus.h>
#include <quad_msgs/FrameAck.h>
#include <quad_msgs/ResetEpisode.h>
#include <quad_msgs/SO3Command.h>
#include <quad_msgs/SimStats.h>
#include <quad_msgs/TRPYCommand.h>
#include <ros/master.h>
#include <ros/network.h>
#include <ros/ros.h>
#include <rosgraph_msgs/Clock.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/PointCloud2.h>
#include <sensor_msgs/point_cloud2_iterator.h>
#include <std_msgs/Float64.h>
#include <tf2_msgs/TFMessage.h>
#include <visualization_msgs/MarkerArray.h>
#include <xmlrpcpp/XmlRpcClient.h>

#include <chrono>
#include <condition_variable>
#include <cstring>
#include <future>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <thread>

namespace {

// ROS time of the first step: sim time starts at 1 s so that stamps are valid (non-zero) from the first
// message.
constexpr uint64_t kTimeBaseNs = 1000000000ULL;
// Resend period of an episode's first odometry while it is unanswered in lockstep
// (QuadSimNode::WaitForCommand).
constexpr double kResendPeriodS = 0.5;

geometry_msgs::Point ToPoint(const Eigen::Vector3d& v) {
  geometry_msgs::Point p;
  p.x = v.x();
  p.y = v.y();
  p.z = v.z();
  return p;
}

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

struct PendingCommand {
  enum class Kind { kNone, kSo3, kTrpy } kind = Kind::kNone;
  quad_sim::So3Command so3;
  quad_sim::TrpyCommand trpy;
};

struct ResetJob {
  quad_msgs::ResetEpisode::Request request;
  std::promise<quad_msgs::ResetEpisode::Response> done;
};

class QuadSimNode {
 public:
  QuadSimNode(ros::NodeHandle nh, const quad_sim::SimConfig& config, uint64_t world_seed)
      : nh_(nh),
        config_(config),
        sim_(config),
        dt_ns_(static_cast<uint64_t>(std::llround(config.physics_dt_s * 1e9))),
        steps_per_odom_(
            static_cast<uint64_t>(std::llround(1.0 / (config.physics_dt_s * config.odometry_rate_hz)))),
        steps_per_clock_(
            std::max<uint64_t>(1, std::llround(config.time.clock_period_s / config.physics_dt_s))) {
    // The lockstep start-up barrier needs to know who is connected to the topics lockstep depends on, by node
    // name (quad_sim/lockstep_peers.h).
    clock_pub_ = AdvertiseTracked<rosgraph_msgs::Clock>("/clock", 10);
    odom_pub_ = AdvertiseTracked<nav_msgs::Odometry>("odom", 100);
    depth_pub_ = AdvertiseTracked<sensor_msgs::Image>("camera/depth/image", 10);
    info_pub_ = AdvertiseTracked<sensor_msgs::CameraInfo>("camera/depth/camera_info", 10);
    // TF as tf2_ros's broadcasters publish it, tracked too: a consumer looking up the camera mount before its
    // /tf_static connection is up waits in sim time, which does not advance while it holds the frame.
    tf_pub_ = AdvertiseTracked<tf2_msgs::TFMessage>("/tf", 100);
    tf_static_pub_ = AdvertiseTracked<tf2_msgs::TFMessage>("/tf_static", 1, true);
    status_pub_ = nh_.advertise<quad_msgs::EpisodeStatus>("sim/status", 10, true);
    markers_pub_ = nh_.advertise<visualization_msgs::MarkerArray>("sim/world_markers", 1, true);
    voxel_pub_ = nh_.advertise<sensor_msgs::PointCloud2>("sim/voxel_map", 1, true);
    z_offset_pub_ = nh_.advertise<std_msgs::Float64>("sim/z_offset", 1, true);
    stats_pub_ = nh_.advertise<quad_msgs::SimStats>("sim/stats", 100);
    // Lockstep round trips are latency bound: disable Nagle's algorithm on every input.
    const ros::TransportHints hints = ros::TransportHints().tcpNoDelay();
    so3_sub_ = nh_.subscribe("so3_cmd", 10, &QuadSimNode::OnSo3, this, hints);
    trpy_sub_ = nh_.subscribe("trpy_cmd", 10, &QuadSimNode::OnTrpy, this, hints);
    ack_sub_ = nh_.subscribe("sim/frame_ack", 100, &QuadSimNode::OnAck, this, hints);
    reset_srv_ = nh_.advertiseService("sim/reset", &QuadSimNode::OnReset, this);

    PublishCameraMount();
    quad_msgs::ResetEpisode::Request first;
    first.seed = world_seed;
    const quad_msgs::ResetEpisode::Response r = DoReset(first);
    if (!r.success) throw std::runtime_error("initial episode: " + r.message);
    MeasureZOffset();
  }

  // The simulation loop (runs in its own thread until shutdown).
  void Run() {
    const bool lockstep = config_.time.mode == quad_sim::TimeMode::kLockstep;
    WaitForLockstepPeers();
    Anchor();
    while (ros::ok()) {
      if (HandleResetJob()) continue;
      const ros::Time now = Now();
      const bool odom_due = sim_.OdometryDue();
      const bool depth_due = sim_.DepthDue();
      if (total_steps_ % steps_per_clock_ == 0 || odom_due || depth_due) PublishClock(now);
      if (odom_due) {
        PublishOdometry(now);
        if (lockstep && config_.lockstep.wait_for_command) WaitForCommand(now);
      }
      if (depth_due) {
        // In lockstep the run statistics go out before every frame: a consumer holding a frame has the
        // timeout counts up to it (the evaluation's runner counts each episode's timeouts this way).
        if (lockstep && !config_.lockstep.depth_consumers.empty()) PublishStats();
        PublishDepth(now);
        if (lockstep && !config_.lockstep.depth_consumers.empty()) WaitForAcks(now);
      }
      if (ResetPending()) continue;  // a reset arrived during a wait: start the new episode instead
      ApplyPendingCommand();
      sim_.Step();
      ++total_steps_;
      PublishStatus(false);
      PublishStatsIfDue();
      Pace();
    }
  }

 private:
  ros::Time Now() const {
    ros::Time t;
    t.fromNSec(kTimeBaseNs + total_steps_ * dt_ns_);
    return t;
  }

  // ---- commands and acknowledgements (subscriber threads) ----
  void OnSo3(const quad_msgs::SO3Command::ConstPtr& msg) {
    quad_sim::So3Command c;
    c.force_world_N = FromVec(msg->force);
    c.q_world_des =
        Eigen::Quaterniond(msg->orientation.w, msg->orientation.x, msg->orientation.y, msg->orientation.z);
    c.w_body_des_radps = FromVec(msg->angular_velocity);
    SetGains(msg->kR, msg->kOm, &c.kR, &c.kOm);
    c.enable_motors = msg->aux.enable_motors;
    PendingCommand p;
    p.kind = PendingCommand::Kind::kSo3;
    p.so3 = c;
    Accept(p, quad_sim::ValidateCommand(c), msg->header.stamp, "SO3Command");
  }

  void OnTrpy(const quad_msgs::TRPYCommand::ConstPtr& msg) {
    quad_sim::TrpyCommand c;
    c.thrust_N = msg->thrust;
    c.roll_rad = msg->roll;
    c.pitch_rad = msg->pitch;
    c.yaw_rad = msg->yaw;
    c.w_body_des_radps = FromVec(msg->angular_velocity);
    SetGains(msg->kR, msg->kOm, &c.kR, &c.kOm);
    c.enable_motors = msg->aux.enable_motors;
    PendingCommand p;
    p.kind = PendingCommand::Kind::kTrpy;
    p.trpy = c;
    Accept(p, quad_sim::ValidateCommand(c), msg->header.stamp, "TRPYCommand");
  }

  // The message's attitude gains; all zero (the message default, never a usable attitude loop) keeps the
  // onboard defaults of kr_mav_control (kR 1.5/1.5/1.0, kOm 0.13/0.13/0.1), as an autopilot keeps its own
  // gains.
  static void SetGains(const boost::array<double, 3>& kR, const boost::array<double, 3>& kOm,
                       Eigen::Vector3d* kR_out, Eigen::Vector3d* kOm_out) {
    if (FromArray(kR).isZero(0.0) && FromArray(kOm).isZero(0.0)) return;
    *kR_out = FromArray(kR);
    *kOm_out = FromArray(kOm);
  }

  void Accept(const PendingCommand& cmd, const quad_sim::CommandStatus& status, const ros::Time& stamp,
              const char* type) {
    std::lock_guard<std::mutex> lock(mu_);
    if (!stamp.isZero() && stamp < episode_start_stamp_) return;  // an answer to the previous episode
    // Any answer (even a rejected one) releases the lockstep wait for its control period.
    last_answer_stamp_ = stamp;
    if (!status.ok()) {
      ++rejected_commands_;
      ROS_WARN_THROTTLE(1.0,
                        "quad_sim: rejected %s stamped %.3f: %s (state untouched, previous command kept)",
                        type, stamp.toSec(), status.reason.c_str());
    } else {
      pending_ = cmd;
    }
    cv_.notify_all();
  }

  void OnAck(const quad_msgs::FrameAck::ConstPtr& msg) {
    std::lock_guard<std::mutex> lock(mu_);
    ros::Time& last = acked_[msg->consumer];
    if (msg->stamp > last) last = msg->stamp;
    cv_.notify_all();
  }

  void ApplyPendingCommand() {
    PendingCommand p;
    {
      std::lock_guard<std::mutex> lock(mu_);
      p = pending_;
      pending_.kind = PendingCommand::Kind::kNone;
    }
    if (p.kind == PendingCommand::Kind::kSo3) sim_.SetSo3Command(p.so3);
    if (p.kind == PendingCommand::Kind::kTrpy) sim_.SetTrpyCommand(p.trpy);
  }

  // ---- lockstep waits ----
  // Waits (wall clock, at most timeout_s) until `done` holds, a reset is requested or the node shuts down.
  template <typename Pred>
  bool WaitFor(Pred done, double timeout_s) {
    std::unique_lock<std::mutex> lock(mu_);
    const std::chrono::steady_clock::time_point deadline =
        std::chrono::steady_clock::now() + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                               std::chrono::duration<double>(timeout_s));
    while (!done() && !reset_job_ && ros::ok()) {
      // Wake at least every 100 ms to notice a shutdown.
      const std::chrono::steady_clock::time_point slice =
          std::chrono::steady_clock::now() + std::chrono::milliseconds(100);
      cv_.wait_until(lock, std::min(deadline, slice));
      if (std::chrono::steady_clock::now() >= deadline) return done();
    }
    return true;
  }

  void WaitForCommand(const ros::Time& stamp) {
    const auto answered = [&] { return last_answer_stamp_ == stamp; };
    const double timeout_s = config_.lockstep.timeout_s;
    bool ok;
    if (AnsweredThisEpisode()) {
      ok = WaitFor(answered, timeout_s);
    } else {
      // Start of a run or of an episode whose command source was (re)started: WaitForLockstepPeers counts
      // odometry subscribers, not which node they are, so the command source's own subscription may still be
      // connecting when the episode's first odometry goes out, and ROS drops a message published before a
      // subscriber connects. Until the episode's first command arrives, the unanswered odometry is sent
      // again every kResendPeriodS (same message, same stamp) within the timeout.
      ok = false;
      for (double waited = 0.0; waited < timeout_s && !ok; waited += kResendPeriodS) {
        if (waited > 0.0) {
          odom_pub_.publish(last_odom_);
          ++odometry_resent_;
          ROS_INFO_THROTTLE(
              5.0,
              "quad_sim lockstep: odometry %.3f, the episode's first, not answered yet: sent again "
              "(%lu resent so far)",
              stamp.toSec(), static_cast<unsigned long>(odometry_resent_));
        }
        ok = WaitFor(answered, std::min(kResendPeriodS, timeout_s - waited));
      }
    }
    if (ok) return;
    ++command_timeouts_;
    ROS_WARN("quad_sim lockstep: no command stamped %.3f within %.2f s (command timeouts so far: %lu)",
             stamp.toSec(), timeout_s, static_cast<unsigned long>(command_timeouts_));
  }

  bool AnsweredThisEpisode() {
    std::lock_guard<std::mutex> lock(mu_);
    return !last_answer_stamp_.isZero();  // cleared by every reset
  }

  void WaitForAcks(const ros::Time& stamp) {
    const bool ok = WaitFor(
        [&] {
          for (const std::string& c : config_.lockstep.depth_consumers) {
            auto it = acked_.find(c);
            if (it == acked_.end() || it->second < stamp) return false;
          }
          return true;
        },
        config_.lockstep.timeout_s);
    if (ok) return;
    ++ack_timeouts_;
    std::string missing;
    {
      std::lock_guard<std::mutex> lock(mu_);
      for (const std::string& c : config_.lockstep.depth_consumers) {
        auto it = acked_.find(c);
        if (it == acked_.end() || it->second < stamp) missing += (missing.empty() ? "" : ", ") + c;
      }
    }
    ROS_WARN(
        "quad_sim lockstep: depth frame %.3f not acknowledged by [%s] within %.2f s (ack timeouts so far: "
        "%lu)",
        stamp.toSec(), missing.c_str(), config_.lockstep.timeout_s,
        static_cast<unsigned long>(ack_timeouts_));
  }

  // In lockstep, the first step of an episode waits until the command sources and depth consumers are
  // connected, so that no message of the episode is lost to a connection still being set up: every FrameAck
  // publisher delivers to the simulator and receives frames, a command publisher is connected, and every
  // topic a participant has registered for is connected to it (CheckLockstepPeers says exactly what is waited
  // for and why counting connections was not enough).
  void WaitForLockstepPeers() {
    if (config_.time.mode != quad_sim::TimeMode::kLockstep) return;
    quad_sim::LockstepNeeds needs;
    needs.odom_topic = odom_pub_.getTopic();
    needs.image_topic = depth_pub_.getTopic();
    needs.frame_topics = {depth_pub_.getTopic(), info_pub_.getTopic()};
    needs.num_depth_consumers = static_cast<int>(config_.lockstep.depth_consumers.size());
    needs.wait_for_command = config_.lockstep.wait_for_command;
    if (!needs.wait_for_command && needs.num_depth_consumers == 0) return;
    const auto t0 = std::chrono::steady_clock::now();
    auto next_log = t0 + std::chrono::seconds(5);
    std::set<std::string> delivering;  // confirmed once: a publisher's accepted connection stays
    std::string waited_for;
    while (ros::ok() && !ResetPending()) {
      quad_sim::LockstepPeers peers = GatherPeers(&delivering);
      const quad_sim::LockstepPeerCheck check = quad_sim::CheckLockstepPeers(peers, needs);
      if (check.ready) break;
      if (waited_for.empty()) {
        ROS_INFO("quad_sim lockstep: waiting for the lockstep peers: %s", check.missing.c_str());
      } else if (std::chrono::steady_clock::now() > next_log) {
        ROS_INFO("quad_sim lockstep: still waiting for the lockstep peers: %s", check.missing.c_str());
        next_log += std::chrono::seconds(5);
      }
      waited_for = check.missing;
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    if (!waited_for.empty()) {
      ROS_INFO("quad_sim lockstep: peers connected after %.3f s (last waited for: %s)",
               std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(),
               waited_for.c_str());
    }
  }

  // Who is registered (the master's system state) and who is connected (our publishers' subscriber links;
  // for the FrameAck publishers, their own bus information).
  quad_sim::LockstepPeers GatherPeers(std::set<std::string>* delivering) {
    quad_sim::LockstepPeers peers;
    {
      std::lock_guard<std::mutex> lock(peers_mu_);
      for (const auto& [topic, nodes] : connected_) {
        for (const auto& [node, n] : nodes) {
          if (n > 0) peers.connected_subscribers[topic].insert(node);
        }
      }
    }
    peers.command_publishers_connected =
        static_cast<int>(so3_sub_.getNumPublishers() + trpy_sub_.getNumPublishers());
    XmlRpc::XmlRpcValue req, res, state;
    req[0] = ros::this_node::getName();
    if (!ros::master::execute("getSystemState", req, res, state, false)) return peers;
    const std::string me = ros::this_node::getName();
    const std::set<std::string> tracked = {clock_pub_.getTopic(), odom_pub_.getTopic(),
                                           depth_pub_.getTopic(), info_pub_.getTopic(),
                                           tf_pub_.getTopic(),    tf_static_pub_.getTopic()};
    const std::string ack_topic = ack_sub_.getTopic();
    const std::set<std::string> cmd_topics = {so3_sub_.getTopic(), trpy_sub_.getTopic()};
    auto nodes_of = [](XmlRpc::XmlRpcValue& entry) {
      std::set<std::string> out;
      for (int j = 0; j < entry[1].size(); ++j) out.insert(static_cast<std::string>(entry[1][j]));
      return out;
    };
    XmlRpc::XmlRpcValue& pubs = state[0];
    for (int i = 0; i < pubs.size(); ++i) {
      const std::string topic = pubs[i][0];
      if (topic == ack_topic) {
        for (const std::string& n : nodes_of(pubs[i])) {
          if (n != me) peers.ack_publishers.insert(n);
        }
      } else if (cmd_topics.count(topic) > 0) {
        for (const std::string& n : nodes_of(pubs[i])) peers.command_publishers.insert(n);
      }
    }
    XmlRpc::XmlRpcValue& subs = state[1];
    for (int i = 0; i < subs.size(); ++i) {
      const std::string topic = subs[i][0];
      if (tracked.count(topic) > 0) peers.registered_subscribers[topic] = nodes_of(subs[i]);
    }
    for (const std::string& n : peers.ack_publishers) {
      if (delivering->count(n) == 0 && PublisherDeliversTo(n, ack_topic, me)) delivering->insert(n);
      if (delivering->count(n) > 0) peers.ack_publishers_delivering.insert(n);
    }
    return peers;
  }

  // True if `node`'s own bus information (its getBusInfo XML-RPC call) lists an accepted outgoing connection
  // on `topic` to `subscriber`: only then does a message it publishes reach that subscriber.
  static bool PublisherDeliversTo(const std::string& node, const std::string& topic,
                                  const std::string& subscriber) {
    XmlRpc::XmlRpcValue req, res, payload;
    req[0] = subscriber;
    req[1] = node;
    if (!ros::master::execute("lookupNode", req, res, payload, false)) return false;
    std::string host;
    uint32_t port = 0;
    if (!ros::network::splitURI(static_cast<std::string>(payload), host, port)) return false;
    XmlRpc::XmlRpcClient client(host.c_str(), static_cast<int>(port), "/");
    XmlRpc::XmlRpcValue args, info;
    args[0] = subscriber;
    const bool ok = client.execute("getBusInfo", args, info);
    client.close();
    if (!ok || info.getType() != XmlRpc::XmlRpcValue::TypeArray || info.size() < 3) return false;
    XmlRpc::XmlRpcValue& links = info[2];
    if (links.getType() != XmlRpc::XmlRpcValue::TypeArray) return false;
    for (int i = 0; i < links.size(); ++i) {
      XmlRpc::XmlRpcValue& l = links[i];
      if (l.getType() != XmlRpc::XmlRpcValue::TypeArray || l.size() < 5) continue;
      if (static_cast<std::string>(l[1]) == subscriber && static_cast<std::string>(l[2]) == "o" &&
          static_cast<std::string>(l[4]) == topic) {
        return true;
      }
    }
    return false;
  }

  template <typename M>
  ros::Publisher AdvertiseTracked(const std::string& topic, uint32_t queue_size, bool latch = false) {
    const auto on_connect = [this](const ros::SingleSubscriberPublisher& p) {
      std::lock_guard<std::mutex> lock(peers_mu_);
      ++connected_[p.getTopic()][p.getSubscriberName()];
    };
    const auto on_disconnect = [this](const ros::SingleSubscriberPublisher& p) {
      std::lock_guard<std::mutex> lock(peers_mu_);
      --connected_[p.getTopic()][p.getSubscriberName()];
    };
    return nh_.advertise<M>(topic, queue_size, on_connect, on_disconnect, ros::VoidConstPtr(), latch);
  }

  // ---- time modes ----
  void Anchor() {
    wall_anchor_ = std::chrono::steady_clock::now();
    sim_anchor_s_ = static_cast<double>(total_steps_) * config_.physics_dt_s;
  }

  void Pace() {
    const quad_sim::TimeMode mode = config_.time.mode;
    if (mode != quad_sim::TimeMode::kRealTime && mode != quad_sim::TimeMode::kRealTimeFactor) return;
    const double factor = mode == quad_sim::TimeMode::kRealTime ? 1.0 : config_.time.real_time_factor;
    const double sim_elapsed = static_cast<double>(total_steps_) * config_.physics_dt_s - sim_anchor_s_;
    const auto target = wall_anchor_ + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                           std::chrono::duration<double>(sim_elapsed / factor));
    const auto now = std::chrono::steady_clock::now();
    if (target > now) {
      std::this_thread::sleep_until(target);
    } else if (now - target > std::chrono::seconds(1)) {
      // More than a second behind (e.g. after a slow reset): do not race to catch up, re-anchor instead.
      Anchor();
    }
  }

  // ---- publications ----
  void PublishClock(const ros::Time& now) {
    rosgraph_msgs::Clock c;
    c.clock = now;
    clock_pub_.publish(c);
  }

  void PublishOdometry(const ros::Time& now) {
    const quad_sim::VehicleState& s = sim_.state();
    // set_z_offset: the engine reports positions in its spawn frame; the measured offset maps them to
    // `world`.
    const Eigen::Vector3d p_world = sim_.VehiclePositionInSpawnFrame() / config_.spawn_frame.units_per_m +
                                    Eigen::Vector3d(config_.spawn_frame.origin_world_m.x(),
                                                    config_.spawn_frame.origin_world_m.y(), z_offset_m_);
    nav_msgs::Odometry o;
    o.header.stamp = now;
    o.header.frame_id = "world";
    o.child_frame_id = "base_link";
    o.pose.pose.position = ToPoint(p_world);
    o.pose.pose.orientation = ToQuat(s.q_world_body);
    // Twist in the world frame (docs/CONVENTIONS.md), angular velocity included.
    const Eigen::Vector3d w_world = s.q_world_body * s.w_body;
    o.twist.twist.linear.x = s.v_world.x();
    o.twist.twist.linear.y = s.v_world.y();
    o.twist.twist.linear.z = s.v_world.z();
    o.twist.twist.angular.x = w_world.x();
    o.twist.twist.angular.y = w_world.y();
    o.twist.twist.angular.z = w_world.z();
    odom_pub_.publish(o);
    last_odom_ = o;
    ++odometry_count_;

    geometry_msgs::TransformStamped tf;
    tf.header = o.header;
    tf.child_frame_id = "base_link";
    tf.transform.translation.x = p_world.x();
    tf.transform.translation.y = p_world.y();
    tf.transform.translation.z = p_world.z();
    tf.transform.rotation = o.pose.pose.orientation;
    tf2_msgs::TFMessage m;
    m.transforms.push_back(tf);
    tf_pub_.publish(m);
  }

  void PublishDepth(const ros::Time& now) {
    const quad_sim::DepthImage img = sim_.RenderDepth();
    ++frame_seq_;
    ++depth_frame_count_;
    sensor_msgs::Image m;
    m.header.stamp = now;
    m.header.frame_id = "camera";
    m.header.seq = static_cast<uint32_t>(frame_seq_);
    m.width = img.width;
    m.height = img.height;
    m.encoding = "32FC1";
    m.is_bigendian = 0;
    m.step = img.width * sizeof(float);
    m.data.resize(img.depth_m.size() * sizeof(float));
    std::memcpy(m.data.data(), img.depth_m.data(), m.data.size());
    depth_pub_.publish(m);
    info_pub_.publish(CameraInfo(m.header));
  }

  sensor_msgs::CameraInfo CameraInfo(const std_msgs::Header& header) const {
    const quad_sim::CameraIntrinsics& k = sim_.camera_intrinsics();
    sensor_msgs::CameraInfo c;
    c.header = header;
    c.width = k.width;
    c.height = k.height;
    c.distortion_model = "plumb_bob";
    c.D.assign(5, 0.0);
    c.K = {k.fx, 0, k.cx, 0, k.fy, k.cy, 0, 0, 1};
    c.R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    c.P = {k.fx, 0, k.cx, 0, 0, k.fy, k.cy, 0, 0, 0, 1, 0};
    return c;
  }

  void PublishCameraMount() {
    geometry_msgs::TransformStamped tf;
    tf.header.stamp = Now();
    tf.header.frame_id = "base_link";
    tf.child_frame_id = "camera";
    tf.transform.translation.x = config_.camera.p_body_camera_m.x();
    tf.transform.translation.y = config_.camera.p_body_camera_m.y();
    tf.transform.translation.z = config_.camera.p_body_camera_m.z();
    tf.transform.rotation = ToQuat(config_.camera.q_body_camera);
    tf2_msgs::TFMessage m;  // the simulator's only static transform
    m.transforms.push_back(tf);
    tf_static_pub_.publish(m);
  }

  void PublishStatus(bool force) {
    const quad_sim::EpisodeState& e = sim_.episode();
    const auto key = std::make_tuple(e.episode_id, e.active, e.collision.num_collisions, e.reached_goal,
                                     command_timeouts_ + ack_timeouts_);
    const bool periodic = sim_.step_count() % std::llround(1.0 / config_.physics_dt_s) == 0;
    if (!force && key == last_status_key_ && !periodic) return;
    last_status_key_ = key;
    quad_msgs::EpisodeStatus s;
    s.header.stamp = Now();
    s.header.frame_id = "world";
    s.episode_id = e.episode_id;
    s.world_seed = sim_.world().seed;
    s.sim_time = Now();
    s.collided = e.collision.collided;
    s.collision_box_id =
        e.collision.collided ? e.collision.box_index : quad_msgs::EpisodeStatus::COLLISION_NONE;
    if (e.collision.collided) {
      ros::Time t;
      t.fromNSec(episode_start_stamp_.toNSec() +
                 static_cast<uint64_t>(std::llround(e.collision.time_s * 1e9)));
      s.collision_time = t;
      s.collision_point = ToPoint(e.collision.point_world_m);
    }
    s.reached_goal = e.reached_goal;
    s.active = e.active;
    s.goal = ToPoint(sim_.goal_world());
    s.reason = e.reason;
    if (command_timeouts_ + ack_timeouts_ > 0) {
      s.reason += "; lockstep timeouts: " + std::to_string(command_timeouts_) + " command, " +
                  std::to_string(ack_timeouts_) + " ack";
    }
    status_pub_.publish(s);
    if (e.collision.collided && !collision_logged_) {
      collision_logged_ = true;
      ROS_WARN("quad_sim: %s", e.reason.c_str());
    }
  }

  void PublishStatsIfDue() {
    const auto now = std::chrono::steady_clock::now();
    if (now - stats_wall_ < std::chrono::seconds(1)) return;
    PublishStats();
    stats_wall_ = now;  // the next real-time factor is measured from here
    stats_sim_s_ = static_cast<double>(total_steps_) * config_.physics_dt_s;
  }

  // SimStats stamped now (sim time); the real-time factor since the last periodic one.
  void PublishStats() {
    const auto now = std::chrono::steady_clock::now();
    const double wall = std::max(1e-9, std::chrono::duration<double>(now - stats_wall_).count());
    const double sim_s = static_cast<double>(total_steps_) * config_.physics_dt_s;
    quad_msgs::SimStats m;
    m.header.stamp = Now();
    m.episode_id = sim_.episode().episode_id;
    m.episode_time_s = sim_.time_s();
    m.real_time_factor = (sim_s - stats_sim_s_) / wall;
    m.lockstep_command_timeouts = command_timeouts_;
    m.lockstep_ack_timeouts = ack_timeouts_;
    {
      std::lock_guard<std::mutex> lock(mu_);
      m.rejected_commands = rejected_commands_;
    }
    m.odometry_count = odometry_count_;
    m.depth_frame_count = depth_frame_count_;
    stats_pub_.publish(m);
  }

  void PublishWorld() {
    const quad_sim::World& w = sim_.world();
    visualization_msgs::MarkerArray arr;
    visualization_msgs::Marker clear;
    clear.action = visualization_msgs::Marker::DELETEALL;
    arr.markers.push_back(clear);
    auto base = [&](const std::string& ns, int id, int type) {
      visualization_msgs::Marker m;
      m.header.frame_id = "world";
      m.header.stamp = Now();
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
    goal.pose.position = ToPoint(sim_.goal_world());
    goal.scale.x = goal.scale.y = goal.scale.z = 2.0 * config_.episode.goal_tolerance_m;
    goal.color.g = 0.9;
    goal.color.a = 0.5;
    arr.markers.push_back(goal);
    visualization_msgs::Marker vehicle = base("vehicle", 0, visualization_msgs::Marker::CUBE);
    vehicle.header.frame_id = "base_link";
    vehicle.frame_locked = true;
    vehicle.scale.x = config_.vehicle.collision_box_m.x();
    vehicle.scale.y = config_.vehicle.collision_box_m.y();
    vehicle.scale.z = config_.vehicle.collision_box_m.z();
    vehicle.color.r = 1.0;
    vehicle.color.g = 0.5;
    vehicle.color.a = 0.8;
    arr.markers.push_back(vehicle);
    markers_pub_.publish(arr);

    const quad_sim::VoxelMap map = sim_.ComputeVoxelMap();
    const std::vector<Eigen::Vector3f> pts = map.OccupiedCenters();
    sensor_msgs::PointCloud2 cloud;
    cloud.header.frame_id = "world";
    cloud.header.stamp = Now();
    sensor_msgs::PointCloud2Modifier mod(cloud);
    mod.setPointCloud2FieldsByString(1, "xyz");
    mod.resize(pts.size());
    sensor_msgs::PointCloud2Iterator<float> x(cloud, "x"), y(cloud, "y"), z(cloud, "z");
    for (const Eigen::Vector3f& p : pts) {
      *x = p.x();
      *y = p.y();
      *z = p.z();
      ++x, ++y, ++z;
    }
    voxel_pub_.publish(cloud);
    if (!config_.octomap_file.empty()) {
      try {
        map.WriteOctomap(config_.octomap_file);
      } catch (const std::exception& e) {
        ROS_ERROR("quad_sim: %s", e.what());
      }
    }
    ROS_INFO("quad_sim: world with %zu boxes (seed %lu), voxel map %zu occupied voxels at %.2f m",
             w.boxes.size(), static_cast<unsigned long>(w.seed), map.NumOccupied(), map.resolution_m());
  }

  // set_z_offset (thesis section 3.3): measure the vertical gap between the engine's spawn frame and the ROS
  // world frame from the engine's own ground query, publish it, and use it for every position the node
  // publishes.
  void MeasureZOffset() {
    z_offset_m_ = -sim_.GroundHeightInSpawnFrame() / config_.spawn_frame.units_per_m;
    std_msgs::Float64 m;
    m.data = z_offset_m_;
    z_offset_pub_.publish(m);
    ROS_INFO(
        "quad_sim set_z_offset: spawn frame origin is %.4f m above the world ground (unit scale %.3g per m)",
        z_offset_m_, config_.spawn_frame.units_per_m);
  }

  // ---- episode reset ----
  bool OnReset(quad_msgs::ResetEpisode::Request& req, quad_msgs::ResetEpisode::Response& res) {
    auto job = std::make_shared<ResetJob>();
    job->request = req;
    std::future<quad_msgs::ResetEpisode::Response> fut = job->done.get_future();
    {
      std::lock_guard<std::mutex> lock(mu_);
      if (reset_job_) {
        res.success = false;
        res.message = "another reset is in progress";
        return true;
      }
      reset_job_ = job;
    }
    cv_.notify_all();
    while (ros::ok() && fut.wait_for(std::chrono::milliseconds(100)) != std::future_status::ready) {
    }
    if (!ros::ok()) return false;
    res = fut.get();
    return true;
  }

  bool ResetPending() {
    std::lock_guard<std::mutex> lock(mu_);
    return reset_job_ != nullptr;
  }

  // Runs a pending reset in the simulation thread; true if one ran.
  bool HandleResetJob() {
    std::shared_ptr<ResetJob> job;
    {
      std::lock_guard<std::mutex> lock(mu_);
      job = reset_job_;
    }
    if (!job) return false;
    quad_msgs::ResetEpisode::Response res = DoReset(job->request);
    {
      std::lock_guard<std::mutex> lock(mu_);
      reset_job_.reset();
    }
    job->done.set_value(res);
    if (res.success) {
      WaitForLockstepPeers();
      Anchor();
    }
    return true;
  }

  quad_msgs::ResetEpisode::Response DoReset(const quad_msgs::ResetEpisode::Request& req) {
    quad_msgs::ResetEpisode::Response res;
    try {
      // A zero start orientation (the message default) selects the configured start pose and goal.
      const auto& o = req.start.orientation;
      const bool default_pose = o.x == 0.0 && o.y == 0.0 && o.z == 0.0 && o.w == 0.0;
      Eigen::Vector3d start = config_.start_m;
      double yaw = config_.start_yaw_rad;
      Eigen::Vector3d goal = config_.goal_m;
      if (!default_pose) {
        const Eigen::Quaterniond q(o.w, o.x, o.y, o.z);
        if (!q.coeffs().allFinite()) throw std::invalid_argument("start orientation is not finite");
        start = Eigen::Vector3d(req.start.position.x, req.start.position.y, req.start.position.z);
        yaw = quad_sim::YawOf(q.normalized());
        goal = Eigen::Vector3d(req.goal.x, req.goal.y, req.goal.z);
      }
      quad_sim::World world;
      if (!req.world_file.empty()) {
        world = quad_sim::LoadWorld(req.world_file);
      } else if (!config_.world_file.empty() && req.seed == 0) {
        world = quad_sim::LoadWorld(config_.world_file);
      } else {
        quad_sim::WorldGenConfig gen = config_.world_gen;
        gen.clear_zones.resize(gen.clear_zones.size() - 2);  // drop the configured start/goal zones ...
        gen.AddClearZone(start);  // ... and keep this episode's start and goal clear
        gen.AddClearZone(goal);
        world = quad_sim::GenerateWorld(gen, req.seed != 0 ? req.seed : config_.world_seed);
      }
      sim_.Reset(world, start, yaw, goal);
    } catch (const std::exception& e) {
      res.success = false;
      res.message = std::string("reset rejected: ") + e.what();
      ROS_ERROR("quad_sim: %s", res.message.c_str());
      return res;
    }
    // Stamps of the new episode start one control period after the last one, so they never repeat.
    total_steps_ += steps_per_odom_;
    {
      std::lock_guard<std::mutex> lock(mu_);
      episode_start_stamp_ = Now();
      pending_ = PendingCommand();
      last_answer_stamp_ = ros::Time();
      acked_.clear();
    }
    odometry_count_ = 0;
    depth_frame_count_ = 0;
    collision_logged_ = false;
    PublishWorld();
    PublishStatus(true);
    PublishStats();  // the counts at the episode's start (SimStats counts are for the whole run)
    res.success = true;
    res.episode_id = sim_.episode().episode_id;
    res.message = "episode " + std::to_string(res.episode_id) + " started with " +
                  std::to_string(sim_.world().boxes.size()) + " boxes";
    ROS_INFO("quad_sim: %s", res.message.c_str());
    return res;
  }

  ros::NodeHandle nh_;
  quad_sim::SimConfig config_;
  quad_sim::Simulator sim_;
  const uint64_t dt_ns_;
  const uint64_t steps_per_odom_;
  const uint64_t steps_per_clock_;
  uint64_t total_steps_ = 0;
  uint64_t frame_seq_ = 0;
  double z_offset_m_ = 0.0;

  ros::Publisher clock_pub_, odom_pub_, depth_pub_, info_pub_, status_pub_, markers_pub_, voxel_pub_,
      z_offset_pub_, stats_pub_;
  ros::Subscriber so3_sub_, trpy_sub_, ack_sub_;
  ros::ServiceServer reset_srv_;
  ros::Publisher tf_pub_, tf_static_pub_;

  // Connected subscribers of the tracked publishers: topic -> node -> number of links (peers_mu_).
  std::mutex peers_mu_;
  std::map<std::string, std::map<std::string, int>> connected_;

  // Shared with the subscriber/service threads (guarded by mu_).
  std::mutex mu_;
  std::condition_variable cv_;
  PendingCommand pending_;
  ros::Time last_answer_stamp_;
  ros::Time episode_start_stamp_;
  std::map<std::string, ros::Time> acked_;
  std::shared_ptr<ResetJob> reset_job_;
  uint64_t rejected_commands_ = 0;

  // Simulation thread only.
  uint64_t command_timeouts_ = 0;
  uint64_t ack_timeouts_ = 0;
  uint64_t odometry_count_ = 0;
  uint64_t odometry_resent_ = 0;  // resends of episodes' first odometry (WaitForCommand)
  nav_msgs::Odometry last_odom_;  // the last odometry published
  uint64_t depth_frame_count_ = 0;
  bool collision_logged_ = false;
  std::tuple<uint32_t, bool, int, bool, uint64_t> last_status_key_{0, false, -1, false, 0};
  std::chrono::steady_clock::time_point wall_anchor_;
  double sim_anchor_s_ = 0.0;
  std::chrono::steady_clock::time_point stats_wall_ = std::chrono::steady_clock::now();
  double stats_sim_s_ = 0.0;
};

}  // namespace

int main(int argc, char** argv) {
  ros::init(argc, argv, "quad_sim");
  ros::NodeHandle nh;
  ros::NodeHandle pnh("~");
  std::string config_path;
  if (!pnh.getParam("config", config_path) || config_path.empty()) {
    ROS_FATAL("quad_sim: the private parameter ~config (path of sim.yaml) is required");
    return 1;
  }
  int world_seed = -1;
  pnh.param("world_seed", world_seed, -1);
  std::unique_ptr<QuadSimNode> node;
  try {
    const quad_sim::SimConfig config = quad_sim::LoadSimConfig(config_path);
    const uint64_t seed = world_seed >= 0 ? static_cast<uint64_t>(world_seed) : config.world_seed;
    ROS_INFO("quad_sim: config %s, time mode %s, world seed %lu", config_path.c_str(),
             quad_sim::ToString(config.time.mode), static_cast<unsigned long>(seed));
    node = std::make_unique<QuadSimNode>(nh, config, seed);
  } catch (const std::exception& e) {
    ROS_FATAL("quad_sim: %s", e.what());
    return 1;
  }
  ros::AsyncSpinner spinner(2);
  spinner.start();
  std::thread loop([&node] { node->Run(); });
  ros::waitForShutdown();
  loop.join();
  return 0;
}
