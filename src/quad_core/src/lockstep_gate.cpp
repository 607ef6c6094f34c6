#include "quad_core/lockstep_gate.h"

#include <cmath>
#include <cstdio>
#include <stdexcept>

namespace quad_core {
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

std::string Seconds(uint64_t stamp_ns, const char* format) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), format, static_cast<double>(stamp_ns) * 1e-9);
  return buf;
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

LockstepGate::LockstepGate(LockstepGateConfig config) : config_(std::move(config)) {
  if (!std::isfinite(config_.timeout_s) || config_.timeout_s <= 0.0) {
    throw std::invalid_argument("lockstep gate: timeout_s must be > 0, got " +
                                std::to_string(config_.timeout_s));
  }
  if (!std::isfinite(config_.first_command_resend_period_s) || config_.first_command_resend_period_s <= 0.0) {
    throw std::invalid_argument("lockstep gate: first_command_resend_period_s must be > 0, got " +
                                std::to_string(config_.first_command_resend_period_s));
  }
  std::set<std::string> seen;
  for (const std::string& c : config_.depth_consumers) {
    if (c.empty()) throw std::invalid_argument("lockstep gate: depth_consumers holds an empty name");
    if (!seen.insert(c).second) {
      throw std::invalid_argument("lockstep gate: depth consumer '" + c + "' is named twice");
    }
  }
}

LockstepNeeds LockstepGate::Needs(const std::string& odom_topic, const std::string& image_topic,
                                  const std::string& camera_info_topic) const {
  LockstepNeeds n;
  n.odom_topic = odom_topic;
  n.image_topic = image_topic;
  n.frame_topics = {image_topic, camera_info_topic};
  n.num_depth_consumers = static_cast<int>(config_.depth_consumers.size());
  n.wait_for_command = config_.wait_for_command;
  return n;
}

void LockstepGate::BeginEpisode(uint64_t first_stamp_ns) {
  episode_start_ns_ = first_stamp_ns;
  last_answer_ns_ = 0;
  acked_ns_.clear();
  wait_ = Wait::kNone;
}

LockstepGate::CommandVerdict LockstepGate::OnCommand(uint64_t stamp_ns) {
  if (stamp_ns != 0 && stamp_ns < episode_start_ns_) return CommandVerdict::kStale;
  last_answer_ns_ = stamp_ns;
  return CommandVerdict::kCurrent;
}

void LockstepGate::OnAck(const std::string& consumer, uint64_t stamp_ns) {
  uint64_t& last = acked_ns_[consumer];
  if (stamp_ns > last) last = stamp_ns;
}

std::vector<std::string> LockstepGate::MissingAcks(uint64_t stamp_ns) const {
  std::vector<std::string> missing;
  for (const std::string& c : config_.depth_consumers) {
    const auto it = acked_ns_.find(c);
    if (it == acked_ns_.end() || it->second < stamp_ns) missing.push_back(c);
  }
  return missing;
}

void LockstepGate::AwaitCommand(uint64_t stamp_ns, double wall_now_s) {
  if (!config_.wait_for_command) {
    wait_ = Wait::kNone;
    return;
  }
  wait_ = Wait::kCommand;
  wait_stamp_ns_ = stamp_ns;
  deadline_s_ = wall_now_s + config_.timeout_s;
  resending_ = !answered_this_episode();
  next_resend_s_ = wall_now_s + config_.first_command_resend_period_s;
}

void LockstepGate::AwaitFrame(uint64_t stamp_ns, double wall_now_s) {
  if (!waits_for_frames()) {
    wait_ = Wait::kNone;
    return;
  }
  wait_ = Wait::kFrame;
  wait_stamp_ns_ = stamp_ns;
  deadline_s_ = wall_now_s + config_.timeout_s;
  resending_ = false;
}

LockstepGate::Decision LockstepGate::Poll(double wall_now_s) {
  Decision d;
  if (wait_ == Wait::kNone) return d;
  const bool done =
      wait_ == Wait::kCommand ? CommandAnswered(wait_stamp_ns_) : FrameAcknowledged(wait_stamp_ns_);
  if (done) {
    wait_ = Wait::kNone;
    return d;
  }
  if (wall_now_s >= deadline_s_) {
    d.action = Action::kTimeout;
    char timeout[32];
    std::snprintf(timeout, sizeof(timeout), "%.2f", config_.timeout_s);
    if (wait_ == Wait::kCommand) {
      ++command_timeouts_;
      d.message = "no command stamped " + Seconds(wait_stamp_ns_, "%.3f") + " within " + timeout +
                  " s (command timeouts so far: " + std::to_string(command_timeouts_) + ")";
    } else {
      ++ack_timeouts_;
      std::string names;
      for (const std::string& c : MissingAcks(wait_stamp_ns_)) names += (names.empty() ? "" : ", ") + c;
      d.message = "depth frame " + Seconds(wait_stamp_ns_, "%.3f") + " not acknowledged by [" + names +
                  "] within " + timeout + " s (ack timeouts so far: " + std::to_string(ack_timeouts_) + ")";
    }
    wait_ = Wait::kNone;
    return d;
  }
  if (resending_ && next_resend_s_ < deadline_s_ && wall_now_s >= next_resend_s_) {
    d.action = Action::kResend;
    ++resends_;
    next_resend_s_ += config_.first_command_resend_period_s;
    return d;
  }
  d.action = Action::kWait;
  d.wake_at_s = deadline_s_;
  if (resending_ && next_resend_s_ < d.wake_at_s) d.wake_at_s = next_resend_s_;
  return d;
}

}  // namespace quad_core
