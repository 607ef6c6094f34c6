// The safety layer: one test per refusal reason, the acceptance of a safe plan, the depth test against a
// brute-force scan of every pixel, the view test and the rest of a kept plan.
#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <limits>
#include <random>

#include "quad_policy/policy_decider.h"
#include "quad_policy/safety.h"

namespace quad_policy {
namespace {

constexpr float kInf = std::numeric_limits<float>::infinity();

// 160 x 120 camera with Fast-Planner's field of view, at the world origin looking along world +x.
CameraModel Camera() {
  CameraModel c;
  c.intrinsics = quad_core::CameraIntrinsics{160, 120, 96.8, 96.8, 79.5, 59.5};
  Eigen::Matrix3d R;  // columns: the optical axes in the world (x right = -y, y down = -z, z forward = +x)
  R << 0, 0, 1, -1, 0, 0, 0, -1, 0;
  c.T_world_camera.linear() = R;
  return c;
}

DepthImage Uniform(float depth_m) {
  DepthImage d;
  d.width = 160;
  d.height = 120;
  d.depth_m.assign(160 * 120, depth_m);
  return d;
}

// Straight line from the vehicle (0.1 m behind the camera) along +x at speed_mps, plus a lateral offset per
// control point; K = 10 over 2 s.
UniformBspline Line(double speed_mps, double y_offset = 0.0, const std::vector<double>& zigzag = {}) {
  UniformBspline s;
  s.start_time_s = 5.0;
  s.knot_dt_s = 2.0 / 7.0;
  s.ctrl_world.resize(10, 3);
  for (int i = 0; i < 10; ++i) {
    const double tau = (i - 1) * s.knot_dt_s;
    s.ctrl_world.row(i) << -0.1 + speed_mps * tau, y_offset + (zigzag.empty() ? 0.0 : zigzag[i]), 0.0;
  }
  return s;
}

const Eigen::Vector3d kVehicle(-0.1, 0.0, 0.0);

SafetyResult Check(const UniformBspline& s, const DepthImage& d, const SafetyConfig& cfg = SafetyConfig()) {
  const DepthImageView v = d.view();
  return CheckTrajectory(s, kVehicle, &v, Camera(), cfg);
}

TEST(Safety, AcceptsASafePlanInFreeSpace) {
  const SafetyResult r = Check(Line(2.0), Uniform(kInf));
  EXPECT_EQ(r.verdict, SafetyVerdict::kAccepted) << r.reason;
  EXPECT_STREQ(ToString(r.verdict), "accepted");
  // A wall beyond the trajectory's reach (4 m + radius < 6 m) is fine too.
  EXPECT_TRUE(Check(Line(2.0), Uniform(6.0f)).accepted());
}

TEST(Safety, RefusesNonFiniteControlPointsEvenWhenDisabled) {
  UniformBspline s = Line(2.0);
  s.ctrl_world(4, 1) = std::nan("");
  SafetyConfig cfg;
  cfg.enabled = false;
  const SafetyResult r = Check(s, Uniform(kInf), cfg);
  EXPECT_EQ(r.verdict, SafetyVerdict::kNonFiniteOutput);
  EXPECT_STREQ(ToString(r.verdict), "non_finite_output");
  EXPECT_NE(r.reason.find("control point 4"), std::string::npos) << r.reason;
}

TEST(Safety, RefusesControlPointSpeedsAboveTheLimit) {
  const SafetyResult r = Check(Line(6.0), Uniform(kInf));
  EXPECT_EQ(r.verdict, SafetyVerdict::kVelocityLimit);
  EXPECT_STREQ(ToString(r.verdict), "velocity_limit");
  EXPECT_NEAR(r.value, 6.0, 1e-9);
  SafetyConfig disabled;
  disabled.enabled = false;
  EXPECT_TRUE(Check(Line(6.0), Uniform(kInf), disabled).accepted());
}

TEST(Safety, RefusesControlPointAccelerationsAboveTheLimit) {
  const std::vector<double> zigzag = {0.3, -0.3, 0.3, -0.3, 0.3, -0.3, 0.3, -0.3, 0.3, -0.3};
  const SafetyResult r = Check(Line(2.0, 0.0, zigzag), Uniform(kInf));
  EXPECT_EQ(r.verdict, SafetyVerdict::kAccelerationLimit);
  EXPECT_STREQ(ToString(r.verdict), "acceleration_limit");
  const double dt = 2.0 / 7.0;
  EXPECT_NEAR(r.value, 1.2 / (dt * dt), 1e-9);  // |c_{i+2} - 2 c_{i+1} + c_i| / dt^2 = 14.7 > 10
}

TEST(Safety, RefusesATrajectoryStartingFarFromTheVehicle) {
  const SafetyResult r = Check(Line(2.0, 2.0), Uniform(kInf));
  EXPECT_EQ(r.verdict, SafetyVerdict::kStartFarFromVehicle);
  EXPECT_STREQ(ToString(r.verdict), "start_far_from_vehicle");
  EXPECT_NEAR(r.value, 2.0, 1e-9);
}

TEST(Safety, RefusesATrajectoryIntoAWallSeenInTheDepthImage) {
  const SafetyResult r = Check(Line(2.0), Uniform(3.0f));
  EXPECT_EQ(r.verdict, SafetyVerdict::kCollisionInDepth);
  EXPECT_STREQ(ToString(r.verdict), "collision_in_depth");
  // The first sample whose sphere reaches 3 m along a ray near the axis: x = 2 t - 0.1 > 3 - 0.25.
  EXPECT_NEAR(r.value, 1.45, 1e-9) << r.reason;
  // With a smaller radius, the refusal comes one sample later.
  SafetyConfig thin;
  thin.vehicle_radius_m = 0.1;
  EXPECT_NEAR(Check(Line(2.0), Uniform(3.0f), thin).value, 1.55, 1e-9);
  // Only up to the check horizon.
  SafetyConfig short_horizon;
  short_horizon.check_horizon_s = 1.0;
  EXPECT_TRUE(Check(Line(2.0), Uniform(3.0f), short_horizon).accepted());
}

TEST(Safety, TooNearPixelsAreOccupiedAndInvalidPixelsAreFree) {
  // -inf (nearer than the camera's minimum range) everywhere: the first judged sample collides.
  EXPECT_EQ(Check(Line(2.0), Uniform(-kInf)).verdict, SafetyVerdict::kCollisionInDepth);
  // NaN carries no information.
  EXPECT_TRUE(Check(Line(2.0), Uniform(std::numeric_limits<float>::quiet_NaN())).accepted());
}

TEST(Safety, RadiusIsTheMarginBesideAnObstacle) {
  // A pillar at 3 m filling the image columns u < 40 (left of the camera axis, world +y side).
  DepthImage d = Uniform(kInf);
  for (int v = 0; v < 120; ++v) {
    for (int u = 0; u < 40; ++u) d.depth_m[v * 160 + u] = 3.0f;
  }
  // The edge ray (column 39) passes (79.5 - 39) / 96.8 * z = 0.418 z beside the axis: the pillar's surface at
  // 3 m begins 1.255 m to the left, the occupied space behind it widens with depth. The straight line is far
  // from it.
  EXPECT_TRUE(Check(Line(2.0), d).accepted());
  // 1.1 m to the left, the sample at 3 m is 0.155 m beside the surface's edge: refused with r = 0.25 m ...
  SafetyConfig cfg;
  cfg.max_start_error_m = 2.0;
  EXPECT_EQ(Check(Line(2.0, 1.1), d, cfg).verdict, SafetyVerdict::kCollisionInDepth);
  // ... and accepted with r = 0.1 m (the samples in front of the pillar see free space up to 3 m).
  cfg.vehicle_radius_m = 0.1;
  EXPECT_TRUE(Check(Line(2.0, 1.1), d, cfg).accepted());
}

TEST(Safety, SamplesBehindTheCameraOrHoldingItAreNotJudged) {
  std::vector<Eigen::Vector3d> samples = {Eigen::Vector3d(-0.1, 0, 0), Eigen::Vector3d(-2.0, 0, 0)};
  const DepthImage wall = Uniform(0.5f);
  EXPECT_FALSE(FindDepthCollision(samples, 0.25, 1, wall.view(), Camera()).collides);
  samples.push_back(Eigen::Vector3d(0.4, 0, 0));
  const DepthCollision hit = FindDepthCollision(samples, 0.25, 1, wall.view(), Camera());
  EXPECT_TRUE(hit.collides);
  EXPECT_EQ(hit.sample_index, 2);
}

// Reference: every pixel of the image, no bounding rectangle.
int BruteForceOccupied(const Eigen::Vector3d& c, double r, const DepthImage& d, const CameraModel& camera) {
  const quad_core::CameraIntrinsics& cam = camera.intrinsics;
  if (c.squaredNorm() <= r * r) return 0;
  int n = 0;
  for (int v = 0; v < cam.height; ++v) {
    for (int u = 0; u < cam.width; ++u) {
      double depth = d.depth_m[v * cam.width + u];
      if (std::isnan(depth) || (std::isinf(depth) && depth > 0)) continue;
      if (depth < 0) depth = 0;
      const Eigen::Vector3d dir((u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1.0);
      const double a = dir.squaredNorm(), b = dir.dot(c), disc = b * b - a * (c.squaredNorm() - r * r);
      if (disc >= 0 && (b + std::sqrt(disc)) / a > depth) ++n;
    }
  }
  return n;
}

TEST(Safety, BoundingRectangleFindsEveryOccupiedPixelOfABruteForceScan) {
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> xy(-3.0, 3.0), z(-1.0, 6.0), radius(0.05, 0.8), dd(0.3, 6.0);
  CameraModel cam = Camera();
  cam.T_world_camera = Eigen::Isometry3d::Identity();  // samples given in the camera frame
  int collisions = 0;
  for (int trial = 0; trial < 300; ++trial) {
    DepthImage d = Uniform(kInf);
    // A few random rectangles at random depths.
    for (int k = 0; k < 4; ++k) {
      const int u0 = static_cast<int>(rng() % 160), v0 = static_cast<int>(rng() % 120);
      const int u1 = std::min(160, u0 + 1 + static_cast<int>(rng() % 60));
      const int v1 = std::min(120, v0 + 1 + static_cast<int>(rng() % 60));
      const float depth = static_cast<float>(dd(rng));
      for (int v = v0; v < v1; ++v) {
        for (int u = u0; u < u1; ++u) d.depth_m[v * 160 + u] = depth;
      }
    }
    const Eigen::Vector3d c(xy(rng), xy(rng), z(rng));
    const double r = radius(rng);
    const int expected = BruteForceOccupied(c, r, d, cam);
    const DepthCollision hit = FindDepthCollision({c}, r, 1, d.view(), cam);
    EXPECT_EQ(hit.collides, expected > 0) << "trial " << trial;
    if (hit.collides) {
      EXPECT_EQ(hit.occupied_pixels, expected) << "trial " << trial;
      ++collisions;
    }
  }
  EXPECT_GT(collisions, 30);  // the random scenes exercise both outcomes
  EXPECT_LT(collisions, 270);
}

TEST(Safety, SampleTimesAreIntegerStepsEndingAtTheHorizon) {
  SafetyConfig cfg;
  cfg.sample_dt_s = 0.3;
  const std::vector<double> t = SafetySampleTimes(Line(1.0), cfg);
  ASSERT_EQ(t.size(), 8u);  // 0, 0.3, ..., 1.8, then 2.0
  EXPECT_DOUBLE_EQ(t[6], 6 * 0.3);
  EXPECT_DOUBLE_EQ(t.back(), 2.0);
  cfg.sample_dt_s = 0.5;
  EXPECT_EQ(SafetySampleTimes(Line(1.0), cfg).size(), 5u);  // 0 .. 2.0 exactly
}

TEST(Safety, ConfigValidationNamesTheField) {
  SafetyConfig cfg;
  cfg.sample_dt_s = 0.0;
  try {
    ValidateSafetyConfig(cfg);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("safety.sample_dt_s"), std::string::npos);
  }
  cfg = SafetyConfig();
  cfg.collision_min_pixels = 0;
  EXPECT_THROW(ValidateSafetyConfig(cfg), std::invalid_argument);
}

TEST(Safety, VerdictCountsSumTheRefusals) {
  VerdictCounts c;
  c.Add(SafetyVerdict::kAccepted);
  c.Add(SafetyVerdict::kVelocityLimit);
  c.Add(SafetyVerdict::kCollisionInDepth);
  c.Add(SafetyVerdict::kCollisionInDepth);
  EXPECT_EQ(c[SafetyVerdict::kCollisionInDepth], 2u);
  EXPECT_EQ(c.refused(), 3u);
}

// TrajectoryInView: straight ahead and a shallow turn stay in the image; a sharp turn leaves it, a plan
// backwards is behind the camera; samples holding the camera (the vehicle's own place) are not judged.
UniformBspline Heading(double yaw_deg, double speed_mps = 1.5) {
  UniformBspline s = Line(0.0);
  const double a = yaw_deg * M_PI / 180.0;
  for (int i = 0; i < 10; ++i) {
    const double tau = (i - 1) * s.knot_dt_s;
    s.ctrl_world.row(i) << speed_mps * tau * std::cos(a), speed_mps * tau * std::sin(a), 0.0;
  }
  return s;
}

TEST(Safety, TrajectoryInViewFollowsTheFieldOfView) {
  const SafetyConfig cfg;  // whole trajectory checked (check_horizon_s 0)
  // Half the horizontal field of view: atan(79.5 / 96.8) = 39.4 deg.
  EXPECT_TRUE(TrajectoryInView(Heading(0.0), Camera(), cfg));
  EXPECT_TRUE(TrajectoryInView(Heading(35.0), Camera(), cfg));
  EXPECT_TRUE(TrajectoryInView(Heading(-35.0), Camera(), cfg));
  EXPECT_FALSE(TrajectoryInView(Heading(45.0), Camera(), cfg));
  EXPECT_FALSE(TrajectoryInView(Heading(180.0), Camera(), cfg));
  EXPECT_TRUE(TrajectoryInView(Heading(90.0, 0.0), Camera(), cfg));  // stays put: the vehicle's own place
  // Only samples up to the check horizon count: 45 deg at 0.2 m/s stays within the vehicle's 0.25 m sphere
  // for the first second and leaves it (and the view) in the second.
  SafetyConfig short_horizon;
  short_horizon.check_horizon_s = 1.0;
  EXPECT_TRUE(TrajectoryInView(Heading(45.0, 0.2), Camera(), short_horizon));
  EXPECT_FALSE(TrajectoryInView(Heading(45.0, 0.2), Camera(), cfg));
}

TEST(Safety, AFrameOfAnotherSizeThanItsCameraIsRefusedWithTheReason) {
  DepthImage tiny;
  tiny.width = tiny.height = 10;
  tiny.depth_m.assign(100, 1.0f);
  try {
    FindDepthCollision({{1.0, 0.0, 0.0}}, 0.25, 1, tiny.view(), Camera());
    ADD_FAILURE() << "no error";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("depth image and camera model sizes differ"), std::string::npos);
  }
}

// The line of Line() flown from t = 5 s; at 1.5 m/s it is 0.45 m further along 0.3 s later.
TEST(RestIsClear, TheRestOfAPlanIsJudgedFromNowOnWithTheRecoveryTest) {
  const UniformBspline plan = Line(1.5);  // starts at t = 5 s, 2 s long
  SafetyConfig cfg;
  cfg.vehicle_radius_m = 0.25;
  cfg.check_horizon_s = 1.0;
  const DepthImage free = Uniform(kInf);
  const DepthImageView fv = free.view();
  const Eigen::Vector3d there(-0.1 + 1.5 * 0.3, 0.0, 0.0);  // where the plan is at t = 5.3 s
  EXPECT_TRUE(RestIsClear(plan, 5.3, 1.0, there, fv, Camera(), cfg));
  // Too little of it left, not started yet, or the vehicle far from where the plan is now.
  EXPECT_FALSE(RestIsClear(plan, 6.2, 1.0, there, fv, Camera(), cfg));
  EXPECT_FALSE(RestIsClear(plan, 4.9, 1.0, there, fv, Camera(), cfg));
  EXPECT_FALSE(RestIsClear(plan, 5.3, 1.0, there + Eigen::Vector3d(0.0, 1.1, 0.0), fv, Camera(), cfg));
  EXPECT_FALSE(RestIsClear(plan, std::nan(""), 1.0, there, fv, Camera(), cfg));
  // A wall 1.2 m ahead of the camera: the next second of the plan (to 1.85 m) runs into it.
  const DepthImage wall = Uniform(1.2f);
  EXPECT_FALSE(RestIsClear(plan, 5.3, 1.0, there, wall.view(), Camera(), cfg));
  // Judged from now on: a wall 2.4 m ahead is beyond the next second of the rest from 5.3 s (its samples
  // reach 1.85 m + 0.25 m), though the whole plan (3 m) would reach it.
  const DepthImage far = Uniform(2.4f);
  EXPECT_TRUE(RestIsClear(plan, 5.3, 1.0, there, far.view(), Camera(), cfg));
  // Leaving the view is refused as for a recovery plan: the line turned 60 deg left of the camera's axis.
  UniformBspline turned = plan;
  for (int i = 0; i < 10; ++i) {
    const double d = turned.ctrl_world(i, 0) + 0.1;
    turned.ctrl_world.row(i) << -0.1 + d * 0.5, d * std::sqrt(3.0) / 2.0, 0.0;
  }
  const Eigen::Vector3d turned_there = turned.Position(0.3);
  EXPECT_FALSE(RestIsClear(turned, 5.3, 1.0, turned_there, fv, Camera(), cfg));
  // With the safety layer off only time and place count.
  SafetyConfig off = cfg;
  off.enabled = false;
  EXPECT_TRUE(RestIsClear(plan, 5.3, 1.0, there, wall.view(), Camera(), off));
}

TEST(Keeping, BadSettingsAreRefusedWithTheirNames) {
  KeepingConfig k;
  EXPECT_NO_THROW(ValidateKeeping(k));
  k.commit_s = -0.1;
  try {
    ValidateKeeping(k);
    ADD_FAILURE() << "no error";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("keeping.commit_s must be finite and >= 0"), std::string::npos);
  }
  k.commit_s = std::nan("");
  EXPECT_THROW(ValidateKeeping(k), std::invalid_argument);
}

TEST(Recovery, TurnedGoalsKeepDistanceAndHeight) {
  const Eigen::Vector3d p(1.0, 2.0, 1.5), goal(11.0, 2.0, 3.0);
  EXPECT_TRUE(TurnedGoal(p, goal, 90.0).isApprox(Eigen::Vector3d(1.0, 12.0, 3.0), 1e-12));
  EXPECT_TRUE(TurnedGoal(p, goal, -30.0)
                  .isApprox(Eigen::Vector3d(1.0 + 10.0 * std::cos(M_PI / 6), -3.0, 3.0), 1e-12));
  EXPECT_NEAR((TurnedGoal(p, goal, 137.0) - p).norm(), (goal - p).norm(), 1e-12);
}

}  // namespace
}  // namespace quad_policy
