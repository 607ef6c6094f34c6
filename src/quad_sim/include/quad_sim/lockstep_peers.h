// When may a lockstepped simulator start (or restart) stepping? The start-up barrier of the lockstep protocol
// (docs/CONVENTIONS.md), ROS-free: the node gathers who is registered with the ROS master and who is really
// connected, this decides.
//
// Why more than counting connections (issue 30): ROS drops a message published before a subscriber's
// connection is set up, and "one subscriber of /odom" was satisfied by the tracker while the expert planner's
// own odometry connection was still being set up. The planner then received the episode's first depth frame
// without its odometry, held it waiting for that odometry, and the simulator waited a whole lockstep timeout
// (20 s) for its acknowledgement. Counting acknowledgement publishers has the mirror race: the simulator's
// side of a connection exists before the publisher has accepted it, and an acknowledgement sent in between
// is lost.
#pragma once

#include <map>
#include <set>
#include <string>
#include <vector>

namespace quad_sim {

// What the node sees, by node name. Topic names are the resolved (global) ones.
struct LockstepPeers {
  // Subscribers registered with the master, per topic the simulator publishes and lockstep depends on
  // (clock, odometry, depth image, camera_info, tf, tf_static).
  std::map<std::string, std::set<std::string>> registered_subscribers;
  // Subscribers whose connection the simulator's publisher has accepted (messages reach them), per topic.
  std::map<std::string, std::set<std::string>> connected_subscribers;
  // Nodes registered with the master as publishers of FrameAck, and of the commands (SO3/TRPY).
  std::set<std::string> ack_publishers;
  std::set<std::string> command_publishers;
  // Ack publishers whose own side lists the simulator as a connected subscriber of FrameAck (an ack they
  // send now reaches the simulator).
  std::set<std::string> ack_publishers_delivering;
  // Command publishers the simulator's subscription is connected to.
  int command_publishers_connected = 0;
};

// The topics and what the protocol needs.
struct LockstepNeeds {
  std::string odom_topic;
  std::string image_topic;                // the depth images
  std::vector<std::string> frame_topics;  // a consumer acknowledges frames: it subscribes to one of these
  int num_depth_consumers = 0;            // lockstep.depth_consumers.size()
  bool wait_for_command = false;          // lockstep.wait_for_command
};

// Ready (empty `missing`) when:
// - depth consumers: at least num_depth_consumers FrameAck publishers are registered, each delivers to the
//   simulator and is connected as a subscriber of a frame topic, and the depth image has a connected
//   subscriber (a policy node subscribes to images only once its FrameAck publisher is connected, after its
//   camera_info: its registration alone cannot show it);
// - commands: a command publisher is connected and odometry has a connected subscriber;
// - every topic a lockstep participant (a FrameAck or command publisher) has registered a subscription to is
//   connected for it. Participants register their subscriptions in their constructors; a consumer's frame
//   subscription connected (the rule above) thus implies that its earlier registrations are known.
// Other nodes (rviz, rostopic, a dead node still registered) are never waited for.
struct LockstepPeerCheck {
  bool ready = false;
  std::string missing;  // human-readable: what is still being waited for
};
LockstepPeerCheck CheckLockstepPeers(const LockstepPeers& peers, const LockstepNeeds& needs);

}  // namespace quad_sim
