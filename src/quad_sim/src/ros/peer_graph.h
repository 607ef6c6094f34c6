// What quad_sim_node sees of the ROS graph for the lockstep start-up barrier (quad_core/lockstep_gate.h,
// CheckLockstepPeers): who is registered with the master, which subscribers the node's publishers have
// accepted, and which FrameAck publishers deliver to the node (their own bus information).
#pragma once

#include "quad_core/lockstep_gate.h"

#include <ros/ros.h>

#include <functional>

#include <map>
#include <mutex>
#include <set>
#include <string>

namespace quad_sim_ros {

class PeerGraph {
 public:
  // Advertises `topic` and keeps count of its connected subscribers by node name.
  template <typename M>
  ros::Publisher Advertise(ros::NodeHandle& nh, const std::string& topic, uint32_t queue_size,
                           bool latch = false) {
    const auto on_connect = [this](const ros::SingleSubscriberPublisher& p) {
      std::lock_guard<std::mutex> lock(mu_);
      ++connected_[p.getTopic()][p.getSubscriberName()];
    };
    const auto on_disconnect = [this](const ros::SingleSubscriberPublisher& p) {
      std::lock_guard<std::mutex> lock(mu_);
      --connected_[p.getTopic()][p.getSubscriberName()];
    };
    ros::Publisher pub =
        nh.advertise<M>(topic, queue_size, on_connect, on_disconnect, ros::VoidConstPtr(), latch);
    tracked_topics_.insert(pub.getTopic());
    return pub;
  }

  // The peers as seen now: registered subscribers of the Advertise()d topics, connected subscribers,
  // FrameAck and command publishers; `delivering` carries the FrameAck publishers confirmed earlier in the
  // same barrier (an accepted connection stays), so each is asked once.
  quad_core::LockstepPeers Gather(const std::string& ack_topic, const std::set<std::string>& command_topics,
                                  int command_publishers_connected, std::set<std::string>* delivering);

  // The start-up barrier: polls the graph every 20 ms until CheckLockstepPeers is ready or keep_waiting()
  // turns false, logging what it waits for (at once, then every 5 s, and how long it took).
  void WaitUntilReady(const quad_core::LockstepNeeds& needs, const std::string& ack_topic,
                      const std::set<std::string>& command_topics,
                      const std::function<int()>& command_publishers_connected,
                      const std::function<bool()>& keep_waiting);

 private:
  std::mutex mu_;
  std::map<std::string, std::map<std::string, int>> connected_;  // topic -> node -> links
  std::set<std::string> tracked_topics_;                         // set while advertising, before any Gather
};

}  // namespace quad_sim_ros
