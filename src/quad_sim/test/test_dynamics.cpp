// Rigid-body dynamics, motors and the onboard attitude controller against closed-form results.
#include "quad_sim/attitude_controller.h"
#include "quad_sim/dynamics.h"
#include "quad_sim/math_utils.h"
#include "quad_sim/simulator.h"

#include "test_util.h"

#include <gtest/gtest.h>

#include <cmath>

using quad_core::VehicleParams;
using quad_sim::DynamicsState;
using quad_sim::QuadrotorDynamics;
using quad_sim::Simulator;

namespace {

constexpr double kPi = 3.14159265358979323846;

quad_sim::So3Command LevelHover(const quad_core::VehicleParams& p, double yaw = 0.0) {
  quad_sim::So3Command c;
  c.force_world_N = Eigen::Vector3d(0, 0, p.mass_kg * p.gravity_mps2);
  c.q_world_des = quad_sim::QuatFromRpy(0, 0, yaw);
  return c;
}

// A simulator in an empty world, the vehicle hovering at trim at p.
std::unique_ptr<Simulator> HoveringSim(const Eigen::Vector3d& p) {
  auto sim = std::make_unique<Simulator>(quad_sim_test::DefaultSimConfig());
  sim->Reset(quad_sim::World(), p, 0.0, Eigen::Vector3d(100, 100, 100));
  return sim;
}

}  // namespace

TEST(Dynamics, HoverAtTrimThrustHoldsAltitudeWithin1mmOver10s) {
  auto sim = HoveringSim(Eigen::Vector3d(1.0, -2.0, 2.0));
  const quad_core::VehicleParams& p = sim->config().vehicle;
  double max_dev = 0.0;
  while (sim->time_s() < 10.0) {
    if (sim->OdometryDue()) {
      ASSERT_TRUE(sim->SetSo3Command(LevelHover(p)).ok());
    }
    sim->Step();
    max_dev = std::max(max_dev, (sim->state().p_world_body - Eigen::Vector3d(1.0, -2.0, 2.0)).norm());
  }
  EXPECT_LT(max_dev, 1e-3);
  EXPECT_FALSE(sim->collision().collided);
  // The rotors sit at the analytic hover speed.
  for (int i = 0; i < 4; ++i) EXPECT_NEAR(sim->state().motor_speeds_radps(i), p.HoverMotorSpeedRadps(), 1e-6);
}

TEST(Dynamics, HoverWithTrpyAtTrimThrustHoldsAltitude) {
  auto sim = HoveringSim(Eigen::Vector3d(0.0, 0.0, 3.0));
  const quad_core::VehicleParams& p = sim->config().vehicle;
  quad_sim::TrpyCommand c;
  c.thrust_N = p.mass_kg * p.gravity_mps2;
  c.yaw_rad = 0.0;
  while (sim->time_s() < 10.0) {
    if (sim->OdometryDue()) {
      ASSERT_TRUE(sim->SetTrpyCommand(c).ok());
    }
    sim->Step();
  }
  EXPECT_LT((sim->state().p_world_body - Eigen::Vector3d(0, 0, 3)).norm(), 1e-3);
}

TEST(Dynamics, FreeFallMatchesGravity) {
  quad_core::VehicleParams p = quad_sim_test::DefaultVehicle();
  p.drag_coeff_Ns_per_m.setZero();
  const QuadrotorDynamics dyn(p, quad_sim::GroundContactParams());
  DynamicsState s;
  s.p_world_body = Eigen::Vector3d(0, 0, 100.0);
  s.v_world = Eigen::Vector3d(1.0, 0.0, 2.0);
  const double dt = 0.001;
  for (int k = 1; k <= 3000; ++k) {
    s = dyn.Step(s, Eigen::Vector4d::Zero(), dt);
    const double t = k * dt;
    // RK4 is exact for constant acceleration: only rounding remains.
    ASSERT_NEAR(s.p_world_body.z(), 100.0 + 2.0 * t - 0.5 * p.gravity_mps2 * t * t, 1e-9) << "t=" << t;
    ASSERT_NEAR(s.v_world.z(), 2.0 - p.gravity_mps2 * t, 1e-9);
    ASSERT_NEAR(s.p_world_body.x(), t, 1e-9);
  }
}

