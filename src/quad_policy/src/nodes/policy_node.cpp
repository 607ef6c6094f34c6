// policy_node: the learned policy in the loop, C++ (LibTorch). A thin adapter around
// quad_policy::PolicyDecider: parameters, message conversion, the tracker action, lockstep acknowledgements.
// docs/inference.md.
//
// Per depth frame: pair it with the latest odometry not newer than the frame, decide (preprocessing, network,
// world-frame B-spline started at the frame's stamp, safety layer), publish the trajectory to fly on
// planner/bspline and send it to tracker/track_bspline (a refused plan sends the stopping trajectory or
// switches the tracker to hover), publish policy/decision, wait until the tracker has taken the trajectory
// (bounded by ~tracker_accept_timeout_s: in lockstep it then takes effect at the same step in every run),
// then acknowledge the frame. Goals are answered on policy/status.
#include <actionlib/client/action_client.h>
#include <geometry_msgs/PoseStamped.h>
#include <nav_msgs/Odometry.h>
#include <quad_msgs/Bspline.h>
#include <quad_msgs/EpisodeStatus.h>
#include <quad_msgs/FrameAck.h>
#include <quad_msgs/PolicyDecision.h>
#include <quad_msgs/SwitchTracker.h>
#include <quad_msgs/TrackBsplineAction.h>
#include <ros/callback_queue.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <std_msgs/String.h>
#include <tf2_ros/transform_listener.h>

#include <quad_common/strict_yaml.h>
#include <quad_common/wait_connected.h>
#include <quad_policy/abi.h>
#include <quad_policy/config.h>
#include <quad_policy/input_checks.h>
#include <quad_policy/policy_decider.h>
#include <quad_policy/torch_policy.h>

#include "../ros/bspline_message.h"

#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>

