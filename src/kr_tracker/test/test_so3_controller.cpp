// SO(3) controller: hover trim, proportional response, saturations, desired angular velocity against finite
// differences of the desired attitude, integral clamp, and rejection of bad input.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "kr_tracker/so3_controller.h"

namespace kr_tracker {
namespace {

constexpr double kMass = 0.75;
constexpr double kG = 9.81;
constexpr double kMaxThrust = 28.8;  // vehicle.yaml: 4 * 8e-7 * 3000^2

quad_core::VehicleState StateAt(const PositionReference& r) {
  quad_core::VehicleState s;
  s.p_world_body = r.p_world;
  s.v_world = r.v_world;
  s.a_world = r.a_world;
  s.has_accel = true;
  return s;
}

double Yaw(const Eigen::Quaterniond& q) {
  const Eigen::Vector3d x = q * Eigen::Vector3d::UnitX();
  return std::atan2(x.y(), x.x());
}

TEST(So3Controller, HoverCommandEqualsWeightWithLevelAttitudeAtAnyYaw) {
  So3Controller c(So3Gains{}, kMass, kG, kMaxThrust);
  for (double yaw : {0.0, 0.5, -2.0, 3.0}) {
    const PositionReference ref = PositionReference::Hold(Eigen::Vector3d(1, -2, 3), yaw);
    const ControlOutput out = c.Compute(ref, StateAt(ref), 0.005);
    EXPECT_EQ(out.status, ControlStatus::kOk);
    EXPECT_TRUE(out.command.force_world_N.isApprox(Eigen::Vector3d(0, 0, kMass * kG), 1e-12));
    const Eigen::Vector3d b3 = out.command.q_world_des * Eigen::Vector3d::UnitZ();
    EXPECT_NEAR((b3 - Eigen::Vector3d::UnitZ()).norm(), 0.0, 1e-12);
    EXPECT_NEAR(quad_core::WrapAngle(Yaw(out.command.q_world_des) - yaw), 0.0, 1e-12);
    EXPECT_NEAR(out.command.w_body_des_radps.norm(), 0.0, 1e-12);
    EXPECT_TRUE(out.command.kR.isApprox(So3Gains{}.kR));
    EXPECT_TRUE(out.command.kOm.isApprox(So3Gains{}.kOm));
    // The fallback command is the same thing.
    EXPECT_TRUE(c.HoverCommand(yaw).force_world_N.isApprox(out.command.force_world_N));
  }
}

TEST(So3Controller, ForceIsMassTimesPdPlusFeedforwardPlusGravity) {
  So3Controller c(So3Gains{}, kMass, kG, kMaxThrust);
  PositionReference ref;
  ref.p_world = Eigen::Vector3d(0.1, -0.05, 0.2);
  ref.v_world = Eigen::Vector3d(0.3, 0.1, -0.1);
  ref.a_world = Eigen::Vector3d(0.2, -0.4, 0.5);
  quad_core::VehicleState s;
  s.v_world = Eigen::Vector3d(0.1, 0.0, 0.05);
  const So3Gains g;
  const Eigen::Vector3d expected =
      kMass * (g.kx.cwiseProduct(ref.p_world) + g.kv.cwiseProduct(ref.v_world - s.v_world) + ref.a_world +
               Eigen::Vector3d(0, 0, kG));
  const ControlOutput out = c.Compute(ref, s, 0.005);
  EXPECT_TRUE(out.command.force_world_N.isApprox(expected, 1e-12));
  // The desired thrust axis is along the force.
  const Eigen::Vector3d b3 = out.command.q_world_des * Eigen::Vector3d::UnitZ();
  EXPECT_NEAR((b3 - expected.normalized()).norm(), 0.0, 1e-12);
}

TEST(So3Controller, TiltIsLimitedAndVerticalCommandStaysPositive) {
  So3Gains g;
  g.max_tilt_rad = 0.5;
  So3Controller c(g, kMass, kG, kMaxThrust);
  quad_core::VehicleState s;
  const ControlOutput out = c.Compute(PositionReference::Hold(Eigen::Vector3d(10, 5, 0), 0.0), s, 0.005);
  const Eigen::Vector3d f = out.command.force_world_N;
  EXPECT_NEAR(std::atan2(f.head<2>().norm(), f.z()), 0.5, 1e-12);
  EXPECT_NEAR(f.z(), kMass * kG, 1e-12);   // altitude command unaffected by the lateral saturation
  EXPECT_NEAR(f.y() / f.x(), 0.5, 1e-12);  // direction of the lateral command kept
  // Far above the reference: the raw vertical command is negative; it is clamped to min_accel_z_mps2.
  const ControlOutput down = c.Compute(PositionReference::Hold(Eigen::Vector3d(0, 0, -10), 0.0), s, 0.005);
  EXPECT_NEAR(down.command.force_world_N.z(), kMass * g.min_accel_z_mps2, 1e-12);
  EXPECT_GT((down.command.q_world_des * Eigen::Vector3d::UnitZ()).z(), 0.99);
}

TEST(So3Controller, ForceIsLimitedToTheThrustFractionKeepingTheVerticalPart) {
  const So3Gains g;  // max_thrust_fraction 0.85
  So3Controller c(g, kMass, kG, kMaxThrust);
  const double limit_N = 0.85 * kMaxThrust;
  quad_core::VehicleState s;
  // Straight up, far: vertical only, at the limit.
  ControlOutput out = c.Compute(PositionReference::Hold(Eigen::Vector3d(0, 0, 50), 0.0), s, 0.005);
  EXPECT_TRUE(out.command.force_world_N.isApprox(Eigen::Vector3d(0, 0, limit_N), 1e-12));
  // Up and sideways: the vertical part is kept (kz * 2 m + g), the horizontal part shortened to fit the
  // limit.
  out = c.Compute(PositionReference::Hold(Eigen::Vector3d(3, 3, 2), 0.0), s, 0.005);
  const double fz = kMass * (g.kx.z() * 2.0 + kG);
  ASSERT_LT(fz, limit_N);
  EXPECT_NEAR(out.command.force_world_N.norm(), limit_N, 1e-9);
  EXPECT_NEAR(out.command.force_world_N.z(), fz, 1e-9);
  EXPECT_NEAR(out.command.force_world_N.x(), out.command.force_world_N.y(), 1e-9);
  // A limit below the weight cannot hover: refused.
  EXPECT_THROW(So3Controller(g, kMass, kG, 0.9 * kMass * kG), std::invalid_argument);
  So3Gains low = g;
  low.max_thrust_fraction = 0.25;  // 7.2 N < 7.36 N weight
  EXPECT_THROW(So3Controller(low, kMass, kG, kMaxThrust), std::invalid_argument);
}

// Reference along a smooth curve with the vehicle exactly on it: the desired attitude R(t) is then a function
// of the reference only, and w_des must equal vee(R^T dR/dt) computed by central differences.
TEST(So3Controller, DesiredAngularVelocityMatchesFiniteDifferenceOfDesiredAttitude) {
  So3Controller c(So3Gains{}, kMass, kG, kMaxThrust);
  auto ref_at = [](double t) {
    PositionReference r;
    const double w = 1.3;
    r.p_world = Eigen::Vector3d(std::sin(w * t), 0.5 * std::cos(2 * w * t), 0.2 * t);
    r.v_world = Eigen::Vector3d(w * std::cos(w * t), -w * std::sin(2 * w * t), 0.2);
    r.a_world = Eigen::Vector3d(-w * w * std::sin(w * t), -2 * w * w * std::cos(2 * w * t), 0.0);
    r.j_world = Eigen::Vector3d(-w * w * w * std::cos(w * t), 4 * w * w * w * std::sin(2 * w * t), 0.0);
    r.yaw_rad = 0.4 * std::sin(t);
    r.yaw_rate_radps = 0.4 * std::cos(t);
    return r;
  };
  const double h = 1e-5;
  for (double t : {0.1, 0.7, 1.9, 2.6}) {
    const auto rot = [&](double tt) {
      const PositionReference r = ref_at(tt);
      return c.Compute(r, StateAt(r), 0.0).command.q_world_des.toRotationMatrix();
    };
    const Eigen::Matrix3d r0 = rot(t);
    const Eigen::Matrix3d omega_hat = r0.transpose() * (rot(t + h) - rot(t - h)) / (2 * h);
    const Eigen::Vector3d w_fd(omega_hat(2, 1), omega_hat(0, 2), omega_hat(1, 0));
    const PositionReference r = ref_at(t);
    const Eigen::Vector3d w = c.Compute(r, StateAt(r), 0.0).command.w_body_des_radps;
    EXPECT_LT((w - w_fd).norm(), 1e-6) << "t=" << t << " w=" << w.transpose() << " fd=" << w_fd.transpose();
    EXPECT_GT(w.norm(), 0.1);  // a non-trivial case
  }
}

TEST(So3Controller, WithoutMeasuredAccelerationTheReferenceAccelerationIsAssumed) {
  So3Controller c(So3Gains{}, kMass, kG, kMaxThrust);
  PositionReference ref = PositionReference::Hold(Eigen::Vector3d(0.1, 0.2, 1.0), 0.3);
  ref.v_world = Eigen::Vector3d(1.0, 0.5, 0.0);
  ref.a_world = Eigen::Vector3d(-2.0, 1.0, 0.5);
  ref.j_world = Eigen::Vector3d(0.5, -3.0, 0.0);
  quad_core::VehicleState unmeasured;
  unmeasured.v_world = Eigen::Vector3d(0.9, 0.4, 0.1);
  unmeasured.a_world = Eigen::Vector3d(7.0, 7.0, 7.0);  // ignored: has_accel is false
  quad_core::VehicleState measured = unmeasured;
  measured.has_accel = true;
  measured.a_world = ref.a_world;
  const Eigen::Vector3d w_unmeasured = c.Compute(ref, unmeasured, 0.0).command.w_body_des_radps;
  EXPECT_TRUE(w_unmeasured.isApprox(c.Compute(ref, measured, 0.0).command.w_body_des_radps, 1e-12));
  measured.a_world.setZero();  // kr_mav_control's value without an IMU: a different (wrong) rate
  EXPECT_GT((c.Compute(ref, measured, 0.0).command.w_body_des_radps - w_unmeasured).norm(), 0.1);
}

TEST(So3Controller, IntegralAccumulatesWithDtAndIsClamped) {
  So3Gains g;
  g.ki = Eigen::Vector3d(1.0, 2.0, 0.0);
  g.max_pos_int_mps2 = 0.3;
  So3Controller c(g, kMass, kG, kMaxThrust);
  quad_core::VehicleState s;
  const PositionReference ref = PositionReference::Hold(Eigen::Vector3d(0.1, 0.1, 0.1), 0.0);
  c.Compute(ref, s, 0.5);
  EXPECT_TRUE(c.integral_mps2().isApprox(Eigen::Vector3d(0.05, 0.1, 0.0), 1e-12));
  for (int i = 0; i < 20; ++i) c.Compute(ref, s, 0.5);
  EXPECT_TRUE(c.integral_mps2().isApprox(Eigen::Vector3d(0.3, 0.3, 0.0), 1e-12));
  c.ResetIntegral();
  EXPECT_EQ(c.integral_mps2().norm(), 0.0);
}

TEST(So3Controller, NonFiniteInputGivesHoverCommandAndLeavesIntegralUntouched) {
  So3Gains g;
  g.ki = Eigen::Vector3d::Ones();
  So3Controller c(g, kMass, kG, kMaxThrust);
  quad_core::VehicleState s;
  c.Compute(PositionReference::Hold(Eigen::Vector3d(0.2, 0, 0), 0.0), s, 0.1);
  const Eigen::Vector3d integral = c.integral_mps2();
  PositionReference bad = PositionReference::Hold(Eigen::Vector3d(1, 0, 0), 0.3);
  bad.v_world.x() = std::numeric_limits<double>::quiet_NaN();
  ControlOutput out = c.Compute(bad, s, 0.1);
  EXPECT_EQ(out.status, ControlStatus::kNonFiniteInput);
  EXPECT_STREQ(ToString(out.status), "non-finite reference or state: hover command returned");
  EXPECT_TRUE(out.command.force_world_N.isApprox(Eigen::Vector3d(0, 0, kMass * kG)));
  EXPECT_TRUE(out.command.AllFinite());
  EXPECT_TRUE(c.integral_mps2().isApprox(integral));
  quad_core::VehicleState bad_state;
  bad_state.p_world_body.z() = std::numeric_limits<double>::infinity();
  out = c.Compute(PositionReference::Hold(Eigen::Vector3d::Zero(), 0.0), bad_state, 0.1);
  EXPECT_EQ(out.status, ControlStatus::kNonFiniteInput);
}

TEST(So3Controller, BadParametersThrowNamingTheField) {
  EXPECT_THROW(So3Controller(So3Gains{}, 0.0, kG, kMaxThrust), std::invalid_argument);
  EXPECT_THROW(So3Controller(So3Gains{}, kMass, -1.0, kMaxThrust), std::invalid_argument);
  So3Gains g;
  g.kv.y() = -1.0;
  try {
    So3Controller c(g, kMass, kG, kMaxThrust);
    FAIL() << "no exception";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("kv"), std::string::npos) << e.what();
  }
  g = So3Gains{};
  g.max_tilt_rad = 2.0;
  EXPECT_THROW(So3Controller(g, kMass, kG, kMaxThrust), std::invalid_argument);
}

TEST(Types, WrapAngleMapsToMinusPiExclusivePiInclusive) {
  EXPECT_DOUBLE_EQ(quad_core::WrapAngle(M_PI), M_PI);
  EXPECT_DOUBLE_EQ(quad_core::WrapAngle(-M_PI), M_PI);
  EXPECT_NEAR(quad_core::WrapAngle(3 * M_PI / 2), -M_PI / 2, 1e-12);
  EXPECT_NEAR(quad_core::WrapAngle(-7.0), -7.0 + 2 * M_PI, 1e-12);
  EXPECT_NEAR(quad_core::WrapAngle(0.3), 0.3, 1e-15);
}

}  // namespace
}  // namespace kr_tracker
