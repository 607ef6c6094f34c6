// The lockstep protocol's state machine, ROS-free (docs/CONVENTIONS.md, "Lockstep"): after publishing an
// odometry message or a depth frame, a lockstepped publisher (the simulator) holds sim time until the frame's
// answers are in: the command stamped with the odometry's stamp, and a FrameAck stamped with the frame's
// stamp from every named consumer. Each wait ends on a wall-clock timeout, which is counted. Before an
// episode's first step, the start-up barrier (CheckLockstepPeers) says whether every participant is
// connected.
//
// Stamps are integer nanoseconds of sim time (exact, as ROS's stamps); 0 means "unstamped". Wall times are
// seconds on any monotonic clock the caller chooses. The gate is not thread-safe: a caller feeding it from
// several threads guards it with one mutex.
//
//   LockstepGate gate(cfg);
//   gate.BeginEpisode(first_stamp_ns);                  // at every reset
//   gate.AwaitFrame(stamp_ns, wall_s);                  // right after publishing the frame
//   while (true) {                                      // the waiting thread
//     const LockstepGate::Decision d = gate.Poll(wall_s);
//     if (d.action == kRelease || d.action == kTimeout) break;   // kTimeout: d.message says who was missing
//     if (d.action == kResend) republish the episode's first odometry;
//     else sleep until d.wake_at_s or until an input arrives (OnAck / OnCommand from the other threads)
//   }
#pragma once

#include <cstdint>
#include <map>
#include <set>
#include <string>
#include <vector>

namespace quad_core {

// ---- the start-up barrier ----
// Why more than counting connections (issue 30): ROS drops a message published before a subscriber's
// connection is set up, and "one subscriber of /odom" was satisfied by the tracker while the expert planner's
// own odometry connection was still being set up. The planner then received the episode's first depth frame
// without its odometry, held it waiting for that odometry, and the simulator waited a whole lockstep timeout
// (20 s) for its acknowledgement. Counting acknowledgement publishers has the mirror race: the simulator's
// side of a connection exists before the publisher has accepted it, and an acknowledgement sent in between
// is lost.

// What the publisher sees of the ROS graph, by node name. Topic names are the resolved (global) ones.
struct LockstepPeers {
  // Subscribers registered with the master, per topic the publisher publishes and lockstep depends on
  // (clock, odometry, depth image, camera_info, tf, tf_static).
  std::map<std::string, std::set<std::string>> registered_subscribers;
  // Subscribers whose connection the publisher has accepted (messages reach them), per topic.
  std::map<std::string, std::set<std::string>> connected_subscribers;
  // Nodes registered with the master as publishers of FrameAck, and of the commands (SO3/TRPY).
  std::set<std::string> ack_publishers;
  std::set<std::string> command_publishers;
  // Ack publishers whose own side lists the publisher as a connected subscriber of FrameAck (an ack they
  // send now reaches it).
  std::set<std::string> ack_publishers_delivering;
  // Command publishers the command subscriptions are connected to.
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
//   publisher and is connected as a subscriber of a frame topic, and the depth image has a connected
//   subscriber (a policy node subscribes to images only once its FrameAck publisher is connected, after its
//   camera_info: its registration alone cannot show it);
// - commands: a command publisher is connected and odometry has a connected subscriber;
// - every topic a lockstep participant (a FrameAck or command publisher) has registered a subscription to is
//   connected for it. Participants register their subscriptions in their constructors; a consumer's frame
//   subscription connected (the rule above) thus implies that its earlier registrations are known.
// Other nodes (rviz, rostopic, a dead node still registered) are never waited for; a participant that joins
// later (registers after a check) is waited for from the next check on.
struct LockstepPeerCheck {
  bool ready = false;
  std::string missing;  // human-readable: what is still being waited for
};
LockstepPeerCheck CheckLockstepPeers(const LockstepPeers& peers, const LockstepNeeds& needs);

// ---- the per-frame gate ----
struct LockstepGateConfig {
  std::vector<std::string> depth_consumers;  // FrameAck.consumer names waited for after every depth frame
  bool wait_for_command = false;             // wait for the command stamped with each odometry stamp
  double timeout_s = 2.0;                    // wall-clock time per wait
  // While an episode has had no command yet, its unanswered odometry is sent again this often (wall
  // seconds): the command source's subscription may still be connecting when the first odometry goes out,
  // and ROS drops a message published before a subscriber connects.
  double first_command_resend_period_s = 0.5;
};

class LockstepGate {
 public:
  enum class Action {
    kRelease,  // the awaited answers are in (or nothing is awaited): step on
    kWait,     // wait until wake_at_s or until an input arrives, then Poll again
    kResend,   // publish the unanswered odometry again, then Poll again
    kTimeout,  // the wait timed out (counted; `message` names what was missing): step on
  };
  struct Decision {
    Action action = Action::kRelease;
    double wake_at_s = 0.0;  // kWait: the latest wall time to Poll again
    std::string message;     // kTimeout: what was missing, for the log
  };
  enum class CommandVerdict {
    kCurrent,  // a command of this episode (or unstamped): apply it
    kStale,    // stamped before this episode began: an answer to the previous episode, ignore it
  };