namespace {

using TrackClient = actionlib::ActionClient<quad_msgs::TrackBsplineAction>;

double MsSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

struct OdomSample {
  double stamp_s;
  quad_policy::VehicleState state;
};

class PolicyNode {
 public:
  PolicyNode() : nh_(), pnh_("~"), tf_listener_(tf_buffer_) {
    quad_policy::CheckLibraryLayout();  // before any call that passes the library's types
    std::string config_path;
    if (!pnh_.getParam("config", config_path))
      throw std::runtime_error("private parameter ~config is required");
    cfg_ = quad_policy::LoadPolicyNodeConfig(config_path);
    std::string policy_file;
    if (pnh_.getParam("policy_file", policy_file) && !policy_file.empty()) cfg_.policy_file = policy_file;
    int threads = 0;
    if (pnh_.getParam("num_threads", threads) && threads > 0) cfg_.num_threads = threads;
    bool send = true;
    if (pnh_.getParam("send_to_tracker", send)) cfg_.send_to_tracker = send;
    tracker_accept_timeout_s_ = pnh_.param<double>("tracker_accept_timeout_s", 1.0);
    odom_period_s_ = pnh_.param<double>("odom_period_s", 0.005);
    odom_wait_s_ = pnh_.param<double>("odom_wait_s", 0.2);
    if (!(std::isfinite(odom_wait_s_) && odom_wait_s_ > 0.0))
      throw std::runtime_error("~odom_wait_s must be a finite number > 0, got " +
                               std::to_string(odom_wait_s_));
    if (cfg_.policy_file.empty())
      throw std::runtime_error("no policy file: set policy_file in the config or ~policy_file");

    quad_policy::TuneMallocForInference();
    quad_policy::ConfigureTorchThreads(cfg_.num_threads);
    auto policy = std::make_shared<const quad_policy::TorchPolicy>(cfg_.policy_file);
    decider_ = std::make_unique<quad_policy::PolicyDecider>(policy, cfg_.safety, cfg_.refusal, cfg_.recovery,
                                                            cfg_.keeping);
    const quad_policy::PolicyMeta& m = policy->meta();
    ROS_INFO(
        "policy_node: %s (input %dx%d, state %s, output %s %s, K = %d over %.2f s, network entry %s), "
        "%d thread(s), refusal action %s, %zu recovery goal turn(s), steering clearance %.2f m, final "
        "approach %.2f m",
        cfg_.policy_file.c_str(), m.input_width, m.input_height, ToString(m.state_frame),
        ToString(m.output_frame), ToString(m.representation), m.num_ctrl_pts, m.horizon_s,
        policy->has_forward_net() ? "forward_net" : "forward_prepared", quad_policy::TorchThreads(),
        ToString(cfg_.refusal.action), cfg_.recovery.goal_yaw_offsets_deg.size(),
        cfg_.recovery.steer_clearance_m, cfg_.recovery.final_approach_m);
    try {
      WarmUp(*policy);
    } catch (const std::exception& e) {
      // A file whose methods exist but do not take a policy's inputs (issue 30): name the file.
      throw std::runtime_error(cfg_.policy_file +
                               ": the policy's forward pass fails on a test input: " + e.what());
    }

    const ros::TransportHints hints = ros::TransportHints().tcpNoDelay();
    odom_sub_ = nh_.subscribe("odom", 50, &PolicyNode::OnOdom, this, hints);
    goal_sub_ = nh_.subscribe("planner/goal", 10, &PolicyNode::OnGoal, this, hints);
    info_sub_ = nh_.subscribe("camera/depth/camera_info", 2, &PolicyNode::OnCameraInfo, this, hints);
    status_sub_ = nh_.subscribe("sim/status", 10, &PolicyNode::OnStatus, this, hints);
    // 100 like the decisions: a recorder that falls behind (3 s at 30 Hz) still gets every trajectory.
    bspline_pub_ = nh_.advertise<quad_msgs::Bspline>("planner/bspline", 100);
    proposal_pub_ = nh_.advertise<quad_msgs::Bspline>("policy/proposal", 100);
    decision_pub_ = nh_.advertise<quad_msgs::PolicyDecision>("policy/decision", 100);
    ack_pub_ = nh_.advertise<quad_msgs::FrameAck>("sim/frame_ack", 100);
    status_pub_ = nh_.advertise<std_msgs::String>("policy/status", 10, true);
    switch_client_ = nh_.serviceClient<quad_msgs::SwitchTracker>("tracker/switch");

    // Subscribe to frames once the simulator can hear this node's acknowledgements (up to 5 s: a simulator
    // that is not lockstepped may never connect).
    quad_common::WaitForSubscriber(ack_pub_, 5.0);
    // Depth frames are decided on their own thread so odometry and goals keep arriving meanwhile.
    ros::SubscribeOptions ops = ros::SubscribeOptions::create<sensor_msgs::Image>(
        "camera/depth/image", 2, [this](const sensor_msgs::Image::ConstPtr& msg) { OnDepth(msg); },
        ros::VoidPtr(), &depth_queue_);
    ops.transport_hints = hints;
    depth_sub_ = nh_.subscribe(ops);
    depth_thread_ = std::thread([this] {
      while (nh_.ok()) depth_queue_.callAvailable(ros::WallDuration(0.05));
    });
  }

  ~PolicyNode() {
    if (depth_thread_.joinable()) depth_thread_.join();
  }

 private:
  // The first forward passes of a TorchScript module are slower (profiling executor): run them before flying.
  void WarmUp(const quad_policy::TorchPolicy& policy) {
    const quad_policy::PolicyMeta& m = policy.meta();
    const std::vector<float> depth_x(static_cast<std::size_t>(m.input_height) * m.input_width, 0.5f);
    quad_policy::StateVector s{};
    s[9] = 1.0f;
    for (int i = 0; i < 3; ++i) policy.Run(depth_x, s, quad_policy::VehicleState(), Eigen::Vector3d::Zero());
  }