TEST(Dynamics, LinearDragDecaysHorizontalVelocityExponentially) {
  const quad_core::VehicleParams p = quad_sim_test::DefaultVehicle();
  const QuadrotorDynamics dyn(p, quad_sim::GroundContactParams());
  DynamicsState s;
  s.p_world_body = Eigen::Vector3d(0, 0, 10.0);
  s.v_world = Eigen::Vector3d(5.0, 0.0, 0.0);
  s.motor_speeds_radps.setConstant(p.HoverMotorSpeedRadps());
  const Eigen::Vector4d hover = Eigen::Vector4d::Constant(p.HoverMotorSpeedRadps());
  for (int k = 0; k < 1000; ++k) s = dyn.Step(s, hover, 0.001);
  const double rate = p.drag_coeff_Ns_per_m.x() / p.mass_kg;
  EXPECT_NEAR(s.v_world.x(), 5.0 * std::exp(-rate * 1.0), 1e-9);
  EXPECT_NEAR(s.p_world_body.x(), 5.0 / rate * (1.0 - std::exp(-rate * 1.0)), 1e-9);
  EXPECT_NEAR(s.p_world_body.z(), 10.0, 1e-9);
}

TEST(Dynamics, MotorsFollowFirstOrderLag) {
  const quad_core::VehicleParams p = quad_sim_test::DefaultVehicle();
  const QuadrotorDynamics dyn(p, quad_sim::GroundContactParams());
  DynamicsState s;
  s.p_world_body = Eigen::Vector3d(0, 0, 1e4);
  const Eigen::Vector4d cmd(2000.0, 1500.0, 1000.0, 500.0);
  for (int k = 1; k <= 100; ++k) {
    s = dyn.Step(s, cmd, 0.001);
    const double t = k * 0.001;
    for (int i = 0; i < 4; ++i) {
      // RK4's error on a linear ODE with h/tau = 0.05 is ~ (h/tau)^5 / 120 per step.
      ASSERT_NEAR(s.motor_speeds_radps(i), cmd(i) * (1.0 - std::exp(-t / p.motor_time_constant_s)),
                  1e-6 * cmd(i));
    }
  }
}

TEST(Dynamics, QuaternionStaysUnitAndTorqueFreeTumbleConservesMomentumOver1e6Steps) {
  quad_core::VehicleParams p = quad_sim_test::DefaultVehicle();
  // An asymmetric body makes the torque-free motion non-trivial (Euler's equations couple the axes).
  p.inertia_kgm2.diagonal() << 2.0e-3, 3.0e-3, 4.5e-3;
  p.drag_coeff_Ns_per_m.setZero();
  const QuadrotorDynamics dyn(p, quad_sim::GroundContactParams());
  DynamicsState s;
  s.p_world_body = Eigen::Vector3d(0, 0, 1e7);  // falls 4.9e6 m in 1000 s: never reaches the ground
  s.w_body = Eigen::Vector3d(2.0, -0.05, 1.0);  // mostly about the minor axis, with a wobble
  const Eigen::Matrix3d& J = p.inertia_kgm2;
  const Eigen::Vector3d L0 = s.q_world_body * (J * s.w_body);
  const double E0 = 0.5 * s.w_body.dot(J * s.w_body);
  double max_norm_err = 0.0;
  for (int k = 0; k < 1000000; ++k) {
    s = dyn.Step(s, Eigen::Vector4d::Zero(), 0.001);
    max_norm_err = std::max(max_norm_err, std::abs(s.q_world_body.norm() - 1.0));
  }
  EXPECT_LT(max_norm_err, 1e-14);
  const Eigen::Vector3d L = s.q_world_body * (J * s.w_body);
  EXPECT_LT((L - L0).norm() / L0.norm(), 1e-6);
  EXPECT_NEAR(0.5 * s.w_body.dot(J * s.w_body), E0, 1e-6 * E0);
}

