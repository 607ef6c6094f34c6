// TrackerManager: start-up anchoring and re-anchoring on episode resets and odometry jumps. The vehicle is
// simulated as following its reference exactly (odometry = the previous reference), so every reference and
// command can be checked against where the vehicle is.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include "kr_tracker/tracker_manager.h"

namespace kr_tracker {
namespace {

constexpr double kDt = 0.005;
constexpr double kMass = 1.0;
constexpr double kG = 9.81;
constexpr double kMaxThrust = 30.0;

quad_core::VehicleState Odom(double t, const Eigen::Vector3d& p, double yaw = 0.0,
                             const Eigen::Vector3d& v = Eigen::Vector3d::Zero()) {
  quad_core::VehicleState s;
  s.t_s = t;
  s.p_world_body = p;
  s.v_world = v;
  s.q_world_body = Eigen::Quaterniond(Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()));
  return s;
}

// A uniform cubic straight line from a to b (tripled end points: at rest at both ends), `duration_s` long.
BsplineGoalSpec Line(const Eigen::Vector3d& a, const Eigen::Vector3d& b, double t0, double duration_s) {
  const int n_inner = 8;
  BsplineGoalSpec g;
  g.order = 3;
  g.traj_id = 3;
  g.start_time_s = t0;
  const int n = n_inner + 4;
  const double dt = duration_s / (n - 3);
  g.pos_pts.resize(n, 3);
  for (int i = 0; i < n; ++i) {
    const double u = std::clamp((i - 1.0) / (n - 3.0), 0.0, 1.0);
    g.pos_pts.row(i) = (a + u * (b - a)).transpose();
  }
  for (int i = 0; i < n + 4; ++i) g.knots.push_back(t0 + dt * (i - 3));
  return g;
}

// Drives the manager with odometry that follows the reference; returns the last step.
class Flight {
 public:
  explicit Flight(TrackerManager* m) : m_(m) {}
  ControlStep Start(double t, const Eigen::Vector3d& p, double yaw = 0.0) {
    t_ = t;
    p_ = p;
    yaw_ = yaw;
    v_.setZero();
    return Step();
  }
  ControlStep Step() {
    last_ = m_->OnOdometry(Odom(t_, p_, yaw_, v_));
    p_ = last_.ref.p_world;
    v_ = last_.ref.v_world;
    yaw_ = last_.ref.yaw_rad;
    t_ += kDt;
    return last_;
  }
  ControlStep Run(double seconds) {
    for (double end = t_ + seconds - 0.5 * kDt; t_ < end;) Step();
    return last_;
  }
  // The simulator's reset: the vehicle is somewhere else, at rest, from the next odometry on.
  void Teleport(const Eigen::Vector3d& p, double yaw) {
    p_ = p;
    yaw_ = yaw;
    v_.setZero();
  }
  double t() const { return t_; }
  const Eigen::Vector3d& p() const { return p_; }

 private:
  TrackerManager* m_;
  double t_ = 0.0;
  Eigen::Vector3d p_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d v_ = Eigen::Vector3d::Zero();
  double yaw_ = 0.0;
  ControlStep last_;
};

// No horizontal force: nothing pulls the vehicle anywhere (e.g. back to the previous episode's position).
bool HorizontalForceIsZero(const So3Command& c) { return c.force_world_N.head<2>().norm() < 1e-9; }

std::vector<GoalEvent> Aborted(TrackerManager* m) {
  std::vector<GoalEvent> out;
  for (const GoalEvent& e : m->TakeEvents()) {
    if (e.kind == GoalEventKind::kAborted) out.push_back(e);
  }
  return out;
}

class TrackerManagerTest : public ::testing::Test {
 protected:
  TrackerManagerTest() : m_(TrackerConfig{}, kMass, kG, kMaxThrust), f_(&m_) {}