  void OnOdom(const nav_msgs::Odometry::ConstPtr& msg) {
    OdomSample o;
    o.stamp_s = msg->header.stamp.toSec();
    const auto& p = msg->pose.pose.position;
    const auto& q = msg->pose.pose.orientation;
    const auto& v = msg->twist.twist.linear;
    o.state.p_world_body = Eigen::Vector3d(p.x, p.y, p.z);
    o.state.q_world_body = Eigen::Quaterniond(q.w, q.x, q.y, q.z);
    o.state.v_world = Eigen::Vector3d(v.x, v.y, v.z);  // twist in the world frame (docs/CONVENTIONS.md)
    {
      std::lock_guard<std::mutex> lock(mu_);
      odom_.push_back(o);
      while (odom_.size() > 400) odom_.pop_front();
    }
    odom_cv_.notify_all();
  }

  void OnGoal(const geometry_msgs::PoseStamped::ConstPtr& msg) {
    const auto& p = msg->pose.position;
    const Eigen::Vector3d g(p.x, p.y, p.z);
    std_msgs::String answer;
    if (!g.allFinite()) {
      ROS_WARN("policy_node: goal with NaN/Inf ignored");
      answer.data = "goal rejected: not finite";
      status_pub_.publish(answer);
      return;
    }
    {
      std::lock_guard<std::mutex> lock(mu_);
      goal_ = g;
    }
    ROS_INFO("policy_node: goal (%.2f, %.2f, %.2f)", g.x(), g.y(), g.z());
    // After the goal is stored: an episode runner in lockstep releases the frame once it reads this.
    char text[96];
    std::snprintf(text, sizeof(text), "goal accepted: (%.2f, %.2f, %.2f)", g.x(), g.y(), g.z());
    answer.data = text;
    status_pub_.publish(answer);
  }

  void OnCameraInfo(const sensor_msgs::CameraInfo::ConstPtr& msg) {
    std::lock_guard<std::mutex> lock(mu_);
    camera_info_ = *msg;
  }

  void OnStatus(const quad_msgs::EpisodeStatus::ConstPtr& msg) {
    std::lock_guard<std::mutex> lock(mu_);
    if (episode_id_ && *episode_id_ != msg->episode_id) {
      // A new episode: the goal, the odometry and the plan state belong to the previous one.
      goal_.reset();
      odom_.clear();
      last_decision_stamp_.reset();
      hovering_ = false;
      reset_decider_ = true;
      ROS_INFO("policy_node: episode %u started: waiting for its goal", msg->episode_id);
    }
    episode_id_ = msg->episode_id;
  }

  void Count(const std::string& name) { ++counts_[name]; }

  bool HasGoal() {
    std::lock_guard<std::mutex> lock(mu_);
    return goal_.has_value();
  }

  void OnDepth(const sensor_msgs::Image::ConstPtr& msg) {
    // actionlib's ActionClient waits for a valid ROS time when it is built; under use_sim_time a lockstepped
    // simulator publishes /clock only once this node's depth subscription is up, so the client is built here,
    // on the first frame. The goal of an episode comes seconds later, but in lockstep those seconds can pass
    // in a fraction of a wall second: until the connection is confirmed, frames without a goal wait for it
    // (up to 50 ms each, 5 s in all, in case there is no tracker), so the first trajectory is not lost to a
    // connection still being set up. The confirmation needs the server's periodic status, i.e. sim time
    // passing: hence a short wait per frame rather than one long one.
    if (cfg_.send_to_tracker && !track_client_) {
      track_client_ = std::make_unique<TrackClient>(nh_, "tracker/track_bspline");
    }
    if (track_client_ && connect_wait_left_s_ > 0.0 && !track_client_->isServerConnected() && !HasGoal()) {
      const auto t0 = std::chrono::steady_clock::now();
      while (!track_client_->isServerConnected() && MsSince(t0) < 50.0 && ros::ok()) {
        std::this_thread::sleep_for(std::chrono::milliseconds(2));
      }
      connect_wait_left_s_ -= MsSince(t0) / 1000.0;
    }
    quad_msgs::PolicyDecision out;
    out.header = msg->header;
    out.node = "cpp";
    out.frame_seq = msg->header.seq;
    out.action = "none";
    Handle(*msg, &out);
    for (const auto& [name, n] : counts_) {
      out.count_names.push_back(name);
      out.count_values.push_back(n);
    }
    {
      std::lock_guard<std::mutex> lock(action_mu_);
      out.tracker_rejections = tracker_rejections_;
      out.last_tracker_rejection = last_rejection_;
    }
    decision_pub_.publish(out);
    WaitTrackerAccept();
    // Lockstep: acknowledge after deciding (and sending), whatever the outcome.
    quad_msgs::FrameAck ack;
    ack.consumer = cfg_.lockstep_consumer;
    ack.frame_seq = msg->header.seq;
    ack.stamp = msg->header.stamp;
    ack_pub_.publish(ack);
  }

