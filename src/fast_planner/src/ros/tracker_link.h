// fast_planner_node's link to the tracker's B-spline action (tracker/track_bspline), ROS side only: a
// trajectory planned before the action server is connected waits and is sent once it is; after sending, the
// node waits (wall time, at most tracker_accept_timeout_s; the action client spins its own thread) until the
// tracker has taken it, so in lockstep the new trajectory takes effect before the simulator advances (the
// frame is acknowledged after this). The client is built late: it waits for a valid time when built, and with
// sim time in lockstep the simulator may be waiting for this node meanwhile.
#pragma once

#include <actionlib/client/simple_action_client.h>
#include <quad_msgs/Bspline.h>
#include <quad_msgs/TrackBsplineAction.h>
#include <ros/ros.h>

#include <cstdint>
#include <memory>
#include <optional>

namespace fast_planner::ros_conv {

class TrackerLink {
 public:
  TrackerLink(const ros::NodeHandle& nh, double accept_timeout_s)
      : nh_(nh), accept_timeout_s_(accept_timeout_s) {}

  // Builds the client once there is a valid time.
  void Connect() {
    if (!client_ && !ros::Time::now().isZero()) {
      client_ = std::make_unique<actionlib::SimpleActionClient<quad_msgs::TrackBsplineAction>>(
          nh_, "tracker/track_bspline", true);
    }
  }

  // Replaces the waiting trajectory by this one and sends it if the server is connected.
  void Send(const quad_msgs::Bspline& b) {
    pending_ = b;
    SendPending();
  }
  // Sends the waiting trajectory, if any, once the server is connected, and waits until it is taken.
  void SendPending() {
    if (!pending_ || !client_ || !client_->isServerConnected()) return;
    quad_msgs::TrackBsplineGoal goal;
    goal.bspline = *pending_;
    client_->sendGoal(goal);
    pending_.reset();
    if (accept_timeout_s_ <= 0.0) return;
    const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(accept_timeout_s_);
    while (client_->getState() == actionlib::SimpleClientGoalState::PENDING) {
      if (ros::WallTime::now() > deadline || !ros::ok()) {
        ROS_WARN("fast_planner: the tracker did not take trajectory %ld within %.2f s (%lu times so far)",
                 static_cast<long>(goal.bspline.traj_id), accept_timeout_s_,
                 static_cast<unsigned long>(++accept_timeouts_));
        return;
      }
      ros::WallDuration(0.0002).sleep();
    }
  }
  bool waiting() const { return pending_.has_value(); }
  // A new episode: the previous episode's waiting trajectory is dropped.
  void Drop() { pending_.reset(); }

 private:
  ros::NodeHandle nh_;
  double accept_timeout_s_;
  uint64_t accept_timeouts_ = 0;
  std::unique_ptr<actionlib::SimpleActionClient<quad_msgs::TrackBsplineAction>> client_;
  std::optional<quad_msgs::Bspline> pending_;
};

}  // namespace fast_planner::ros_conv
