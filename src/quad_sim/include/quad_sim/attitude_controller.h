// The vehicle's onboard attitude controller: SO3Command / TRPYCommand -> rotor speed commands, as the
// attitude loop on a Kumar-lab vehicle (kr_mav_control's so3 interface).
//
// Geometric attitude control on SO(3) after Lee, Leok and McClamroch, "Geometric tracking control of a
// quadrotor UAV on SE(3)", CDC 2010:
//   e_R  = 1/2 vee(R_d^T R - R^T R_d),     e_W = W - R^T R_d W_d,
//   M    = -kR e_R - kOm e_W + W x J W - J (hat(W) R^T R_d W_d)      (the desired angular acceleration is 0),
// collective thrust f = F_des . (R e3) for an SO(3) command (the force projected on the current body z axis),
// or the commanded thrust for TRPY. [f, M] is mapped to rotor speeds through the inverse of the rotor mixer
// and clamped to the motor limits.
#pragma once

#include "quad_core/vehicle_params.h"
#include "quad_sim/commands.h"
#include "quad_sim/dynamics.h"

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace quad_sim {

// What the onboard loop tracks: a collective thrust (or a world force to project), an attitude, body rates,
// gains.
struct AttitudeTarget {
  bool thrust_from_force = true;  // true: f = force_world . R e3 (SO3); false: thrust_N
  Eigen::Vector3d force_world_N = Eigen::Vector3d::Zero();
  double thrust_N = 0.0;
  Eigen::Matrix3d R_world_des = Eigen::Matrix3d::Identity();
  Eigen::Vector3d w_body_des_radps = Eigen::Vector3d::Zero();
  Eigen::Vector3d kR = Eigen::Vector3d(1.5, 1.5, 1.0);
  Eigen::Vector3d kOm = Eigen::Vector3d(0.13, 0.13, 0.1);
  bool enable_motors = false;

  static AttitudeTarget FromSo3(const So3Command& cmd);
  static AttitudeTarget FromTrpy(const TrpyCommand& cmd);
};

class AttitudeController {
 public:
  explicit AttitudeController(const quad_core::VehicleParams& vehicle);

  // Desired collective thrust (N) and body moment (N m) for the target at the current state.
  Eigen::Vector4d ThrustAndMoment(const AttitudeTarget& target, const DynamicsState& state) const;
  // Rotor speed commands (rad/s): zeros when motors are disabled, else within [min, max] speed.
  Eigen::Vector4d MotorCommands(const AttitudeTarget& target, const DynamicsState& state) const;

 private:
  quad_core::VehicleParams vehicle_;
  Eigen::Matrix4d mixer_inv_;
};

}  // namespace quad_sim