  void Skip(const std::string& status, const std::string& reason, quad_msgs::PolicyDecision* out) {
    out->status = status;
    out->reason = reason;
    Count(status);
  }

  void Refuse(const std::string& reason, quad_msgs::PolicyDecision* out) {
    ROS_WARN_THROTTLE(2.0, "policy_node: frame refused: %s", reason.c_str());
    Skip("bad_input", reason, out);
  }

  void Handle(const sensor_msgs::Image& img, quad_msgs::PolicyDecision* out) {
    const double stamp = img.header.stamp.toSec();
    const std::string layout = quad_policy::DepthLayoutProblem(
        {img.encoding, img.is_bigendian != 0, img.width, img.height, img.step, img.data.size()});
    if (!layout.empty()) return Refuse(layout, out);
    std::optional<Eigen::Vector3d> goal;
    std::optional<OdomSample> odom;
    std::optional<sensor_msgs::CameraInfo> info;
    std::optional<ros::Time> last_decision;
    bool reset_decider = false;
    {
      // The frame's own odometry (its control period's, published before the frame) travels on another
      // topic: wait for it (at most ~odom_wait_s of wall time), so that which odometry a decision starts
      // from does not depend on message timing. Without it, the newest older one is used.
      std::unique_lock<std::mutex> lock(mu_);
      odom_cv_.wait_for(lock, std::chrono::duration<double>(odom_wait_s_), [&] {
        return !odom_.empty() && odom_.back().stamp_s > stamp - odom_period_s_ + 1e-6;
      });
      goal = goal_;
      last_decision = last_decision_stamp_;
      std::swap(reset_decider, reset_decider_);
      for (auto it = odom_.rbegin(); it != odom_.rend(); ++it) {
        if (it->stamp_s <= stamp + 1e-9) {
          odom = *it;
          break;
        }
      }
      info = camera_info_;
    }
    if (reset_decider) decider_->Reset();  // a new episode: no stops in a row, no remembered depth frames
    if (!goal) return Skip("no_goal", "no goal for this episode yet", out);
    if (!odom) return Skip("no_odometry", "no odometry at or before the frame", out);
    if (!info) return Skip("no_camera_info", "no camera info yet", out);
    // Bad input is refused before anything is computed from it: no trajectory is sent for this frame, so the
    // tracker flies on along the plan it has (or holds) (docs/CONVENTIONS.md, fault table).
    const std::string size = quad_policy::DepthSizeProblem(img.width, img.height, info->width, info->height);
    if (!size.empty()) return Refuse(size, out);
    const std::string state = quad_policy::StateProblem(odom->state, odom->stamp_s);
    if (!state.empty()) return Refuse(state, out);
    if (stamp - odom->stamp_s > cfg_.max_odom_age_s) {
      return Skip("stale_odometry", "latest odometry is " + std::to_string(stamp - odom->stamp_s) + " s old",
                  out);
    }
    if ((odom->state.p_world_body - *goal).norm() < cfg_.goal_tolerance_m) {
      return Skip("goal_reached", "within goal_tolerance_m of the goal", out);
    }
    // In integer nanoseconds (as the Python node), so that both nodes decide on exactly the same frames.
    if (cfg_.replan_rate_hz > 0.0 && last_decision &&
        (img.header.stamp - *last_decision).toNSec() < std::llround(1e9 / cfg_.replan_rate_hz)) {
      return Skip("rate_limited", "replan_rate_hz", out);
    }
    if (!T_body_camera_) {
      try {
        // No waiting: a lockstepped simulator holds ROS time while this frame is open (the static transform
        // is normally in long before the first frame; without it the frame is skipped and the next one
        // retries).
        const geometry_msgs::TransformStamped t =
            tf_buffer_.lookupTransform("base_link", img.header.frame_id, ros::Time(0));
        const auto& tr = t.transform.translation;
        const auto& rq = t.transform.rotation;
        Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
        T.linear() = Eigen::Quaterniond(rq.w, rq.x, rq.y, rq.z).normalized().toRotationMatrix();
        T.translation() = Eigen::Vector3d(tr.x, tr.y, tr.z);
        T_body_camera_ = T;
      } catch (const tf2::TransformException& e) {
        ROS_WARN_THROTTLE(5.0, "policy_node: no transform base_link -> %s yet: %s",
                          img.header.frame_id.c_str(), e.what());
        return Skip("no_camera_pose", e.what(), out);
      }
    }
    quad_policy::DecisionInputs in;
    in.stamp_s = stamp;
    in.depth = quad_policy::DepthImageView{static_cast<int>(img.width), static_cast<int>(img.height),
                                           img.step / 4, reinterpret_cast<const float*>(img.data.data())};
    in.camera.width = static_cast<int>(info->width);
    in.camera.height = static_cast<int>(info->height);
    in.camera.fx = info->K[0];
    in.camera.fy = info->K[4];
    in.camera.cx = info->K[2];
    in.camera.cy = info->K[5];
    Eigen::Isometry3d T_world_body = Eigen::Isometry3d::Identity();
    T_world_body.linear() = odom->state.q_world_body.normalized().toRotationMatrix();
    T_world_body.translation() = odom->state.p_world_body;
    in.camera.T_world_camera = T_world_body * *T_body_camera_;
    in.state = odom->state;
    in.goal_world = *goal;

    quad_policy::Decision d;
    try {
      d = decider_->Decide(in);
    } catch (const std::exception& e) {
      ROS_WARN_THROTTLE(5.0, "policy_node: no decision: %s", e.what());
      return Skip("bad_input", e.what(), out);
    }
    bool hovering;
    {
      std::lock_guard<std::mutex> lock(mu_);
      last_decision_stamp_ = img.header.stamp;
      hovering = hovering_;
    }
    const auto t0 = std::chrono::steady_clock::now();
    const quad_policy::UniformBspline* send = d.to_send();
    quad_msgs::Bspline msg;
    if (send != nullptr) msg = quad_policy::ToBsplineMessage(*send, ++traj_id_, img.header.stamp);
    out->message_ms = d.timings.decode_ms + MsSince(t0);
    out->status = "decided";
    out->verdict = ToString(d.safety.verdict);
    out->accepted = d.accepted();
    out->reason = d.safety.reason;
    out->preprocess_ms = d.timings.preprocess_ms;
    out->forward_ms = d.timings.forward_ms;
    out->decision_ms = out->preprocess_ms + out->forward_ms + out->message_ms;
    out->safety_ms = d.timings.safety_ms;
    Count(out->verdict);
    proposal_pub_.publish(
        quad_policy::ToBsplineMessage(d.proposed, d.accepted() ? traj_id_ : 0, img.header.stamp));
    if (!d.accepted()) {
      ROS_WARN_THROTTLE(2.0, "policy_node: plan refused: %s", d.safety.reason.c_str());
    }
    if (d.recovery) {
      Count(d.steered ? "steered" : "recovered");
      out->reason += quad_policy::RecoveryText(d, decider_->policy().meta().hypotheses);
    }
    if (d.final_approach) {
      Count("final_approach");
      out->reason += "; final approach: straight to the goal (not the network's plan)";
    }
    if (d.kept) {
      Count(d.committed ? "committed" : "kept");
      char kept[112];
      std::snprintf(kept, sizeof(kept), "; %s the plan sent %.2f s before (its rest is clear)",
                    d.committed ? "committed to" : "kept", in.stamp_s - d.kept->start_time_s);
      out->reason += kept;
    }
    if (d.turn_rate_radps != 0.0) {
      Count("turning");
      char turn[96];
      std::snprintf(turn, sizeof(turn), "; turning in place at %.0f deg/s, backing off %.2f m",
                    d.turn_rate_radps * 180.0 / M_PI, d.turn_backoff_m);
      out->reason += turn;
    }
    if (send != nullptr) {
      out->action = d.final_approach           ? "final_approach"
                    : d.recovery               ? (d.steered ? "steer" : "recovery")
                    : d.accepted()             ? "policy"
                    : d.turn_rate_radps != 0.0 ? "turn"
                                               : "stop";
      out->traj_id = msg.traj_id;
      bspline_pub_.publish(msg);
      SendToTracker(msg);
      SetHovering(false);
    } else if (d.kept) {
      out->action = "keep";  // the tracker flies on along the plan sent before
    } else {
      out->action = "hover";
      if (!hovering) SetHovering(SwitchToHover());
    }
  }

