#include "quad_sim/lockstep_peers.h"

namespace quad_sim {
namespace {

bool Contains(const std::map<std::string, std::set<std::string>>& m, const std::string& topic,
              const std::string& node) {
  const auto it = m.find(topic);
  return it != m.end() && it->second.count(node) > 0;
}

void Add(std::string* out, const std::string& what) {
  if (!out->empty()) *out += "; ";
  *out += what;
}

}  // namespace

LockstepPeerCheck CheckLockstepPeers(const LockstepPeers& peers, const LockstepNeeds& needs) {
  LockstepPeerCheck r;
  if (needs.num_depth_consumers > 0) {
    if (static_cast<int>(peers.ack_publishers.size()) < needs.num_depth_consumers) {
      Add(&r.missing, std::to_string(peers.ack_publishers.size()) + " of " +
                          std::to_string(needs.num_depth_consumers) + " FrameAck publishers registered");
    }
    for (const std::string& node : peers.ack_publishers) {
      if (peers.ack_publishers_delivering.count(node) == 0) {
        Add(&r.missing, node + "'s FrameAck publisher not yet connected to the simulator");
      }
      bool gets_frames = false;
      for (const std::string& t : needs.frame_topics)
        gets_frames |= Contains(peers.connected_subscribers, t, node);
      if (!gets_frames) Add(&r.missing, node + " not yet connected to the depth frames");
    }
    const auto images = peers.connected_subscribers.find(needs.image_topic);
    if (images == peers.connected_subscribers.end() || images->second.empty()) {
      Add(&r.missing, "no depth image subscriber connected");
    }
  }
  if (needs.wait_for_command) {
    if (peers.command_publishers_connected == 0) Add(&r.missing, "no command publisher connected");
    const auto it = peers.connected_subscribers.find(needs.odom_topic);
    if (it == peers.connected_subscribers.end() || it->second.empty()) {
      Add(&r.missing, "no odometry subscriber connected");
    }
  }
  std::set<std::string> participants = peers.ack_publishers;
  participants.insert(peers.command_publishers.begin(), peers.command_publishers.end());
  for (const auto& [topic, nodes] : peers.registered_subscribers) {
    for (const std::string& node : nodes) {
      if (participants.count(node) > 0 && !Contains(peers.connected_subscribers, topic, node)) {
        Add(&r.missing, node + " registered for " + topic + " but not yet connected");
      }
    }
  }
  r.ready = r.missing.empty();
  return r;
}

}  // namespace quad_sim