  // Start-up at old_ on episode 1, take off to 2 m above it and start a B-spline goal 6 m along +y; returns
  // with the goal running half way.
  void FlyInEpisodeOne() {
    f_.Start(1.0, old_);
    EXPECT_EQ(m_.OnEpisodeStatus(1, 1.0), "");
    ASSERT_EQ(m_.Goto(old_ + Eigen::Vector3d(0, 0, 2), 0.0, 0.0, 0.0), "");
    f_.Run(6.0);
    ASSERT_LT((f_.p() - (old_ + Eigen::Vector3d(0, 0, 2))).norm(), 1e-6);
    const Eigen::Vector3d a = f_.p();
    ASSERT_EQ(m_.AddGoal(1, Line(a, a + Eigen::Vector3d(0, 6, 0), f_.t(), 6.0), f_.t()), "");
    f_.Run(3.0);
    ASSERT_TRUE(m_.bspline().running_goal().has_value());
    ASSERT_GT(m_.last_ref().v_world.norm(), 0.5);
    m_.TakeEvents();
  }

  TrackerManager m_;
  Flight f_;
  const Eigen::Vector3d old_{0.0, 0.0, 0.125};
  const Eigen::Vector3d new_start_{8.0, -5.0, 0.125};  // on the ground
  const double new_yaw_ = 1.2;
};

TEST_F(TrackerManagerTest, StartUpHoldsTheFirstOdometryPoseWithWeightCompensatingThrust) {
  EXPECT_FALSE(m_.have_odom());
  EXPECT_EQ(m_.Goto(Eigen::Vector3d(1, 1, 1), 0.0, 0.0, 0.0), "no odometry received yet");
  const ControlStep s = f_.Start(1.0, Eigen::Vector3d(2, 3, 0.125), 0.7);
  EXPECT_TRUE(s.reanchored.empty());
  EXPECT_EQ(m_.active_tracker(), "hover");
  EXPECT_TRUE(s.ref.p_world.isApprox(Eigen::Vector3d(2, 3, 0.125)));
  EXPECT_NEAR(s.ref.yaw_rad, 0.7, 1e-12);
  EXPECT_TRUE(HorizontalForceIsZero(s.command));
  EXPECT_NEAR(s.command.force_world_N.z(), kMass * kG, 1e-9);
  EXPECT_TRUE(s.command.enable_motors);
  EXPECT_EQ(m_.reanchor_count(), 0);
}

TEST_F(TrackerManagerTest, NewEpisodeAbortsTheGoalAndReAnchorsOnTheFirstOdometryOfTheNewEpisode) {
  FlyInEpisodeOne();
  const Eigen::Vector3d before = m_.last_ref().p_world;
  const double t_start = f_.t() + kDt;  // the new episode's first odometry: one period after the last

  // The status arrives before the new episode's odometry: the goal is aborted at once ...
  EXPECT_NE(m_.OnEpisodeStatus(2, t_start), "");
  const auto aborted = Aborted(&m_);
  ASSERT_EQ(aborted.size(), 1u);
  EXPECT_EQ(aborted[0].goal_id, 1u);
  EXPECT_NE(aborted[0].reason.find("episode reset"), std::string::npos) << aborted[0].reason;
  EXPECT_TRUE(m_.reset_pending());
  // ... and an odometry of the old episode still in flight does not re-anchor.
  EXPECT_TRUE(f_.Step().reanchored.empty());

  // The first odometry of the new episode (vehicle on the ground elsewhere) re-anchors there.
  f_.Teleport(new_start_, new_yaw_);
  const ControlStep s = f_.Step();
  EXPECT_NE(s.reanchored.find("episode reset"), std::string::npos) << s.reanchored;
  EXPECT_FALSE(m_.reset_pending());
  EXPECT_EQ(m_.reanchor_count(), 1);
  EXPECT_EQ(m_.active_tracker(), "hover");
  EXPECT_TRUE(s.ref.p_world.isApprox(new_start_)) << s.ref.p_world.transpose();
  EXPECT_NEAR(s.ref.yaw_rad, new_yaw_, 1e-12);
  EXPECT_EQ(s.ref.v_world.norm(), 0.0);
  // As at start-up: weight-compensating thrust, nothing pulling back towards the previous episode.
  EXPECT_TRUE(HorizontalForceIsZero(s.command)) << s.command.force_world_N.transpose();
  EXPECT_NEAR(s.command.force_world_N.z(), kMass * kG, 1e-9);
  // And it stays there.
  f_.Run(2.0);
  EXPECT_LT((f_.p() - new_start_).norm(), 1e-9);
  EXPECT_GT((before - new_start_).norm(), 5.0);
  EXPECT_TRUE(Aborted(&m_).empty());
}

bool SameBits(const ControlStep& a, const ControlStep& b) {
  const So3Command &x = a.command, &y = b.command;
  const PositionReference &r = a.ref, &q = b.ref;
  return x.force_world_N == y.force_world_N && x.q_world_des.coeffs() == y.q_world_des.coeffs() &&
         x.w_body_des_radps == y.w_body_des_radps && x.kR == y.kR && x.kOm == y.kOm &&
         x.enable_motors == y.enable_motors && r.p_world == q.p_world && r.v_world == q.v_world &&
         r.a_world == q.a_world && r.j_world == q.j_world && r.yaw_rad == q.yaw_rad &&
         r.yaw_rate_radps == q.yaw_rate_radps && a.status == b.status;
}

// Keyed episodes (issue 32): collect.launch keeps the tracker across episodes, so an episode's commands must
// not depend on the episodes flown before it. A manager that flew an episode (goto, B-spline goal running)
// and then gets a new episode's status and odometry answers with bit-identical commands and references to a
// fresh manager given the same status (its first) and odometry, through a goto and a B-spline goal.
TEST_F(TrackerManagerTest, ANewEpisodeIsFlownBitIdenticallyToAFreshManagersFirstEpisode) {
  FlyInEpisodeOne();
  const double t0 = 2001.0;  // the keyed episode's start, long after the previous one
  EXPECT_NE(m_.OnEpisodeStatus(2, t0), "");
  TrackerManager fresh(TrackerConfig{}, kMass, kG, kMaxThrust);
  EXPECT_EQ(fresh.OnEpisodeStatus(2, t0), "");
  Flight used(&m_), first(&fresh);
  int steps = 0;
  const auto fly = [&](double seconds) {
    for (double end = used.t() + seconds - 0.5 * kDt; used.t() < end; ++steps) {
      const ControlStep a = used.Step(), b = first.Step();
      ASSERT_TRUE(SameBits(a, b)) << "step " << steps << " at t = " << used.t() << ": ref "
                                  << a.ref.p_world.transpose() << " vs " << b.ref.p_world.transpose();
    }
  };
  const ControlStep a = used.Start(t0, new_start_, new_yaw_), b = first.Start(t0, new_start_, new_yaw_);
  EXPECT_NE(a.reanchored, "");  // the used manager re-anchors, the fresh one anchors at start-up
  ASSERT_TRUE(SameBits(a, b));
  fly(0.5);
  const Eigen::Vector3d up = new_start_ + Eigen::Vector3d(0, 0, 1.5);
  ASSERT_EQ(m_.Goto(up, new_yaw_ + 0.4, 0.0, 0.0), "");
  ASSERT_EQ(fresh.Goto(up, new_yaw_ + 0.4, 0.0, 0.0), "");
  fly(5.0);
  ASSERT_LT((used.p() - up).norm(), 1e-3);
  const Eigen::Vector3d p = used.p();
  const BsplineGoalSpec goal = Line(p, p + Eigen::Vector3d(4, -3, 0.5), used.t() + 0.1, 5.0);
  ASSERT_EQ(m_.AddGoal(9, goal, used.t()), "");
  ASSERT_EQ(fresh.AddGoal(9, goal, first.t()), "");
  fly(7.0);
  EXPECT_EQ(m_.active_tracker(), "bspline");
  EXPECT_EQ(fresh.active_tracker(), "bspline");
  EXPECT_GT((used.p() - p).norm(), 4.5);  // the goal (5.02 m long) was flown
  EXPECT_EQ(m_.controller().integral_mps2(), fresh.controller().integral_mps2());
}

TEST_F(TrackerManagerTest, OdometryJumpAloneReAnchorsAndAbortsTheGoal) {
  FlyInEpisodeOne();
  // A step below the limit is ordinary motion.
  f_.Teleport(f_.p() + Eigen::Vector3d(0.5, 0, 0), 0.0);
  EXPECT_TRUE(f_.Step().reanchored.empty());
  EXPECT_TRUE(m_.bspline().running_goal().has_value());
  // No status (missed), but the vehicle is 9 m away from one odometry to the next.
  f_.Teleport(new_start_, new_yaw_);
  const double t_jump = f_.t();
  const ControlStep s = f_.Step();
  EXPECT_NE(s.reanchored.find("odometry jump"), std::string::npos) << s.reanchored;
  const auto aborted = Aborted(&m_);
  ASSERT_EQ(aborted.size(), 1u);
  EXPECT_NE(aborted[0].reason.find("odometry jump"), std::string::npos) << aborted[0].reason;
  EXPECT_TRUE(s.ref.p_world.isApprox(new_start_));
  EXPECT_NEAR(s.ref.yaw_rad, new_yaw_, 1e-12);
  EXPECT_TRUE(HorizontalForceIsZero(s.command));

  // A goto sent after the jump re-anchor survives the late status of the same episode.
  ASSERT_EQ(m_.Goto(new_start_ + Eigen::Vector3d(0, 0, 1.5), new_yaw_, 0.0, 0.0), "");
  f_.Step();
  const std::string what = m_.OnEpisodeStatus(2, t_jump);
  EXPECT_NE(what.find("already re-anchored"), std::string::npos) << what;
  EXPECT_EQ(m_.active_tracker(), "line");
  f_.Run(5.0);
  EXPECT_LT((f_.p() - (new_start_ + Eigen::Vector3d(0, 0, 1.5))).norm(), 1e-6);
}

TEST_F(TrackerManagerTest, StatusAfterTheNewOdometryReAnchorsAtOnce) {
  FlyInEpisodeOne();
  // The new start is close (below the jump limit) and its odometry arrives before the status.
  const Eigen::Vector3d near = f_.p() + Eigen::Vector3d(0.4, 0.3, 0.0);
  const double t_start = f_.t();
  f_.Teleport(near, 0.3);
  EXPECT_TRUE(f_.Step().reanchored.empty());
  const std::string what = m_.OnEpisodeStatus(2, t_start);
  EXPECT_NE(what.find("re-anchored at once"), std::string::npos) << what;
  EXPECT_FALSE(m_.reset_pending());
  EXPECT_EQ(Aborted(&m_).size(), 1u);
  EXPECT_TRUE(m_.last_ref().p_world.isApprox(near));
  EXPECT_NEAR(m_.last_ref().yaw_rad, 0.3, 1e-12);
  f_.Teleport(near, 0.3);  // the vehicle is still there (that step's command went towards the old reference)
  const ControlStep s = f_.Step();
  EXPECT_TRUE(s.ref.p_world.isApprox(near));
  EXPECT_TRUE(HorizontalForceIsZero(s.command));
}

TEST_F(TrackerManagerTest, GotoDuringTheResetIsFlownFromTheNewStart) {
  FlyInEpisodeOne();
  const Eigen::Vector3d old_pos = f_.p();
  ASSERT_NE(m_.OnEpisodeStatus(2, f_.t()), "");
  // The episode manager's take-off, sent before the new episode's odometry reached the tracker.
  const Eigen::Vector3d takeoff = new_start_ + Eigen::Vector3d(0, 0, 1.5);
  bool deferred = false;
  ASSERT_EQ(m_.Goto(takeoff, new_yaw_, 0.0, 0.0, &deferred), "");
  EXPECT_TRUE(deferred);
  EXPECT_EQ(m_.Goto(Eigen::Vector3d(std::nan(""), 0, 0), 0.0, 0.0, 0.0), "goal position is not finite");
  // B-spline goals cannot be checked against the vehicle's position yet.
  const std::string why = m_.AddGoal(5, Line(takeoff, takeoff, f_.t(), 2.0), f_.t());
  EXPECT_NE(why.find("episode reset (episode 2 started) in progress"), std::string::npos) << why;

  f_.Teleport(new_start_, new_yaw_);
  ControlStep s = f_.Step();
  EXPECT_FALSE(s.reanchored.empty());
  EXPECT_EQ(m_.active_tracker(), "line");
  EXPECT_TRUE(s.ref.p_world.isApprox(new_start_, 1e-9)) << s.ref.p_world.transpose();
  EXPECT_LT(s.ref.v_world.norm(), 1e-9);
  // Every reference of the take-off lies on the vertical segment above the new start.
  double worst = 0.0, lowest = 1e9;
  for (int i = 0; i < 2000; ++i) {
    s = f_.Step();
    worst = std::max(worst, (s.ref.p_world.head<2>() - new_start_.head<2>()).norm());
    lowest = std::min(lowest, s.ref.p_world.z());
  }
  EXPECT_LT(worst, 1e-9);  // the previous episode's position is > 9 m away horizontally
  EXPECT_GE(lowest, new_start_.z() - 1e-9);
  EXPECT_GT((old_pos - new_start_).head<2>().norm(), 9.0);
  EXPECT_EQ(m_.line().status(), TrackerStatus::kSucceeded);
  EXPECT_LT((f_.p() - takeoff).norm(), 1e-9);
  EXPECT_NEAR(s.ref.yaw_rad, new_yaw_, 1e-9);
}

TEST_F(TrackerManagerTest, LineTrackerAfterAResetStartsAtRestFromTheNewPosition) {
  f_.Start(1.0, old_);
  m_.OnEpisodeStatus(1, 1.0);
  ASSERT_EQ(m_.Goto(old_ + Eigen::Vector3d(6, 0, 2), 0.0, 0.0, 0.0), "");
  f_.Run(2.0);
  ASSERT_GT(m_.last_ref().v_world.norm(), 0.5);  // mid-goto, moving
  ASSERT_EQ(m_.line().status(), TrackerStatus::kTracking);
  m_.OnEpisodeStatus(2, f_.t());
  f_.Teleport(new_start_, new_yaw_);
  f_.Step();
  EXPECT_EQ(m_.active_tracker(), "hover");
  EXPECT_EQ(m_.line().status(), TrackerStatus::kInactive);  // the old profile is gone
  ASSERT_EQ(m_.Goto(new_start_ + Eigen::Vector3d(-1, 0, 1), new_yaw_, 0.0, 0.0), "");
  const ControlStep s = f_.Step();
  EXPECT_TRUE(s.ref.p_world.isApprox(new_start_, 1e-9)) << s.ref.p_world.transpose();
  EXPECT_LT(s.ref.v_world.norm(), 1e-9);
  EXPECT_LT(s.ref.a_world.norm(), 1e-9);
}

// Lockstep reproducibility: a goal starting exactly at an odometry stamp may reach the tracker before or
// after that odometry was processed. Both orders must fly the same commands: the goal (and the switch to the
// B-spline tracker) take effect at the first odometry strictly after its start_time.
TEST(TrackerManager, GoalTakesEffectAfterItsStartTimeWhateverTheArrivalOrder) {
  std::vector<std::vector<So3Command>> runs;
  for (const bool goal_first : {true, false}) {
    TrackerManager m(TrackerConfig{}, kMass, kG, kMaxThrust);
    Flight f(&m);
    const Eigen::Vector3d a(1.0, 2.0, 1.5);
    f.Start(1.0, a);
    ASSERT_EQ(m.Goto(a + Eigen::Vector3d(0.5, 0, 0), 0.0, 0.0, 0.0), "");
    f.Run(0.5);  // the line tracker is still moving: a switch at a different step would show
    const double t_start = f.t();  // the next odometry's stamp
    const BsplineGoalSpec goal = Line(f.p(), f.p() + Eigen::Vector3d(0, 4, 0), t_start, 4.0);
    std::vector<So3Command> cmds;
    if (goal_first) ASSERT_EQ(m.AddGoal(1, goal, t_start), "");
    cmds.push_back(f.Step().command);  // the odometry stamped t_start
    if (!goal_first) ASSERT_EQ(m.AddGoal(1, goal, t_start), "");
    EXPECT_EQ(m.active_tracker(), "line") << "no switch before the start time has passed";
    for (int i = 0; i < 200; ++i) cmds.push_back(f.Step().command);
    EXPECT_EQ(m.active_tracker(), "bspline");
    EXPECT_TRUE(m.bspline().running_goal().has_value());
    runs.push_back(cmds);
  }
  ASSERT_EQ(runs[0].size(), runs[1].size());
  for (size_t i = 0; i < runs[0].size(); ++i) {
    EXPECT_TRUE(runs[0][i].force_world_N == runs[1][i].force_world_N) << "step " << i;
    EXPECT_TRUE(runs[0][i].q_world_des.coeffs() == runs[1][i].q_world_des.coeffs()) << "step " << i;
  }
}

TEST(TrackerManager, ReAnchorResetsTheIntegralAndTheDirectionOfTravelYaw) {
  TrackerConfig cfg;
  cfg.gains.ki = Eigen::Vector3d(1.0, 1.0, 1.0);
  TrackerManager m(cfg, kMass, kG, kMaxThrust);
  // Hold (0, 0, 1) while the vehicle sits 0.3 m below: the integral builds up.
  m.OnOdometry(Odom(1.0, Eigen::Vector3d(0, 0, 1)));
  for (int i = 1; i <= 400; ++i) m.OnOdometry(Odom(1.0 + i * kDt, Eigen::Vector3d(0, 0, 0.7)));
  ASSERT_GT(m.controller().integral_mps2().z(), 0.3);

  // Fly north with direction-of-travel yaw (no yaw points): the reference turns towards +pi/2.
  Flight f(&m);
  f.Start(3.1, Eigen::Vector3d(0, 0, 1));
  const Eigen::Vector3d a(0, 0, 1);
  ASSERT_EQ(m.AddGoal(1, Line(a, a + Eigen::Vector3d(0, 8, 0), f.t(), 6.0), f.t()), "");
  f.Run(3.0);
  ASSERT_GT(m.last_ref().yaw_rad, 1.5);

  m.ReAnchor(Odom(f.t(), Eigen::Vector3d(20, 0, 1), -2.0), "test re-anchor");
  EXPECT_EQ(m.controller().integral_mps2().norm(), 0.0);
  EXPECT_EQ(m.reanchor_count(), 1);
  const auto events = m.TakeEvents();
  ASSERT_FALSE(events.empty());
  EXPECT_EQ(events.back().kind, GoalEventKind::kAborted);
  EXPECT_EQ(events.back().reason, "test re-anchor");

  // A new goal east from the new pose: the rate-limited yaw starts from the new heading (-2.0), not from the
  // previous episode's +pi/2.
  f.Teleport(Eigen::Vector3d(20, 0, 1), -2.0);
  f.Step();
  const Eigen::Vector3d b(20, 0, 1);
  ASSERT_EQ(m.AddGoal(2, Line(b, b + Eigen::Vector3d(8, 0, 0), f.t(), 6.0), f.t()), "");
  const double max_step = BsplineTrackerConfig{}.max_yaw_rate_radps * kDt;
  double prev = -2.0;
  for (int i = 0; i < 200; ++i) {
    const ControlStep s = f.Step();
    EXPECT_LE(std::fabs(quad_core::WrapAngle(s.ref.yaw_rad - prev)), max_step + 1e-9) << i;
    prev = s.ref.yaw_rad;
  }
  EXPECT_GT(prev, -2.0);  // turning towards 0 (east), the short way
}

TEST(TrackerManager, StatusBookkeeping) {
  TrackerManager m(TrackerConfig{}, kMass, kG, kMaxThrust);
  // Statuses before any odometry: recorded, nothing to re-anchor (the first odometry anchors).
  EXPECT_EQ(m.OnEpisodeStatus(4, 1.0), "");
  EXPECT_EQ(m.OnEpisodeStatus(5, 2.0), "");
  EXPECT_FALSE(m.reset_pending());
  m.OnOdometry(Odom(3.0, Eigen::Vector3d(1, 1, 1)));
  EXPECT_EQ(m.OnEpisodeStatus(5, 3.5), "");  // periodic status of the same episode
  EXPECT_EQ(m.episode_id(), 5u);
  // No start time: the next odometry is the new episode's.
  EXPECT_NE(m.OnEpisodeStatus(6, 0.0), "");
  EXPECT_TRUE(m.reset_pending());
  bool deferred = false;
  EXPECT_EQ(m.Switch("bspline", &deferred), "");
  EXPECT_TRUE(deferred);
  EXPECT_EQ(m.Switch("mpc"), "unknown tracker 'mpc' (hover, line, bspline)");
  const ControlStep s = m.OnOdometry(Odom(3.005, Eigen::Vector3d(1.2, 1, 1)));
  EXPECT_FALSE(s.reanchored.empty());
  EXPECT_EQ(m.active_tracker(), "bspline");  // the deferred switch, applied after the re-anchor
  EXPECT_TRUE(s.ref.p_world.isApprox(Eigen::Vector3d(1.2, 1, 1)));
  // Non-finite odometry is skipped and answered with the safe command.
  const ControlStep bad = m.OnOdometry(Odom(std::nan(""), Eigen::Vector3d(0, 0, 0)));
  EXPECT_TRUE(bad.odometry_skipped);
  EXPECT_EQ(bad.status, ControlStatus::kNonFiniteInput);
  // The hold: the hover command at the last reference's yaw, that reference's position held still.
  EXPECT_EQ(bad.command.force_world_N, Eigen::Vector3d(0.0, 0.0, kMass * kG));
  EXPECT_TRUE(bad.ref.p_world.isApprox(s.ref.p_world));
  EXPECT_EQ(bad.ref.yaw_rad, s.ref.yaw_rad);
  EXPECT_TRUE(bad.ref.v_world.isZero());
  EXPECT_TRUE(bad.ref.a_world.isZero());
  EXPECT_EQ(m.reanchor_count(), 1);
}

TEST(TrackerManager, RejectsABadInitialTrackerOrJumpLimit) {
  TrackerConfig cfg;
  cfg.initial_tracker = "mpc";
  try {
    TrackerManager m(cfg, kMass, kG, kMaxThrust);
    FAIL() << "accepted initial_tracker mpc";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("initial_tracker 'mpc'"), std::string::npos) << e.what();
  }
  cfg = TrackerConfig{};
  cfg.max_odom_jump_m = 0.0;
  try {
    TrackerManager m(cfg, kMass, kG, kMaxThrust);
    FAIL() << "accepted max_odom_jump_m 0";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("max_odom_jump_m"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace kr_tracker
