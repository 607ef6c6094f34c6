#include "peer_graph.h"

#include <ros/master.h>
#include <ros/network.h>
#include <xmlrpcpp/XmlRpcClient.h>

#include <chrono>
#include <thread>

namespace quad_sim_ros {
namespace {

// True if `node`'s own bus information (its getBusInfo XML-RPC call) lists an accepted outgoing connection
// on `topic` to `subscriber`: only then does a message it publishes reach that subscriber.
bool PublisherDeliversTo(const std::string& node, const std::string& topic, const std::string& subscriber) {
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

std::set<std::string> NodesOf(XmlRpc::XmlRpcValue& entry) {
  std::set<std::string> out;
  for (int j = 0; j < entry[1].size(); ++j) out.insert(static_cast<std::string>(entry[1][j]));
  return out;
}

}  // namespace

quad_core::LockstepPeers PeerGraph::Gather(const std::string& ack_topic,
                                           const std::set<std::string>& command_topics,
                                           int command_publishers_connected,
                                           std::set<std::string>* delivering) {
  quad_core::LockstepPeers peers;
  {
    std::lock_guard<std::mutex> lock(mu_);
    for (const auto& [topic, nodes] : connected_) {
      for (const auto& [node, n] : nodes) {
        if (n > 0) peers.connected_subscribers[topic].insert(node);
      }
    }
  }
  peers.command_publishers_connected = command_publishers_connected;
  const std::string me = ros::this_node::getName();
  XmlRpc::XmlRpcValue req, res, state;
  req[0] = me;
  if (!ros::master::execute("getSystemState", req, res, state, false)) return peers;
  XmlRpc::XmlRpcValue& pubs = state[0];
  for (int i = 0; i < pubs.size(); ++i) {
    const std::string topic = pubs[i][0];
    if (topic == ack_topic) {
      for (const std::string& n : NodesOf(pubs[i])) {
        if (n != me) peers.ack_publishers.insert(n);
      }
    } else if (command_topics.count(topic) > 0) {
      for (const std::string& n : NodesOf(pubs[i])) peers.command_publishers.insert(n);
    }
  }
  XmlRpc::XmlRpcValue& subs = state[1];
  for (int i = 0; i < subs.size(); ++i) {
    const std::string topic = subs[i][0];
    if (tracked_topics_.count(topic) > 0) peers.registered_subscribers[topic] = NodesOf(subs[i]);
  }
  for (const std::string& n : peers.ack_publishers) {
    if (delivering->count(n) == 0 && PublisherDeliversTo(n, ack_topic, me)) delivering->insert(n);
    if (delivering->count(n) > 0) peers.ack_publishers_delivering.insert(n);
  }
  return peers;
}

void PeerGraph::WaitUntilReady(const quad_core::LockstepNeeds& needs, const std::string& ack_topic,
                               const std::set<std::string>& command_topics,
                               const std::function<int()>& command_publishers_connected,
                               const std::function<bool()>& keep_waiting) {
  const auto t0 = std::chrono::steady_clock::now();
  auto next_log = t0 + std::chrono::seconds(5);
  std::set<std::string> delivering;  // confirmed once: a publisher's accepted connection stays
  std::string waited_for;
  while (ros::ok() && keep_waiting()) {
    const quad_core::LockstepPeers peers =
        Gather(ack_topic, command_topics, command_publishers_connected(), &delivering);
    const quad_core::LockstepPeerCheck check = quad_core::CheckLockstepPeers(peers, needs);
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

}  // namespace quad_sim_ros