TEST(Dynamics, SteadySpinAboutPrincipalAxisMatchesClosedForm) {
  quad_core::VehicleParams p = quad_sim_test::DefaultVehicle();
  const QuadrotorDynamics dyn(p, quad_sim::GroundContactParams());
  DynamicsState s;
  s.p_world_body = Eigen::Vector3d(0, 0, 1e4);
  s.w_body = Eigen::Vector3d(0, 0, 3.0);
  for (int k = 0; k < 10000; ++k) s = dyn.Step(s, Eigen::Vector4d::Zero(), 0.001);
  const Eigen::Quaterniond expected(Eigen::AngleAxisd(30.0, Eigen::Vector3d::UnitZ()));
  EXPECT_LT(s.q_world_body.angularDistance(expected), 1e-9);
}

TEST(AttitudeController, CommandedRollStepSettles) {
  auto sim = HoveringSim(Eigen::Vector3d(0.0, 0.0, 5.0));
  const quad_core::VehicleParams& p = sim->config().vehicle;
  const double roll = 20.0 * kPi / 180.0;
  quad_sim::So3Command c;
  c.q_world_des = quad_sim::QuatFromRpy(roll, 0.0, 0.0);
  c.force_world_N = c.q_world_des * Eigen::Vector3d(0, 0, p.mass_kg * p.gravity_mps2 / std::cos(roll));
  double max_roll = 0.0;
  double err_after_settle = 0.0;
  while (sim->time_s() < 1.5) {
    if (sim->OdometryDue()) {
      ASSERT_TRUE(sim->SetSo3Command(c).ok());
    }
    sim->Step();
    const double r = sim->state().q_world_body.angularDistance(Eigen::Quaterniond::Identity());
    max_roll = std::max(max_roll, r);
    if (sim->time_s() >= 0.5) {
      err_after_settle = std::max(err_after_settle, sim->state().q_world_body.angularDistance(c.q_world_des));
    }
  }
  // Second order with wn ~ 24 rad/s and damping ~ 1 (kR = 1.5, kOm = 0.13, Jxx = 2.5e-3) behind a 20 ms motor
  // lag.
  EXPECT_LT(err_after_settle, 0.5 * kPi / 180.0);
  EXPECT_LT(max_roll, roll * 1.15);
  // Tilted thrust with the weight compensated: horizontal acceleration g tan(roll) towards -y, altitude kept.
  EXPECT_LT(sim->state().v_world.y(), -0.5 * p.gravity_mps2 * std::tan(roll));
  EXPECT_NEAR(sim->state().p_world_body.z(), 5.0, 0.1);
}

TEST(AttitudeController, CommandedYawStepSettles) {
  auto sim = HoveringSim(Eigen::Vector3d(0.0, 0.0, 5.0));
  const quad_core::VehicleParams& p = sim->config().vehicle;
  const double yaw = 60.0 * kPi / 180.0;
  while (sim->time_s() < 2.0) {
    if (sim->OdometryDue()) {
      ASSERT_TRUE(sim->SetSo3Command(LevelHover(p, yaw)).ok());
    }
    sim->Step();
  }
  EXPECT_NEAR(quad_sim::YawOf(sim->state().q_world_body), yaw, 0.5 * kPi / 180.0);
  EXPECT_LT(sim->state().w_body.norm(), 0.01);
}

