// Physical parameters of the simulated quadrotor, loaded strictly from config/vehicle.yaml.
//
// This is the single source of the vehicle's mass, inertia, rotors and gravity: the simulator flies with
// these values and the controller (kr_tracker) links quad_core and calls LoadVehicleParams on the same
// file, so a mass mismatch between controller and plant cannot happen by configuration.
#pragma once

#include <Eigen/Core>

#include <array>
#include <string>

namespace quad_core {
class StrictYaml;

// Rotor arrangement. kX: rotors at +-45 deg from the body x axis (Falcon 250); kPlus: rotors on the body
// axes.
enum class FrameLayout { kX, kPlus };

const char* ToString(FrameLayout layout);

struct VehicleParams {
  double mass_kg = 0.0;
  double gravity_mps2 = 0.0;
  Eigen::Matrix3d inertia_kgm2 = Eigen::Matrix3d::Zero();  // about the centre of mass, body axes (FLU)
  double arm_length_m = 0.0;                               // centre of mass to each rotor axis
  FrameLayout frame_layout = FrameLayout::kX;
  double thrust_coeff_N_per_radps2 = 0.0;   // kf: thrust of one rotor = kf * speed^2
  double torque_coeff_Nm_per_radps2 = 0.0;  // km: reaction torque of one rotor = km * speed^2
  double motor_time_constant_s = 0.0;       // first-order motor: d(speed)/dt = (cmd - speed) / tau
  double min_motor_speed_radps = 0.0;
  double max_motor_speed_radps = 0.0;
  Eigen::Vector3d drag_coeff_Ns_per_m = Eigen::Vector3d::Zero();  // linear drag in body axes
  Eigen::Vector3d collision_box_m = Eigen::Vector3d::Zero();      // edge lengths of the collision box

  // Weight m * g, i.e. the total thrust needed to hover (N).
  double HoverThrustN() const { return mass_kg * gravity_mps2; }
  // Speed of every rotor at hover (rad/s).
  double HoverMotorSpeedRadps() const;
  // Total thrust with all rotors at their maximum speed (N).
  double MaxThrustN() const {
    return 4.0 * thrust_coeff_N_per_radps2 * max_motor_speed_radps * max_motor_speed_radps;
  }
  // Rotor positions in body axes (z = 0) and spin directions (+1: counter-clockwise seen from above, whose
  // reaction torque on the body is clockwise, i.e. -z).
  std::array<Eigen::Vector3d, 4> RotorPositionsBody() const;
  std::array<double, 4> RotorSpinDirections() const;
  // The mixer: [thrust_N; moment_body_Nm] = Mixer() * [speed_i^2].
  Eigen::Matrix4d Mixer() const;

  // Throws std::invalid_argument naming the field if a value is out of range (used after loading and by code
  // that builds VehicleParams by hand, e.g. tests).
  void Validate() const;
};

// Loads and validates config/vehicle.yaml. Throws quad_core::ConfigError naming the file and the missing,
// unknown or out-of-range key.
VehicleParams LoadVehicleParams(const std::string& yaml_path);

// Reads the vehicle keys from an already opened strict YAML document (all keys at the top level of `y`).
VehicleParams ReadVehicleParams(quad_core::StrictYaml* y);

}  // namespace quad_core