  // Throws std::invalid_argument naming the field: timeout_s or the resend period not positive and finite,
  // an empty or repeated consumer name.
  explicit LockstepGate(LockstepGateConfig config);

  const LockstepGateConfig& config() const { return config_; }
  bool waits_for_command() const { return config_.wait_for_command; }
  bool waits_for_frames() const { return !config_.depth_consumers.empty(); }
  // Whether the start-up barrier applies at all (nothing to wait for without participants).
  bool needs_peers() const { return waits_for_command() || waits_for_frames(); }
  // What the start-up barrier checks for this configuration, given the publisher's resolved topics.
  LockstepNeeds Needs(const std::string& odom_topic, const std::string& image_topic,
                      const std::string& camera_info_topic) const;

  // A new episode whose first stamp is first_stamp_ns: acknowledgements and answers of earlier episodes are
  // forgotten, commands stamped before it become stale, and any wait in progress is dropped (not a timeout).
  void BeginEpisode(uint64_t first_stamp_ns);

  // Inputs. OnCommand: any command, accepted or rejected by validation, answers its stamp's odometry. OnAck:
  // the newest stamp per consumer counts (duplicates and late acks of older frames change nothing; a
  // consumer not in the config is remembered but never waited for).
  CommandVerdict OnCommand(uint64_t stamp_ns);
  void OnAck(const std::string& consumer, uint64_t stamp_ns);

  // True once a command of this episode has answered (an unstamped command clears it, as it answers
  // nothing).
  bool answered_this_episode() const { return last_answer_ns_ != 0; }
  bool CommandAnswered(uint64_t stamp_ns) const { return last_answer_ns_ == stamp_ns; }
  bool FrameAcknowledged(uint64_t stamp_ns) const { return MissingAcks(stamp_ns).empty(); }
  // Consumers (in config order) without an acknowledgement of stamp_ns or later.
  std::vector<std::string> MissingAcks(uint64_t stamp_ns) const;

  // Start a wait (replacing any other): for the command stamped stamp_ns (no-op release without
  // wait_for_command), or for every consumer's ack of the frame stamped stamp_ns (no-op without consumers).
  // A command wait with no answer yet this episode resends every first_command_resend_period_s.
  void AwaitCommand(uint64_t stamp_ns, double wall_now_s);
  void AwaitFrame(uint64_t stamp_ns, double wall_now_s);
  // What to do now about the current wait. kRelease and kTimeout end it.
  Decision Poll(double wall_now_s);
  // Ends the current wait without counting a timeout (a reset or a shutdown interrupted it).
  void Abandon() { wait_ = Wait::kNone; }
  bool waiting() const { return wait_ != Wait::kNone; }

  uint64_t command_timeouts() const { return command_timeouts_; }
  uint64_t ack_timeouts() const { return ack_timeouts_; }
  uint64_t resends() const { return resends_; }

 private:
  enum class Wait { kNone, kCommand, kFrame };

  LockstepGateConfig config_;
  uint64_t episode_start_ns_ = 0;
  uint64_t last_answer_ns_ = 0;
  std::map<std::string, uint64_t> acked_ns_;  // newest acknowledged stamp per consumer

  Wait wait_ = Wait::kNone;
  uint64_t wait_stamp_ns_ = 0;
  double deadline_s_ = 0.0;
  bool resending_ = false;
  double next_resend_s_ = 0.0;

  uint64_t command_timeouts_ = 0;
  uint64_t ack_timeouts_ = 0;
  uint64_t resends_ = 0;
};

}  // namespace quad_core
