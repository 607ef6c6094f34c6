// The policy node's link to the tracker's B-spline action (tracker/track_bspline): sending a trajectory and
// waiting, bounded, until the tracker has taken it. ROS side only.
//
// Why the wait: in lockstep the simulator steps on once the frame is acknowledged, and the tracker applies a
// trajectory from the first odometry after it took it; without the wait the step it starts at would depend on
// message timing. Why the client is built late: actionlib's ActionClient waits for a valid ROS time when it
// is built, and under use_sim_time a lockstepped simulator publishes /clock only once the node subscribes to
// frames, so the node builds it on the first frame (Start()).
#pragma once

#include <actionlib/client/action_client.h>
#include <quad_msgs/TrackBsplineAction.h>
#include <ros/ros.h>

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>

namespace quad_policy {

class TrackerLink {
 public:
  using Client = actionlib::ActionClient<quad_msgs::TrackBsplineAction>;
  using CountEvent = std::function<void(const std::string&)>;

  TrackerLink(double accept_timeout_s, CountEvent count)
      : accept_timeout_s_(accept_timeout_s), count_(count) {}

  // Builds the client on the first call. Until its connection is confirmed (which needs sim time to pass), a
  // frame without a goal yet waits up to 50 ms (5 s in all), so the first trajectory of an episode is not
  // lost to a connection still being set up.
  void Start(ros::NodeHandle& nh, bool frame_has_goal) {
    if (!client_) client_ = std::make_unique<Client>(nh, "tracker/track_bspline");
    if (connect_wait_left_s_ <= 0.0 || client_->isServerConnected() || frame_has_goal) return;
    const auto t0 = std::chrono::steady_clock::now();
    while (!client_->isServerConnected() && Seconds(t0) < 0.05 && ros::ok()) {
      std::this_thread::sleep_for(std::chrono::milliseconds(2));
    }
    connect_wait_left_s_ -= Seconds(t0);
  }

  // Sent even when the connection is not confirmed yet (counted): right after start-up the goal topic is
  // often connected before the server's status has confirmed it, and the goal then arrives. Waited for as
  // well (those first goals must take effect at the same step in every run too), unless a wait timed out
  // without a confirmed connection (no tracker at all).
  void Send(const quad_msgs::Bspline& msg) {
    if (!client_) return;
    const bool connected = client_->isServerConnected();
    if (!connected) count_("tracker_not_connected");
    quad_msgs::TrackBsplineGoal goal;
    goal.bspline = msg;
    Client::GoalHandle gh = client_->sendGoal(goal, [this](Client::GoalHandle h) { OnTransition(h); });
    if (connected) no_tracker_ = false;
    if (connected || !no_tracker_) {
      pending_ = gh;
      pending_id_ = msg.traj_id;
    }
    std::lock_guard<std::mutex> lock(mu_);
    handles_.push_back(gh);  // keeps the goal tracked until its result arrives
    while (handles_.size() > 64) handles_.pop_front();
  }

  // Waits (wall time, at most accept_timeout_s) until the tracker has answered the trajectory sent last. The
  // comm state is read without holding accept_mu_ (actionlib holds its own lock while it calls OnTransition).
  void WaitAccepted() {
    if (!pending_) return;
    const Client::GoalHandle gh = *pending_;
    pending_.reset();
    const auto t0 = std::chrono::steady_clock::now();
    while (gh.getCommState() == actionlib::CommState::WAITING_FOR_GOAL_ACK && ros::ok()) {
      if (Seconds(t0) >= accept_timeout_s_) {
        if (!client_->isServerConnected()) no_tracker_ = true;
        count_("tracker_accept_timeout");
        ROS_WARN("policy_node: the tracker did not take trajectory %ld in time",
                 static_cast<long>(pending_id_));
        return;
      }
      std::unique_lock<std::mutex> lock(accept_mu_);  // woken by any transition; the timeout covers a miss
      accept_cv_.wait_for(lock, std::chrono::milliseconds(2));
    }
  }

  // Rejections so far and the last one's reason.
  std::pair<uint64_t, std::string> Rejections() {
    std::lock_guard<std::mutex> lock(mu_);
    return {rejections_, last_rejection_};
  }

 private:
  static double Seconds(std::chrono::steady_clock::time_point t0) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  }

  void OnTransition(Client::GoalHandle gh) {  // on the main spinner thread
    { std::lock_guard<std::mutex> lock(accept_mu_); }
    accept_cv_.notify_all();
    if (gh.getCommState() != actionlib::CommState::DONE) return;
    if (gh.getTerminalState() != actionlib::TerminalState::REJECTED) return;
    std::lock_guard<std::mutex> lock(mu_);
    ++rejections_;
    const auto result = gh.getResult();
    last_rejection_ = result ? result->reason : gh.getTerminalState().getText();
  }

  double accept_timeout_s_;
  CountEvent count_;
  std::unique_ptr<Client> client_;
  std::optional<Client::GoalHandle> pending_;  // the trajectory sent last, until the tracker answers
  int64_t pending_id_ = 0;
  bool no_tracker_ = false;           // a wait timed out without a confirmed connection
  double connect_wait_left_s_ = 5.0;  // wall time left to wait for the connection at start-up
  std::mutex accept_mu_;
  std::condition_variable accept_cv_;
  std::mutex mu_;  // guards the handles and the rejections
  std::deque<Client::GoalHandle> handles_;
  uint64_t rejections_ = 0;
  std::string last_rejection_;
};

}  // namespace quad_policy
