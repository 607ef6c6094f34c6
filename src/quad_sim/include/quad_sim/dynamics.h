// 6-DoF rigid-body quadrotor dynamics with first-order motors, linear drag and penalty ground contact,
// integrated with classical RK4 (the quaternion is renormalised after every step).
//
// Written here rather than taken from Bullet's btRigidBody: Bullet integrates with semi-implicit Euler in
// single precision and has no rotor or motor model, while the tests ask for hover held within 1 mm over 10 s
// and a unit quaternion over 10^6 steps.
#pragma once

#include "quad_core/vehicle_params.h"
#include "quad_core/vehicle_state.h"

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <array>

namespace quad_sim {

struct DynamicsState {
  Eigen::Vector3d p_world_body = Eigen::Vector3d::Zero();  // centre of mass in the world frame (m)
  Eigen::Vector3d v_world = Eigen::Vector3d::Zero();  // velocity of the centre of mass, world frame (m/s)
  Eigen::Quaterniond q_world_body = Eigen::Quaterniond::Identity();
  Eigen::Vector3d w_body = Eigen::Vector3d::Zero();  // angular velocity in body axes (rad/s)
  Eigen::Vector4d motor_speeds_radps = Eigen::Vector4d::Zero();

  bool AllFinite() const;
  // The odometry of this state at sim time t_s (the motor speeds are internal to the simulator).
  quad_core::VehicleState Odometry(double t_s) const;
};

// Spring-damper contact of the collision box's corners with the ground plane z = 0, with regularised Coulomb
// friction. Lets the vehicle rest on the ground (a static sink of weight / (4 * stiffness)) and take off
// again.
struct GroundContactParams {
  double stiffness_N_per_m = 5000.0;        // per corner
  double damping_Ns_per_m = 30.0;           // per corner, normal direction
  double friction_coeff = 0.8;              // Coulomb limit |F_t| <= mu * N
  double friction_damping_Ns_per_m = 30.0;  // per corner, tangential viscous regularisation below the limit
};

// Total external wrench on the vehicle, and its parts (for tests and diagnostics).
struct Wrench {
  Eigen::Vector3d force_world_N = Eigen::Vector3d::Zero();
  Eigen::Vector3d moment_body_Nm = Eigen::Vector3d::Zero();
};

class QuadrotorDynamics {
 public:
  QuadrotorDynamics(const quad_core::VehicleParams& vehicle, const GroundContactParams& ground);

  // One RK4 step of length dt_s with the motor speed commands held constant over the step. Commands are
  // clamped to [0, max_speed] (0 means motors off; the attitude controller applies the idle limit when
  // armed).
  DynamicsState Step(const DynamicsState& state, const Eigen::Vector4d& motor_cmd_radps, double dt_s) const;

  // Rotor thrust and moments (body frame) for given rotor speeds.
  Wrench RotorWrench(const DynamicsState& state) const;
  // Contact wrench of the ground plane on the collision box's corners.
  Wrench GroundWrench(const DynamicsState& state) const;
  // Lowest point of the collision box (world z).
  double LowestPointZ(const DynamicsState& state) const;

  const quad_core::VehicleParams& vehicle() const { return vehicle_; }

 private:
  struct Derivative {
    Eigen::Vector3d p_dot;
    Eigen::Vector3d v_dot;
    Eigen::Vector4d q_dot;  // (w, x, y, z)
    Eigen::Vector3d w_dot;
    Eigen::Vector4d motor_dot;
  };
  Derivative Evaluate(const DynamicsState& s, const Eigen::Vector4d& motor_cmd_radps) const;
  static DynamicsState Advance(const DynamicsState& s, const Derivative& d, double h);

  quad_core::VehicleParams vehicle_;
  GroundContactParams ground_;
  Eigen::Matrix4d mixer_;
  Eigen::Matrix3d inertia_inv_;
  std::array<Eigen::Vector3d, 8> corners_body_;
};

}  // namespace quad_sim
