// The lockstep gate (quad_core/lockstep_gate.h) without ROS: the per-frame waits (acks in and out of order,
// duplicates, stale acks and commands, timeouts counted, the first odometry resent, episodes) and the
// start-up barrier (the situations of issue 30's stalls, each of which let the simulator start stepping
// before a consumer could get the episode's first messages).
#include "quad_core/lockstep_gate.h"

#include <gtest/gtest.h>

#include <stdexcept>

namespace quad_core {
namespace {

using Action = LockstepGate::Action;

constexpr uint64_t kMs = 1000000;     // ns
constexpr uint64_t kT0 = 1000 * kMs;  // the first stamp of a run (sim time 1 s)

LockstepGateConfig GateConfig() {
  LockstepGateConfig c;
  c.depth_consumers = {"fast_planner", "episode_manager"};
  c.wait_for_command = true;
  c.timeout_s = 2.0;
  c.first_command_resend_period_s = 0.5;
  return c;
}

TEST(LockstepGate, FrameIsReleasedOnlyWhenEveryConsumerAcknowledgedIt) {
  LockstepGate g(GateConfig());
  g.BeginEpisode(kT0);
  g.AwaitFrame(kT0 + 5 * kMs, 10.0);
  EXPECT_EQ(g.Poll(10.0).action, Action::kWait);
  g.OnAck("fast_planner", kT0 + 5 * kMs);
  const LockstepGate::Decision d = g.Poll(10.1);
  EXPECT_EQ(d.action, Action::kWait);
  EXPECT_DOUBLE_EQ(d.wake_at_s, 12.0);  // the deadline: frame waits never resend
  EXPECT_EQ(g.MissingAcks(kT0 + 5 * kMs), std::vector<std::string>{"episode_manager"});
  g.OnAck("episode_manager", kT0 + 5 * kMs);
  EXPECT_EQ(g.Poll(10.2).action, Action::kRelease);
  EXPECT_FALSE(g.waiting());
  EXPECT_EQ(g.ack_timeouts(), 0u);
}

TEST(LockstepGate, AcksArrivingOutOfOrderAndTwiceKeepTheNewestStamp) {
  LockstepGate g(GateConfig());
  g.BeginEpisode(kT0);
  g.OnAck("fast_planner", kT0 + 66 * kMs);
  g.OnAck("fast_planner", kT0 + 33 * kMs);  // late ack of an older frame: does not step back
  g.OnAck("fast_planner", kT0 + 33 * kMs);  // duplicate
  g.OnAck("episode_manager", kT0 + 66 * kMs);
  EXPECT_TRUE(g.FrameAcknowledged(kT0 + 66 * kMs));
  EXPECT_TRUE(g.FrameAcknowledged(kT0 + 33 * kMs));  // a newer ack covers an older frame
  EXPECT_FALSE(g.FrameAcknowledged(kT0 + 99 * kMs));
}

TEST(LockstepGate, AnAckOfAnOldFrameDoesNotReleaseTheCurrentOne) {
  LockstepGate g(GateConfig());
  g.BeginEpisode(kT0);
  g.AwaitFrame(kT0 + 66 * kMs, 0.0);
  g.OnAck("fast_planner", kT0 + 33 * kMs);
  g.OnAck("episode_manager", kT0 + 33 * kMs);
  EXPECT_EQ(g.Poll(0.5).action, Action::kWait);
  EXPECT_EQ(g.MissingAcks(kT0 + 66 * kMs).size(), 2u);
}

TEST(LockstepGate, AnUnknownConsumerIsNeverWaitedFor) {
  LockstepGate g(GateConfig());
  g.BeginEpisode(kT0);
  g.AwaitFrame(kT0, 0.0);
  g.OnAck("rviz_tool", kT0);
  EXPECT_EQ(g.Poll(0.1).action, Action::kWait);
  g.OnAck("fast_planner", kT0);
  g.OnAck("episode_manager", kT0);
  EXPECT_EQ(g.Poll(0.2).action, Action::kRelease);
}

TEST(LockstepGate, FrameTimeoutIsCountedAndNamesTheMissingConsumers) {
  LockstepGate g(GateConfig());
  g.BeginEpisode(kT0);
  g.AwaitFrame(kT0 + 500 * kMs, 3.0);
  g.OnAck("episode_manager", kT0 + 500 * kMs);
  EXPECT_EQ(g.Poll(4.99).action, Action::kWait);
  const LockstepGate::Decision d = g.Poll(5.0);
  EXPECT_EQ(d.action, Action::kTimeout);
  EXPECT_EQ(d.message,
            "depth frame 1.500 not acknowledged by [fast_planner] within 2.00 s (ack timeouts so far: 1)");
  EXPECT_EQ(g.ack_timeouts(), 1u);
  EXPECT_EQ(g.command_timeouts(), 0u);
  EXPECT_FALSE(g.waiting());
  // The next frame waits afresh; a second timeout counts again.
  g.AwaitFrame(kT0 + 533 * kMs, 5.0);
  EXPECT_EQ(g.Poll(7.5).action, Action::kTimeout);
  EXPECT_EQ(g.ack_timeouts(), 2u);
}

TEST(LockstepGate, AnswersArrivingAtTheDeadlineStillRelease) {
  LockstepGate g(GateConfig());
  g.BeginEpisode(kT0);
  g.AwaitFrame(kT0, 0.0);
  g.OnAck("fast_planner", kT0);
  g.OnAck("episode_manager", kT0);
  EXPECT_EQ(g.Poll(100.0).action, Action::kRelease);
  EXPECT_EQ(g.ack_timeouts(), 0u);
}

TEST(LockstepGate, CommandWaitReleasesOnlyOnTheExactStamp) {
  LockstepGate g(GateConfig());
  g.BeginEpisode(kT0);
  EXPECT_EQ(g.OnCommand(kT0), LockstepGate::CommandVerdict::kCurrent);
  ASSERT_TRUE(g.answered_this_episode());
  g.AwaitCommand(kT0 + 5 * kMs, 0.0);
  EXPECT_EQ(g.Poll(0.1).action, Action::kWait);  // the answer of the previous period
  g.OnCommand(kT0 + 5 * kMs);
  EXPECT_EQ(g.Poll(0.2).action, Action::kRelease);
}

TEST(LockstepGate, CommandTimeoutIsCountedWithoutResendOnceAnswered) {
  LockstepGate g(GateConfig());
  g.BeginEpisode(kT0);
  g.OnCommand(kT0);
  g.AwaitCommand(kT0 + 5 * kMs, 10.0);
  const LockstepGate::Decision w = g.Poll(10.6);
  EXPECT_EQ(w.action, Action::kWait);  // answered this episode: no resend
  EXPECT_DOUBLE_EQ(w.wake_at_s, 12.0);
  const LockstepGate::Decision d = g.Poll(12.0);
  EXPECT_EQ(d.action, Action::kTimeout);
  EXPECT_EQ(d.message, "no command stamped 1.005 within 2.00 s (command timeouts so far: 1)");
  EXPECT_EQ(g.command_timeouts(), 1u);
  EXPECT_EQ(g.resends(), 0u);
}

// The episode's first odometry may reach nobody (the command source still connecting): it is sent again
// every resend period until the first command, within the timeout.
TEST(LockstepGate, TheEpisodesFirstOdometryIsResentUntilAnswered) {
  LockstepGate g(GateConfig());
  g.BeginEpisode(kT0);
  g.AwaitCommand(kT0, 0.0);
  LockstepGate::Decision d = g.Poll(0.0);
  EXPECT_EQ(d.action, Action::kWait);
  EXPECT_DOUBLE_EQ(d.wake_at_s, 0.5);
  EXPECT_EQ(g.Poll(0.5).action, Action::kResend);
  d = g.Poll(0.5);
  EXPECT_EQ(d.action, Action::kWait);
  EXPECT_DOUBLE_EQ(d.wake_at_s, 1.0);
  EXPECT_EQ(g.Poll(1.0).action, Action::kResend);
  g.OnCommand(kT0);
  EXPECT_EQ(g.Poll(1.2).action, Action::kRelease);
  EXPECT_EQ(g.resends(), 2u);
  EXPECT_EQ(g.command_timeouts(), 0u);
}

TEST(LockstepGate, UnansweredFirstOdometryIsResentThreeTimesThenTimesOut) {
  LockstepGate g(GateConfig());  // 2 s timeout, 0.5 s period: resends at 0.5, 1.0, 1.5
  g.BeginEpisode(kT0);
  g.AwaitCommand(kT0, 0.0);
  int resends = 0;
  double t = 0.0;
  for (int i = 0; i < 100; ++i) {
    const LockstepGate::Decision d = g.Poll(t);
    if (d.action == Action::kTimeout) break;
    if (d.action == Action::kResend) ++resends;
    if (d.action == Action::kWait) t = d.wake_at_s;
  }
  EXPECT_EQ(resends, 3);
  EXPECT_DOUBLE_EQ(t, 2.0);
  EXPECT_EQ(g.command_timeouts(), 1u);
}

TEST(LockstepGate, CommandsOfThePreviousEpisodeAreStale) {
  LockstepGate g(GateConfig());
  g.BeginEpisode(kT0);
  g.OnCommand(kT0 + 100 * kMs);
  g.BeginEpisode(kT0 + 205 * kMs);
  EXPECT_FALSE(g.answered_this_episode());
  EXPECT_EQ(g.OnCommand(kT0 + 200 * kMs), LockstepGate::CommandVerdict::kStale);
  EXPECT_FALSE(g.answered_this_episode());
  EXPECT_EQ(g.OnCommand(0), LockstepGate::CommandVerdict::kCurrent);  // unstamped: applied, answers nothing
  EXPECT_FALSE(g.answered_this_episode());
  EXPECT_EQ(g.OnCommand(kT0 + 205 * kMs), LockstepGate::CommandVerdict::kCurrent);
  EXPECT_TRUE(g.CommandAnswered(kT0 + 205 * kMs));
}

TEST(LockstepGate, ANewEpisodeForgetsAcksAndDropsTheWaitWithoutATimeout) {
  LockstepGate g(GateConfig());
  g.BeginEpisode(kT0);
  g.OnAck("fast_planner", kT0 + 900 * kMs);
  g.OnAck("episode_manager", kT0 + 900 * kMs);
  g.AwaitFrame(kT0 + 933 * kMs, 0.0);
  g.BeginEpisode(kT0 + 1000 * kMs);
  EXPECT_FALSE(g.waiting());
  EXPECT_EQ(g.Poll(50.0).action, Action::kRelease);
  EXPECT_EQ(g.ack_timeouts(), 0u);
  EXPECT_EQ(g.MissingAcks(kT0 + 1000 * kMs).size(), 2u);  // earlier acks do not carry over
  // A reset interrupting a wait ends it without a timeout as well.
  g.AwaitFrame(kT0 + 1000 * kMs, 50.0);
  g.Abandon();
  EXPECT_EQ(g.Poll(100.0).action, Action::kRelease);
  EXPECT_EQ(g.ack_timeouts(), 0u);
}

TEST(LockstepGate, WithoutParticipantsNothingIsAwaited) {
  LockstepGateConfig c;
  c.wait_for_command = false;
  LockstepGate g(c);
  EXPECT_FALSE(g.needs_peers());
  g.BeginEpisode(kT0);
  g.AwaitCommand(kT0, 0.0);
  EXPECT_EQ(g.Poll(0.0).action, Action::kRelease);
  g.AwaitFrame(kT0, 0.0);
  EXPECT_EQ(g.Poll(0.0).action, Action::kRelease);
  EXPECT_EQ(g.command_timeouts() + g.ack_timeouts(), 0u);
}

TEST(LockstepGate, BadConfigIsRefusedNamingTheField) {
  LockstepGateConfig c = GateConfig();
  c.timeout_s = 0.0;
  EXPECT_THROW(
      {
        try {
          LockstepGate g(c);
        } catch (const std::invalid_argument& e) {
          EXPECT_NE(std::string(e.what()).find("timeout_s"), std::string::npos) << e.what();
          throw;
        }
      },
      std::invalid_argument);
  c = GateConfig();
  c.depth_consumers = {"fast_planner", "fast_planner"};
  EXPECT_THROW(LockstepGate g(c), std::invalid_argument);
  c.depth_consumers = {""};
  EXPECT_THROW(LockstepGate g(c), std::invalid_argument);
  c = GateConfig();
  c.first_command_resend_period_s = -1.0;
  EXPECT_THROW(LockstepGate g(c), std::invalid_argument);
}

// ---- the start-up barrier ----
const char* kOdom = "/odom";
const char* kDepth = "/camera/depth/image";
const char* kInfo = "/camera/depth/camera_info";
const char* kClock = "/clock";

LockstepNeeds EvalNeeds() {
  LockstepNeeds n;
  n.odom_topic = kOdom;
  n.image_topic = kDepth;
  n.frame_topics = {kDepth, kInfo};
  n.num_depth_consumers = 2;  // the planner and the evaluation's runner
  n.wait_for_command = true;
  return n;
}

// The evaluation's start-up with everything connected: tracker (commands), planner and runner (consumers).
LockstepPeers AllConnected() {
  LockstepPeers p;
  p.ack_publishers = {"/fast_planner", "/eval_runner"};
  p.ack_publishers_delivering = p.ack_publishers;
  p.command_publishers = {"/kr_tracker"};
  p.command_publishers_connected = 1;
  p.registered_subscribers[kOdom] = {"/kr_tracker", "/fast_planner", "/eval_runner"};
  p.registered_subscribers[kDepth] = {"/fast_planner"};
  p.registered_subscribers[kInfo] = {"/fast_planner", "/eval_runner"};
  p.registered_subscribers[kClock] = {"/kr_tracker", "/fast_planner", "/eval_runner", "/rosout"};
  p.connected_subscribers = p.registered_subscribers;
  return p;
}

TEST(LockstepPeers, ReadyWhenEveryParticipantIsConnected) {
  const LockstepPeerCheck c = CheckLockstepPeers(AllConnected(), EvalNeeds());
  EXPECT_TRUE(c.ready) << c.missing;
  EXPECT_EQ(c.missing, "");
}

// The stall of issue 30: the tracker's (and the runner's) odometry connection satisfied "one odometry
// subscriber", the planner's own was still being set up, and the first frame's odometry never reached it.
TEST(LockstepPeers, WaitsForAConsumersOdometryConnectionWhenAnotherNodeIsConnected) {
  LockstepPeers p = AllConnected();
  p.connected_subscribers[kOdom].erase("/fast_planner");
  const LockstepPeerCheck c = CheckLockstepPeers(p, EvalNeeds());
  EXPECT_FALSE(c.ready);
  EXPECT_NE(c.missing.find("/fast_planner registered for /odom but not yet connected"), std::string::npos)
      << c.missing;
}

// The mirror race: the simulator's side of the FrameAck connection exists, the planner has not accepted it
// yet, and its first acknowledgement would be lost.
TEST(LockstepPeers, WaitsUntilEachAckPublisherDeliversToTheSimulator) {
  LockstepPeers p = AllConnected();
  p.ack_publishers_delivering.erase("/fast_planner");
  const LockstepPeerCheck c = CheckLockstepPeers(p, EvalNeeds());
  EXPECT_FALSE(c.ready);
  EXPECT_NE(c.missing.find("/fast_planner's FrameAck publisher"), std::string::npos) << c.missing;
}

// A consumer whose FrameAck publisher is up before its frame subscription: it must get the first frame.
TEST(LockstepPeers, WaitsForEachConsumersFrameSubscription) {
  LockstepPeers p = AllConnected();
  p.registered_subscribers[kInfo].erase("/eval_runner");  // not even registered yet
  p.connected_subscribers[kInfo].erase("/eval_runner");
  const LockstepPeerCheck c = CheckLockstepPeers(p, EvalNeeds());
  EXPECT_FALSE(c.ready);
  EXPECT_NE(c.missing.find("/eval_runner not yet connected to the depth frames"), std::string::npos)
      << c.missing;
}

// The Python policy node subscribes to camera_info at once but to images only once its FrameAck publisher is
// connected: its camera_info connection must not let the simulator send the first image to nobody.
TEST(LockstepPeers, WaitsForADepthImageSubscriber) {
  LockstepNeeds n = EvalNeeds();
  n.num_depth_consumers = 1;
  LockstepPeers p = AllConnected();
  p.ack_publishers = {"/policy_node"};
  p.ack_publishers_delivering = p.ack_publishers;
  p.registered_subscribers = {{kOdom, {"/kr_tracker", "/policy_node"}}, {kInfo, {"/policy_node"}}};
  p.connected_subscribers = p.registered_subscribers;
  LockstepPeerCheck c = CheckLockstepPeers(p, n);
  EXPECT_FALSE(c.ready);
  EXPECT_NE(c.missing.find("no depth image subscriber connected"), std::string::npos) << c.missing;
  p.connected_subscribers[kDepth] = {"/policy_node"};
  c = CheckLockstepPeers(p, n);
  EXPECT_TRUE(c.ready) << c.missing;
}

TEST(LockstepPeers, WaitsForAsManyAckPublishersAsConsumers) {
  LockstepPeers p = AllConnected();
  p.ack_publishers.erase("/eval_runner");  // the runner has not started yet
  p.registered_subscribers[kOdom].erase("/eval_runner");
  p.connected_subscribers[kOdom].erase("/eval_runner");
  const LockstepPeerCheck c = CheckLockstepPeers(p, EvalNeeds());
  EXPECT_FALSE(c.ready);
  EXPECT_NE(c.missing.find("1 of 2 FrameAck publishers registered"), std::string::npos) << c.missing;
}

TEST(LockstepPeers, WaitsForTheClockOfAParticipant) {
  LockstepPeers p = AllConnected();
  p.connected_subscribers[kClock].erase("/kr_tracker");
  const LockstepPeerCheck c = CheckLockstepPeers(p, EvalNeeds());
  EXPECT_FALSE(c.ready);
  EXPECT_NE(c.missing.find("/kr_tracker registered for /clock"), std::string::npos) << c.missing;
}

// Bystanders (rviz, rostopic, a dead node still registered with the master) never hold the simulator.
TEST(LockstepPeers, IgnoresNodesThatTakeNoPartInLockstep) {
  LockstepPeers p = AllConnected();
  p.registered_subscribers[kOdom].insert("/rostopic_123");
  p.registered_subscribers[kDepth].insert("/rviz");
  const LockstepPeerCheck c = CheckLockstepPeers(p, EvalNeeds());
  EXPECT_TRUE(c.ready) << c.missing;
}

TEST(LockstepPeers, CommandWaitNeedsACommandPublisherAndAnOdometrySubscriber) {
  LockstepNeeds n = EvalNeeds();
  n.num_depth_consumers = 0;
  LockstepPeers p;
  LockstepPeerCheck c = CheckLockstepPeers(p, n);
  EXPECT_FALSE(c.ready);
  EXPECT_NE(c.missing.find("no command publisher connected"), std::string::npos) << c.missing;
  EXPECT_NE(c.missing.find("no odometry subscriber connected"), std::string::npos) << c.missing;
  p.command_publishers = {"/kr_tracker"};
  p.command_publishers_connected = 1;
  p.connected_subscribers[kOdom] = {"/kr_tracker"};
  c = CheckLockstepPeers(p, n);
  EXPECT_TRUE(c.ready) << c.missing;
}

// A participant that joins after the episode's first check (a respawned tracker, a runner started late) is
// waited for as soon as it registers, and releases the barrier once connected.
TEST(LockstepPeers, AParticipantJoiningLaterIsWaitedForUntilConnected) {
  LockstepNeeds n = EvalNeeds();
  n.num_depth_consumers = 1;
  LockstepPeers p = AllConnected();
  p.ack_publishers = {"/fast_planner"};
  p.ack_publishers_delivering = p.ack_publishers;
  ASSERT_TRUE(CheckLockstepPeers(p, n).ready);
  p.command_publishers.insert("/kr_tracker_2");
  p.registered_subscribers[kOdom].insert("/kr_tracker_2");
  LockstepPeerCheck c = CheckLockstepPeers(p, n);
  EXPECT_FALSE(c.ready);
  EXPECT_NE(c.missing.find("/kr_tracker_2 registered for /odom but not yet connected"), std::string::npos)
      << c.missing;
  p.connected_subscribers[kOdom].insert("/kr_tracker_2");
  c = CheckLockstepPeers(p, n);
  EXPECT_TRUE(c.ready) << c.missing;
}

}  // namespace
}  // namespace quad_core
