// policy_node: the learned policy in the loop, C++ (LibTorch), a thin adapter around PolicyDecider (messages:
// ../ros/messages.h, the tracker action: ../ros/tracker_link.h). docs/inference.md.
//
// Per depth frame: pair it with the newest odometry not newer than the frame (quad_core/pairing.h), decide,
// publish the trajectory to fly on planner/bspline (and as a marker on policy/plan_marker) and send it to
// tracker/track_bspline (a refusal sends the stopping trajectory or switches the tracker to hover), publish
// policy/decision, wait until the tracker has taken the trajectory (bounded by tracker_accept_timeout_s: in
// lockstep it then takes effect at the same step in every run), then acknowledge the frame. Goals are
// answered on policy/status. Every parameter comes from the policy config (~config, required); ~policy_file,
// ~num_threads (> 0) and ~send_to_tracker override its keys when set (the launch file's arguments).
#include <geometry_msgs/PoseStamped.h>
#include <quad_msgs/EpisodeStatus.h>
#include <quad_msgs/FrameAck.h>
#include <quad_msgs/PolicyDecision.h>
#include <quad_msgs/SwitchTracker.h>
#include <ros/callback_queue.h>
#include <ros/ros.h>
#include <std_msgs/String.h>
#include <tf2_ros/transform_listener.h>

#include <quad_core/pairing.h>
#include <quad_core/wait_connected.h>
#include <quad_policy/abi.h>
#include <quad_policy/config.h>
#include <quad_policy/input_checks.h>
#include <quad_policy/policy_decider.h>
#include <quad_policy/torch_policy.h>

#include "../ros/messages.h"
#include "../ros/tracker_link.h"

#include <atomic>
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
#include <tuple>

