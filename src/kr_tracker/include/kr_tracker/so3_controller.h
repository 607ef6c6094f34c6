// SO(3) position controller with KumarRobotics kr_mav_control's control law (so3_control/SO3Control), as a
// pure Eigen class (ROS-free).
//
// Law (Lee, Leok, McClamroch 2010; Mellinger & Kumar 2011, as kr_mav_control implements it):
//   e_p = p_des - p,  e_v = v_des - v
//   a_cmd = kx .* e_p + kv .* e_v + i + a_des + g e_z,  with i += ki .* e_p dt (per-axis clamp)
//   F = m a_cmd (world frame),  b3 = F / |F|,  b2_des = (-sin yaw, cos yaw, 0)
//   b1 = (b2_des x b3) / |b2_des x b3|,  b2 = b3 x b1,  R_des = [b1 b2 b3]
//   dF = m (kx .* (v_des - v) + kv .* (a_des - a) + j_des),  db3 = d/dt (F / |F|),  ...,
//   w_des = vee(R_des^T dR_des)
// Differences to kr_mav_control (docs/kr_tracker.md): the integral is weighted by dt (theirs adds ki * e_p
// per call, so its effect depended on the control rate); the vertical command is kept above min_accel_z_mps2
// so the desired attitude never flips upside down; the tilt limit (optional there) is always on; and the
// force is limited to max_thrust_fraction of the vehicle's maximum thrust, shortening the horizontal part
// first. Without that limit a large step saturates the rotors, the onboard attitude loop loses its yaw
// authority and the vehicle spins (34 % overshoot on the 3 m step with the default gains in our simulator).
#pragma once

#include <Eigen/Geometry>

#include <string>

#include "kr_tracker/types.h"

namespace kr_tracker {

struct So3Gains {
  // kr_mav_control's defaults (so3_control/config/gains.yaml).
  Eigen::Vector3d kx{7.4, 7.4, 10.4};  // position, 1/s^2
  Eigen::Vector3d kv{4.8, 4.8, 6.0};   // velocity, 1/s
  Eigen::Vector3d ki{0.0, 0.0, 0.0};   // integral of position error, 1/s^3
  double max_pos_int_mps2 = 0.5;       // per-axis clamp of the integral term (acceleration)
  Eigen::Vector3d kR{1.5, 1.5, 1.0};   // attitude gains, passed to the onboard attitude controller
  Eigen::Vector3d kOm{0.13, 0.13, 0.1};
  double max_tilt_rad = 0.7854;    // limit on the angle between the commanded thrust and world z (45 deg)
  double min_accel_z_mps2 = 0.98;  // lower limit on the vertical commanded acceleration (0.1 g)
  // Upper limit on the commanded force as a fraction of the vehicle's maximum thrust (vehicle.yaml): keeps a
  // margin of rotor speed for the attitude moments, which a saturated collective leaves none of.
  double max_thrust_fraction = 0.85;

  // Throws std::invalid_argument naming the field for negative/non-finite gains or limits out of range.
  void Validate() const;
};

enum class ControlStatus { kOk, kNonFiniteInput, kNonFiniteOutput };
const char* ToString(ControlStatus status);

struct ControlOutput {
  So3Command command;
  ControlStatus status = ControlStatus::kOk;
};

class So3Controller {
 public:
  // mass_kg, gravity_mps2 and max_thrust_N come from config/vehicle.yaml (quad_core::LoadVehicleParams) in
  // the node and tools. Throws std::invalid_argument for non-positive values, a usable thrust below the
  // weight, or invalid gains.
  So3Controller(const So3Gains& gains, double mass_kg, double gravity_mps2, double max_thrust_N);

  // One control step. dt_s weights the integral (0 disables its update). If an input or the result is not
  // finite the integral is left untouched and the hover command at the current yaw is returned with the
  // status.
  ControlOutput Compute(const PositionReference& ref, const quad_core::VehicleState& state, double dt_s);

  // Thrust m g along world z, level attitude at the given yaw, zero rates: the safe fallback.
  So3Command HoverCommand(double yaw_rad) const;

  void ResetIntegral() { pos_int_mps2_.setZero(); }
  const Eigen::Vector3d& integral_mps2() const { return pos_int_mps2_; }
  const So3Gains& gains() const { return gains_; }
  void set_gains(const So3Gains& gains);
  double mass_kg() const { return mass_kg_; }
  double gravity_mps2() const { return gravity_mps2_; }
  double max_thrust_N() const { return max_thrust_N_; }

 private:
  So3Gains gains_;
  double mass_kg_;
  double gravity_mps2_;
  double max_thrust_N_;
  Eigen::Vector3d pos_int_mps2_ = Eigen::Vector3d::Zero();
};

}  // namespace kr_tracker
