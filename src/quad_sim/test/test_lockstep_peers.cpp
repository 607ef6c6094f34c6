// The lockstep start-up barrier (quad_sim/lockstep_peers.h): the situations of issue 30's stalls, each of
// which let the simulator start stepping before a consumer could get the episode's first messages.
#include "quad_sim/lockstep_peers.h"

#include <gtest/gtest.h>

namespace quad_sim {
namespace {

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

}  // namespace
}  // namespace quad_sim
