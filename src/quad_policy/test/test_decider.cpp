// The decider without a network file: its output is a test double flying straight at the goal it is asked
// about (world-frame B-spline, K = 10 over 2 s), so every branch of Decide(inputs, y, ask) is reached by
// constructed depth frames.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <vector>

#include "quad_policy/policy_decider.h"

namespace quad_policy {
namespace {

constexpr float kInf = std::numeric_limits<float>::infinity();
const Eigen::Vector3d kHover(0.0, 0.0, 1.5);

PolicyMeta Meta() {
  return ParsePolicyMeta(
      "{\"format\": \"quad_il_policy/1\", \"output\": {\"bspline_order\": 3, \"horizon_s\": 2.0, "
      "\"network_frame\": \"world\", \"network_representation\": \"bspline\", \"num_ctrl_pts\": 10}, "
      "\"preprocessing\": {\"input_height\": 8, \"input_width\": 8, \"max_depth_m\": 10.0, "
      "\"position_scale_m\": 10.0, \"state_frame\": \"world\", \"velocity_scale_mps\": 3.0}}",
      "meta");
}

// Straight from the vehicle at the goal at 1.5 m/s.
std::vector<float> Line(const Eigen::Vector3d& goal) {
  const Eigen::Vector3d d = (goal - kHover).normalized();
  std::vector<float> y;
  for (int i = 0; i < 10; ++i) {
    const Eigen::Vector3d c = kHover + 1.5 * (i - 1) * (2.0 / 7.0) * d;
    for (int j = 0; j < 3; ++j) y.push_back(static_cast<float>(c[j]));
  }
  return y;
}

// 80 x 60 camera 0.1 m ahead of the vehicle, looking along +x.
CameraModel Camera() {
  CameraModel c;
  c.intrinsics = quad_core::CameraIntrinsics{80, 60, 48.4, 48.4, 39.5, 29.5};
  Eigen::Matrix3d R;
  R << 0, 0, 1, -1, 0, 0, 0, -1, 0;
  c.T_world_camera.linear() = R;
  c.T_world_camera.translation() = kHover + Eigen::Vector3d(0.1, 0.0, 0.0);
  return c;
}

struct Scene {
  DepthImage depth;
  explicit Scene(float d = kInf) {
    depth.width = 80;
    depth.height = 60;
    depth.depth_m.assign(80 * 60, d);
  }
  Scene& Wall(int col0, int col1, float d) {
    for (int v = 0; v < 60; ++v) {
      for (int u = col0; u < col1; ++u) depth.depth_m[v * 80 + u] = d;
    }
    return *this;
  }
};

Decision DecideAt(PolicyDecider& decider, const Scene& scene, double stamp_s, const Eigen::Vector3d& goal,
                  int* asked = nullptr, const Eigen::Vector3d& v = Eigen::Vector3d::Zero()) {
  DecisionInputs in;
  in.stamp_s = stamp_s;
  in.depth = scene.depth.view();
  in.camera = Camera();
  in.state.p_world_body = kHover;
  in.state.v_world = v;
  in.goal_world = goal;
  return decider.Decide(in, Line(goal), [asked](const Eigen::Vector3d& g) {
    if (asked) ++*asked;
    return Line(g);
  });
}

SafetyConfig Safety() {
  SafetyConfig s;
  s.max_vel_mps = 4.5;
  s.max_acc_mps2 = 6.0;
  s.check_horizon_s = 1.0;
  return s;
}

const Eigen::Vector3d kGoal(10.0, 0.0, 1.5);

TEST(Decider, SendsAnAcceptedPlanAndStopsOnARefusalWithoutRecovery) {
  PolicyDecider d(Meta(), Safety(), RefusalConfig());
  const Decision free = DecideAt(d, Scene(), 1.0, kGoal);
  EXPECT_EQ(free.sent_kind(), SentKind::kPolicy);
  EXPECT_EQ(free.to_send(), &free.proposed);
  EXPECT_EQ(Summarize(free, 1, 1.0).action, "policy");
  const Decision wall = DecideAt(d, Scene(1.2f), 1.1, kGoal);
  EXPECT_EQ(wall.safety.verdict, SafetyVerdict::kCollisionInDepth);
  ASSERT_EQ(wall.sent_kind(), SentKind::kStop);
  EXPECT_EQ(wall.stop->num_ctrl_pts(), 4);
  EXPECT_EQ(Summarize(wall, 1, 1.1).action, "stop");
  EXPECT_EQ(d.counts()[SafetyVerdict::kAccepted], 1u);
  EXPECT_EQ(d.counts().refused(), 1u);
  RefusalConfig hover;
  hover.action = RefusalAction::kHover;
  PolicyDecider h(Meta(), Safety(), hover);
  const Decision held = DecideAt(h, Scene(1.2f), 1.0, kGoal);
  EXPECT_EQ(held.sent_kind(), SentKind::kNothing);
  EXPECT_EQ(held.to_send(), nullptr);
  EXPECT_EQ(Summarize(held, 1, 1.0).action, "hover");
}

TEST(Decider, TheRecoveryAsksTheNetworkForTurnedGoalsUntilAPlanPassesAndStaysInView) {
  RecoveryConfig r;
  r.goal_yaw_offsets_deg = {60.0, 10.0, 20.0, -20.0};  // 60: out of view; 10: still the wall; 20: clear
  PolicyDecider d(Meta(), Safety(), RefusalConfig(), r);
  int asked = 0;
  const Decision rec = DecideAt(d, Scene().Wall(35, 45, 1.2f), 1.0, kGoal, &asked);
  ASSERT_EQ(rec.sent_kind(), SentKind::kRecovery);
  EXPECT_EQ(asked, 3);
  EXPECT_EQ(rec.recovery_tries, 3);
  EXPECT_EQ(rec.recovery_yaw_deg, 20.0);
  const DecisionSummary s = Summarize(rec, 1, 1.0);
  EXPECT_EQ(s.action, "recovery");
  EXPECT_EQ(s.events, std::vector<std::string>{"recovered"});
  EXPECT_NE(s.reason.find("collision_in_depth"), std::string::npos);
  EXPECT_NE(s.reason.find("; recovered with the goal turned 20 deg"), std::string::npos);
  asked = 0;
  const Decision none = DecideAt(d, Scene(1.2f), 1.1, kGoal, &asked);
  EXPECT_EQ(none.sent_kind(), SentKind::kStop);
  EXPECT_EQ(asked, 4);
}

TEST(Decider, KeepsThePlanSentBeforeOnARefusalAndWhileCommitted) {
  KeepingConfig k;
  k.on_refusal = true;
  PolicyDecider d(Meta(), Safety(), RefusalConfig(), RecoveryConfig(), k);
  const Eigen::Vector3d turned(10.0 * std::cos(25.0 * M_PI / 180.0), 10.0 * std::sin(25.0 * M_PI / 180.0),
                               1.5);
  EXPECT_EQ(DecideAt(d, Scene(), 1.0, kGoal).sent_kind(), SentKind::kPolicy);
  const Decision kept = DecideAt(d, Scene().Wall(0, 25, 1.0f), 1.1, turned);
  ASSERT_EQ(kept.sent_kind(), SentKind::kKept);
  EXPECT_EQ(kept.to_send(), nullptr);
  EXPECT_NE(Summarize(kept, 1, 1.1).reason.find("; kept the plan sent 0.10 s before"), std::string::npos);
  EXPECT_EQ(DecideAt(d, Scene().Wall(0, 30, 1.0f), 1.2, turned).sent_kind(), SentKind::kStop);
  d.Reset();  // a new episode forgets the plan sent before
  EXPECT_EQ(DecideAt(d, Scene().Wall(0, 25, 1.0f), 1.3, turned).sent_kind(), SentKind::kStop);

  KeepingConfig c;
  c.commit_s = 0.25;
  PolicyDecider committed(Meta(), Safety(), RefusalConfig(), RecoveryConfig(), c);
  std::vector<SentKind> kinds;
  for (int i = 0; i < 4; ++i) kinds.push_back(DecideAt(committed, Scene(), 1.0 + 0.1 * i, kGoal).sent_kind());
  EXPECT_EQ(kinds, (std::vector<SentKind>{SentKind::kPolicy, SentKind::kCommitted, SentKind::kCommitted,
                                          SentKind::kPolicy}));
}

TEST(Decider, FliesTheFinalApproachNearTheGoalWhenItIsClear) {
  RecoveryConfig r;
  r.final_approach_m = 1.5;
  PolicyDecider d(Meta(), Safety(), RefusalConfig(), r);
  const Eigen::Vector3d near(1.2, 0.0, 1.5);
  const Eigen::Vector3d v(1.0, 0.2, -0.1);
  const Decision fa = DecideAt(d, Scene(), 1.0, near, nullptr, v);
  ASSERT_EQ(fa.sent_kind(), SentKind::kFinalApproach);
  EXPECT_TRUE(fa.final_approach->Position(fa.final_approach->duration_s()).isApprox(near, 1e-9));
  EXPECT_EQ(Summarize(fa, 1, 1.0).action, "final_approach");
  EXPECT_EQ(DecideAt(d, Scene().Wall(30, 50, 0.9f), 1.1, near, nullptr, v).sent_kind(), SentKind::kStop);
  EXPECT_EQ(DecideAt(d, Scene(), 1.2, Eigen::Vector3d(1.8, 0.0, 1.5)).sent_kind(), SentKind::kPolicy);
}

TEST(Decider, BadInputsAreRefusedNamingTheProblem) {
  PolicyDecider d(Meta(), Safety(), RefusalConfig());
  DecisionInputs in;
  const Scene scene;
  in.depth = scene.depth.view();
  in.camera = Camera();
  in.state.p_world_body = kHover;
  in.goal_world = kGoal;
  const auto ask = [](const Eigen::Vector3d& g) { return Line(g); };
  const auto error = [&](const DecisionInputs& x, const std::vector<float>& y) {
    try {
      d.Decide(x, y, ask);
    } catch (const std::invalid_argument& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_EQ(error(in, std::vector<float>(29, 0.0f)), "network output has 29 values, the policy declares 30");
  DecisionInputs bad = in;
  bad.state.v_world.y() = std::nan("");
  EXPECT_EQ(error(bad, Line(kGoal)), "v_world has a NaN/Inf element");
  bad = in;
  bad.stamp_s = std::nan("");
  EXPECT_EQ(error(bad, Line(kGoal)), "depth stamp is not finite");
  bad = in;
  bad.depth = DepthImageView{};
  EXPECT_EQ(error(bad, Line(kGoal)), "depth image is empty");
  EXPECT_THROW(d.policy(), std::logic_error);  // no TorchPolicy: Decide(inputs) is not available
}

}  // namespace
}  // namespace quad_policy