  void SendToTracker(const quad_msgs::Bspline& msg) {
    if (!track_client_) return;
    if (!track_client_->isServerConnected()) {
      // Sent anyway: right after start-up the goal topic is often connected before the server's status has
      // confirmed the connection, and the goal then arrives. Counted as an event.
      ROS_WARN_THROTTLE(5.0, "policy_node: tracker action tracker/track_bspline not confirmed connected");
      Count("tracker_not_connected");
    }
    quad_msgs::TrackBsplineGoal goal;
    goal.bspline = msg;
    TrackClient::GoalHandle gh =
        track_client_->sendGoal(goal, [this](TrackClient::GoalHandle h) { OnTransition(h); });
    // Waited for even when the connection is not confirmed yet: actionlib confirms it only once the server's
    // status has arrived, which can be after the first goals, and those must take effect at the same step in
    // every run too. Only after a wait timed out without a confirmed connection (no tracker at all), the next
    // goals are not waited for until the connection is confirmed.
    const bool connected = track_client_->isServerConnected();
    if (connected) no_tracker_ = false;
    if (connected || !no_tracker_) {
      sent_ = gh;
      sent_traj_id_ = msg.traj_id;
    }
    std::lock_guard<std::mutex> lock(action_mu_);
    // The handles keep the goals tracked until their results arrive; older goals are long decided.
    handles_.push_back(gh);
    while (handles_.size() > 64) handles_.pop_front();
  }