namespace {

double MsSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

quad_policy::PolicyNodeConfig LoadConfig(const ros::NodeHandle& pnh) {
  quad_policy::CheckLibraryLayout();  // before any call that passes the library's types
  std::string path;
  if (!pnh.getParam("config", path)) {
    throw std::runtime_error("missing parameter '" + pnh.resolveName("config") +
                             "' (a policy config, set it in the launch file)");
  }
  quad_policy::PolicyNodeConfig cfg = quad_policy::LoadPolicyNodeConfig(path);
  std::string policy_file;
  if (pnh.getParam("policy_file", policy_file) && !policy_file.empty()) cfg.policy_file = policy_file;
  int threads = 0;
  if (pnh.getParam("num_threads", threads) && threads > 0) cfg.num_threads = threads;
  pnh.getParam("send_to_tracker", cfg.send_to_tracker);  // unchanged when not set
  if (cfg.policy_file.empty())
    throw std::runtime_error("no policy file: set policy_file in the config or ~policy_file");
  return cfg;
}

class PolicyNode {
 public:
  PolicyNode()
      : pnh_("~"),
        tf_listener_(tf_buffer_),
        cfg_(LoadConfig(pnh_)),
        tracker_(cfg_.tracker_accept_timeout_s, [this](const std::string& event) { ++counts_[event]; }) {
    quad_policy::TuneMallocForInference();
    quad_policy::ConfigureTorchThreads(cfg_.num_threads);
    auto policy = std::make_shared<const quad_policy::TorchPolicy>(cfg_.policy_file);
    decider_ = std::make_unique<quad_policy::PolicyDecider>(policy, cfg_.safety, cfg_.refusal, cfg_.recovery,
                                                            cfg_.keeping);
    const quad_policy::PolicyMeta& m = policy->meta();
    ROS_INFO(
        "policy_node: %s (input %dx%d, output %s %s, K = %d over %.2f s), %d thread(s), refusal action %s",
        cfg_.policy_file.c_str(), m.input_width, m.input_height, ToString(m.output_frame),
        ToString(m.representation), m.num_ctrl_pts, m.horizon_s, quad_policy::TorchThreads(),
        ToString(cfg_.refusal.action));
    policy->WarmUp();
    const ros::TransportHints hints = ros::TransportHints().tcpNoDelay();
    odom_sub_ = nh_.subscribe("odom", 50, &PolicyNode::OnOdom, this, hints);
    goal_sub_ = nh_.subscribe("planner/goal", 10, &PolicyNode::OnGoal, this, hints);
    info_sub_ = nh_.subscribe("camera/depth/camera_info", 2, &PolicyNode::OnCameraInfo, this, hints);
    status_sub_ = nh_.subscribe("sim/status", 10, &PolicyNode::OnStatus, this, hints);
    // 100 like the decisions: a recorder that falls behind (3 s at 30 Hz) still gets every trajectory.
    bspline_pub_ = nh_.advertise<quad_msgs::Bspline>("planner/bspline", 100);
    proposal_pub_ = nh_.advertise<quad_msgs::Bspline>("policy/proposal", 100);
    marker_pub_ = nh_.advertise<visualization_msgs::Marker>("policy/plan_marker", 10);
    decision_pub_ = nh_.advertise<quad_msgs::PolicyDecision>("policy/decision", 100);
    ack_pub_ = nh_.advertise<quad_msgs::FrameAck>("sim/frame_ack", 100);
    status_pub_ = nh_.advertise<std_msgs::String>("policy/status", 10, true);
    switch_client_ = nh_.serviceClient<quad_msgs::SwitchTracker>("tracker/switch");
    // Frames only once the simulator hears our acknowledgements (up to 5 s: an unlockstepped one never does).
    quad_core::WaitForSubscriber(ack_pub_, 5.0);
    // Depth frames are decided on their own thread so odometry and goals keep arriving meanwhile.
    ros::SubscribeOptions ops = ros::SubscribeOptions::create<sensor_msgs::Image>(
        "camera/depth/image", 2, [this](const sensor_msgs::Image::ConstPtr& msg) { OnDepth(*msg); },
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
  void OnOdom(const nav_msgs::Odometry::ConstPtr& msg) {
    {
      std::lock_guard<std::mutex> lock(mu_);
      odom_.push_back(quad_ros::ToVehicleState(*msg));
      while (odom_.size() > 400) odom_.pop_front();
    }
    odom_cv_.notify_all();
  }

  void OnGoal(const geometry_msgs::PoseStamped::ConstPtr& msg) {
    const Eigen::Vector3d g(msg->pose.position.x, msg->pose.position.y, msg->pose.position.z);
    std_msgs::String answer;
    answer.data = "goal rejected: not finite";
    if (g.allFinite()) {
      std::lock_guard<std::mutex> lock(mu_);
      goal_ = g;
      char text[96];
      std::snprintf(text, sizeof(text), "goal accepted: (%.2f, %.2f, %.2f)", g.x(), g.y(), g.z());
      answer.data = text;
    }
    // After the goal is stored: an episode runner in lockstep releases the frame once it reads this.
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
    }
    episode_id_ = msg->episode_id;
  }

  void OnDepth(const sensor_msgs::Image& img) {
    if (cfg_.send_to_tracker) tracker_.Start(nh_, HasGoal());
    quad_msgs::PolicyDecision out;
    out.header = img.header;
    out.node = "cpp";
    out.frame_seq = img.header.seq;
    out.action = "none";
    Handle(img, &out);
    for (const auto& [name, n] : counts_) {
      out.count_names.push_back(name);
      out.count_values.push_back(n);
    }
    std::tie(out.tracker_rejections, out.last_tracker_rejection) = tracker_.Rejections();
    decision_pub_.publish(out);
    tracker_.WaitAccepted();
    quad_msgs::FrameAck ack;  // lockstep: acknowledge after deciding (and sending), whatever the outcome
    ack.consumer = cfg_.lockstep_consumer;
    ack.frame_seq = img.header.seq;
    ack.stamp = img.header.stamp;
    ack_pub_.publish(ack);
  }

  bool HasGoal() {
    std::lock_guard<std::mutex> lock(mu_);
    return goal_.has_value();
  }

  void Skip(const std::string& status, const std::string& reason, quad_msgs::PolicyDecision* out) {
    out->status = status;
    out->reason = reason;
    ++counts_[status];
    if (status == "bad_input") ROS_WARN_THROTTLE(2.0, "policy_node: frame refused: %s", reason.c_str());
  }

  void Handle(const sensor_msgs::Image& img, quad_msgs::PolicyDecision* out) {
    const double stamp = img.header.stamp.toSec();
    std::string problem;
    quad_policy::DecisionInputs in;
    in.stamp_s = stamp;
    in.depth = quad_policy::DepthView(img, &problem);
    if (!problem.empty()) return Skip("bad_input", problem, out);
    std::optional<Eigen::Vector3d> goal;
    std::optional<quad_policy::VehicleState> odom;
    std::optional<sensor_msgs::CameraInfo> info;
    std::optional<ros::Time> last_decision;
    bool reset_decider = false;
    {
      // Wait (at most odom_wait_s of wall time) for the frame's own odometry, so that which odometry a
      // decision starts from does not depend on message timing; without it, the newest older one is used.
      std::unique_lock<std::mutex> lock(mu_);
      odom_cv_.wait_for(lock, std::chrono::duration<double>(cfg_.odom_wait_s), [&] {
        return !odom_.empty() && quad_core::OdometryCoversFrame(odom_.back().t_s, stamp, cfg_.odom_period_s);
      });
      const auto* paired = quad_core::PairedOdometry(odom_, stamp, [](const auto& s) { return s.t_s; });
      if (paired != nullptr) odom = *paired;
      goal = goal_;
      info = camera_info_;
      last_decision = last_decision_stamp_;
      std::swap(reset_decider, reset_decider_);
    }
    if (reset_decider) decider_->Reset();
    if (!goal) return Skip("no_goal", "no goal for this episode yet", out);
    if (!odom) return Skip("no_odometry", "no odometry at or before the frame", out);
    if (!info) return Skip("no_camera_info", "no camera info yet", out);
    // Bad input is refused before anything is computed from it: nothing is sent for this frame, so the
    // tracker flies on along the plan it has (docs/CONVENTIONS.md, fault table).
    problem = quad_policy::DepthSizeProblem(img.width, img.height, info->width, info->height);
    if (problem.empty()) problem = quad_policy::StateProblem(*odom, odom->t_s);
    if (!problem.empty()) return Skip("bad_input", problem, out);
    if (stamp - odom->t_s > cfg_.max_odom_age_s) {
      return Skip("stale_odometry", "latest odometry is " + std::to_string(stamp - odom->t_s) + " s old",
                  out);
    }
    if ((odom->p_world_body - *goal).norm() < cfg_.goal_tolerance_m) {
      return Skip("goal_reached", "within goal_tolerance_m of the goal", out);
    }
    // In integer nanoseconds (as the Python node), so that both nodes decide on exactly the same frames.
    if (cfg_.replan_rate_hz > 0.0 && last_decision &&
        (img.header.stamp - *last_decision).toNSec() < std::llround(1e9 / cfg_.replan_rate_hz)) {
      return Skip("rate_limited", "replan_rate_hz", out);
    }
    if (!T_body_camera_) {
      try {  // no waiting: a lockstepped simulator holds ROS time while this frame is open (the next retries)
        T_body_camera_ = quad_policy::ToIsometry(
            tf_buffer_.lookupTransform("base_link", img.header.frame_id, ros::Time(0)).transform);
      } catch (const tf2::TransformException& e) {
        return Skip("no_camera_pose", e.what(), out);
      }
    }
    in.camera = quad_policy::ToCameraModel(*info, *odom, *T_body_camera_);
    in.state = *odom;
    in.goal_world = *goal;
    quad_policy::Decision d;
    try {
      d = decider_->Decide(in);
    } catch (const std::exception& e) {
      return Skip("bad_input", e.what(), out);
    }
    {
      std::lock_guard<std::mutex> lock(mu_);
      last_decision_stamp_ = img.header.stamp;
    }
    const auto t0 = std::chrono::steady_clock::now();
    const quad_policy::UniformBspline* send = d.to_send();
    quad_msgs::Bspline msg;
    if (send != nullptr) msg = quad_policy::ToBsplineMessage(*send, ++traj_id_, img.header.stamp);
    out->message_ms = d.timings.decode_ms + MsSince(t0);
    const quad_policy::DecisionSummary summary = Summarize(d, decider_->meta().hypotheses, stamp);
    out->status = "decided";
    out->verdict = ToString(d.safety.verdict);
    out->accepted = d.accepted();
    out->reason = summary.reason;
    out->action = summary.action;
    out->preprocess_ms = d.timings.preprocess_ms;
    out->forward_ms = d.timings.forward_ms;
    out->decision_ms = out->preprocess_ms + out->forward_ms + out->message_ms;
    out->safety_ms = d.timings.safety_ms;
    ++counts_[out->verdict];
    for (const std::string& event : summary.events) ++counts_[event];
    proposal_pub_.publish(
        quad_policy::ToBsplineMessage(d.proposed, d.accepted() ? traj_id_ : 0, img.header.stamp));
    if (send != nullptr) {
      out->traj_id = msg.traj_id;
      bspline_pub_.publish(msg);
      marker_pub_.publish(quad_policy::PlanMarker(*send, img.header, "policy_cpp"));
      tracker_.Send(msg);
      hovering_ = false;
    } else if (summary.action == "hover" && !hovering_) {
      hovering_ = SwitchToHover();
    }
  }

  bool SwitchToHover() {
    quad_msgs::SwitchTracker srv;
    srv.request.tracker = "hover";
    if (switch_client_.call(srv) && srv.response.success) return true;
    ROS_WARN_THROTTLE(5.0, "policy_node: could not switch the tracker to hover: %s",
                      srv.response.message.c_str());
    ++counts_["hover_failed"];
    return false;
  }

  ros::NodeHandle nh_;
  ros::NodeHandle pnh_;
  tf2_ros::Buffer tf_buffer_;
  tf2_ros::TransformListener tf_listener_;
  quad_policy::PolicyNodeConfig cfg_;
  std::unique_ptr<quad_policy::PolicyDecider> decider_;
  ros::Subscriber odom_sub_, goal_sub_, info_sub_, status_sub_, depth_sub_;
  ros::Publisher bspline_pub_, proposal_pub_, marker_pub_, decision_pub_, ack_pub_, status_pub_;
  ros::ServiceClient switch_client_;
  quad_policy::TrackerLink tracker_;  // used on the depth thread
  ros::CallbackQueue depth_queue_;
  std::thread depth_thread_;

  std::mutex mu_;                    // guards the inputs below (written by the main spinner, read
                                     // by the depth thread)
  std::condition_variable odom_cv_;  // an odometry message arrived
  std::deque<quad_policy::VehicleState> odom_;
  std::optional<Eigen::Vector3d> goal_;
  std::optional<sensor_msgs::CameraInfo> camera_info_;
  std::optional<uint32_t> episode_id_;
  std::optional<ros::Time> last_decision_stamp_;
  std::atomic<bool> hovering_ = false;  // the tracker was switched to hover by a refusal
                                        // (cleared by the next trajectory)
  bool reset_decider_ = false;  // a new episode began: the depth thread resets the decider before deciding

  // depth thread only
  std::optional<Eigen::Isometry3d> T_body_camera_;
  std::map<std::string, uint64_t> counts_;
  int64_t traj_id_ = 0;
};

}  // namespace

int main(int argc, char** argv) {
  ros::init(argc, argv, "policy_node");
  try {
    PolicyNode node;
    ros::spin();
  } catch (const std::exception& e) {
    ROS_FATAL("policy_node: %s", e.what());
    // Debian's rosconsole prints nothing to the console without a config file: the reason the node stops (a
    // bad policy file, config or parameter) also goes to stderr, so whoever started it sees it.
    std::fprintf(stderr, "[FATAL] policy_node: %s\n", e.what());
    return 1;
  }
  return 0;
}