TEST(AttitudeController, LevelAttitudeAtRestGivesEqualRotorSpeeds) {
  const quad_core::VehicleParams p = quad_sim_test::DefaultVehicle();
  const quad_sim::AttitudeController ctl(p);
  DynamicsState s;
  const Eigen::Vector4d w = ctl.MotorCommands(quad_sim::AttitudeTarget::FromSo3(LevelHover(p)), s);
  for (int i = 0; i < 4; ++i) EXPECT_NEAR(w(i), p.HoverMotorSpeedRadps(), 1e-9);
  // Projected force: with the body tilted by 30 deg, the thrust is F . (R e3).
  s.q_world_body = quad_sim::QuatFromRpy(kPi / 6.0, 0, 0);
  const Eigen::Vector4d fm = ctl.ThrustAndMoment(quad_sim::AttitudeTarget::FromSo3(LevelHover(p)), s);
  EXPECT_NEAR(fm(0), p.mass_kg * p.gravity_mps2 * std::cos(kPi / 6.0), 1e-12);
  // The restoring moment acts about -x (rolls back to level) and equals -kR * e_R with e_R = sin(30deg) e_x.
  EXPECT_NEAR(fm(1), -1.5 * std::sin(kPi / 6.0), 1e-12);
}

TEST(GroundContact, VehicleRestsOnGroundAndTakesOff) {
  auto sim = std::make_unique<Simulator>(quad_sim_test::DefaultSimConfig());
  const quad_core::VehicleParams& p = sim->config().vehicle;
  sim->Reset(quad_sim::World(), Eigen::Vector3d(0, 0, 0.125), 0.3, Eigen::Vector3d(50, 0, 1));
  // Motors off for 2 s: the vehicle settles with a sub-millimetre sink and stays put.
  while (sim->time_s() < 2.0) sim->Step();
  const double sink = 0.125 - sim->state().p_world_body.z();
  EXPECT_GT(sink, 0.0);
  EXPECT_LT(sink, 1e-3);
  EXPECT_LT(sim->state().v_world.norm(), 1e-4);
  EXPECT_LT(sim->state().w_body.norm(), 1e-3);
  EXPECT_TRUE(sim->on_ground());
  EXPECT_FALSE(sim->collision().collided);
  // Take off with 30 % more thrust than the weight for 1 s.
  quad_sim::So3Command up = LevelHover(p, 0.3);
  up.force_world_N *= 1.3;
  const double t0 = sim->time_s();
  while (sim->time_s() < t0 + 1.0) {
    if (sim->OdometryDue()) sim->SetSo3Command(up);
    sim->Step();
  }
  EXPECT_FALSE(sim->on_ground());
  // 0.3 g for about 1 s (less the motor spin-up): ~1.3 m.
  EXPECT_GT(sim->state().p_world_body.z(), 0.125 + 1.0);
  EXPECT_FALSE(sim->collision().collided);
  EXPECT_NEAR(quad_sim::YawOf(sim->state().q_world_body), 0.3, 1e-3);
}

TEST(StaleCommand, VehicleLandsGentlyAndCutsMotors) {
  auto sim = HoveringSim(Eigen::Vector3d(2.0, 2.0, 2.0));
  const quad_core::VehicleParams& p = sim->config().vehicle;
  // Commands for 0.5 s, then silence: the onboard controller must land at descent_rate_mps and stop the
  // motors.
  while (sim->time_s() < 0.5) {
    if (sim->OdometryDue()) sim->SetSo3Command(LevelHover(p));
    sim->Step();
  }
  EXPECT_FALSE(sim->command_stale());
  double min_vz = 0.0;
  while (sim->time_s() < 8.0) {
    sim->Step();
    min_vz = std::min(min_vz, sim->state().v_world.z());
  }
  EXPECT_TRUE(sim->command_stale());
  EXPECT_TRUE(sim->on_ground());
  EXPECT_FALSE(sim->collision().collided) << sim->episode().reason;
  EXPECT_GT(min_vz, -sim->config().stale_command.descent_rate_mps - 0.1);
  EXPECT_EQ(sim->motor_commands_radps(), Eigen::Vector4d::Zero());
  EXPECT_NEAR(sim->state().p_world_body.x(), 2.0, 0.05);
}