  // Waits (wall time, at most tracker_accept_timeout_s) until the tracker has answered this frame's
  // trajectory. In lockstep the simulator steps on once the frame is acknowledged; the tracker applies a
  // trajectory from the first odometry after it took it, so without this wait the step it starts at would
  // depend on message timing. The comm state is read without holding accept_mu_ (actionlib holds its own
  // lock while it calls OnTransition, which takes accept_mu_).
  void WaitTrackerAccept() {
    if (!sent_) return;
    const TrackClient::GoalHandle gh = *sent_;
    sent_.reset();
    const auto deadline =
        std::chrono::steady_clock::now() + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                               std::chrono::duration<double>(tracker_accept_timeout_s_));
    while (gh.getCommState() == actionlib::CommState::WAITING_FOR_GOAL_ACK) {
      if (!ros::ok()) return;
      if (std::chrono::steady_clock::now() >= deadline) {
        if (!track_client_->isServerConnected()) no_tracker_ = true;
        ++tracker_accept_timeouts_;
        Count("tracker_accept_timeout");
        ROS_WARN("policy_node: the tracker did not take trajectory %ld within %.2f s (%lu times so far)",
                 static_cast<long>(sent_traj_id_), tracker_accept_timeout_s_,
                 static_cast<unsigned long>(tracker_accept_timeouts_));
        return;
      }
      // Woken by any transition; the short timeout covers a wake-up missed.
      std::unique_lock<std::mutex> lock(accept_mu_);
      accept_cv_.wait_for(lock, std::chrono::milliseconds(2));
    }
  }

  void SetHovering(bool hovering) {
    std::lock_guard<std::mutex> lock(mu_);
    hovering_ = hovering;
  }

  // Transition callbacks run on the main spinner thread.
  void OnTransition(TrackClient::GoalHandle gh) {
    { std::lock_guard<std::mutex> lock(accept_mu_); }
    accept_cv_.notify_all();
    if (gh.getCommState() != actionlib::CommState::DONE) return;
    if (gh.getTerminalState() == actionlib::TerminalState::REJECTED) {
      std::lock_guard<std::mutex> lock(action_mu_);
      ++tracker_rejections_;
      const auto result = gh.getResult();
      last_rejection_ = result ? result->reason : gh.getTerminalState().getText();
      ROS_WARN_THROTTLE(2.0, "policy_node: tracker rejected a trajectory: %s", last_rejection_.c_str());
    }
  }

  bool SwitchToHover() {
    quad_msgs::SwitchTracker srv;
    srv.request.tracker = "hover";
    if (switch_client_.call(srv) && srv.response.success) return true;
    ROS_WARN_THROTTLE(5.0, "policy_node: could not switch the tracker to hover: %s",
                      srv.response.message.c_str());
    Count("hover_failed");
    return false;
  }

  ros::NodeHandle nh_;
  ros::NodeHandle pnh_;
  tf2_ros::Buffer tf_buffer_;
  tf2_ros::TransformListener tf_listener_;
  quad_policy::PolicyNodeConfig cfg_;
  std::unique_ptr<quad_policy::PolicyDecider> decider_;

  ros::Subscriber odom_sub_, goal_sub_, info_sub_, status_sub_, depth_sub_;
  ros::Publisher bspline_pub_, proposal_pub_, decision_pub_, ack_pub_, status_pub_;
  ros::ServiceClient switch_client_;
  std::unique_ptr<TrackClient> track_client_;  // built and used on the depth thread
  ros::CallbackQueue depth_queue_;
  std::thread depth_thread_;

  std::mutex mu_;  // guards the inputs below (written by the main spinner, read by the depth thread)
  std::condition_variable odom_cv_;  // an odometry message arrived
  double odom_period_s_ = 0.005;
  double odom_wait_s_ = 0.2;  // wall-time bound on waiting for a frame's own odometry
  std::deque<OdomSample> odom_;
  std::optional<Eigen::Vector3d> goal_;
  std::optional<sensor_msgs::CameraInfo> camera_info_;
  std::optional<uint32_t> episode_id_;
  std::optional<ros::Time> last_decision_stamp_;
  bool hovering_ = false;  // the tracker was switched to hover by a refusal (cleared by the next trajectory)
  bool reset_decider_ = false;  // a new episode began: the depth thread resets the decider before deciding

  // depth thread only
  std::optional<Eigen::Isometry3d> T_body_camera_;
  std::map<std::string, uint64_t> counts_;
  int64_t traj_id_ = 0;
  std::optional<TrackClient::GoalHandle> sent_;  // this frame's trajectory, until the tracker answers
  int64_t sent_traj_id_ = 0;
  double tracker_accept_timeout_s_ = 1.0;
  uint64_t tracker_accept_timeouts_ = 0;
  bool no_tracker_ = false;           // a wait timed out without a confirmed connection
  double connect_wait_left_s_ = 5.0;  // wall time left to wait for the tracker's connection at start-up
  std::mutex accept_mu_;
  std::condition_variable accept_cv_;

  std::mutex action_mu_;
  std::deque<TrackClient::GoalHandle> handles_;
  uint64_t tracker_rejections_ = 0;
  std::string last_rejection_;
};

}  // namespace

int main(int argc, char** argv) {
  ros::init(argc, argv, "policy_node");
  try {
    PolicyNode node;
    ros::spin();
  } catch (const std::exception& e) {
    ROS_FATAL("policy_node: %s", e.what());
    // Debian's rosconsole prints nothing to the console without a config file: the reason the node stops
    // (a bad policy file, config or parameter) also goes to stderr, so whoever started it sees it.
    std::fprintf(stderr, "[FATAL] policy_node: %s\n", e.what());
    return 1;
  }
  return 0;
}
