#include "quad_core/vehicle_params.h"

#include <quad_core/strict_yaml.h>

#include <Eigen/LU>

#include <cmath>
#include <sstream>
#include <stdexcept>

namespace quad_core {

namespace {

Eigen::Vector3d ReadVector3(quad_core::StrictYaml* y, const std::string& key, const quad_core::Check& check) {
  const std::vector<double> v = y->Get<std::vector<double>>(key, check);
  if (v.size() != 3) {
    throw quad_core::ConfigError(y->source() + ": key '" + key + "' must be a list of 3 numbers, got " +
                                 std::to_string(v.size()));
  }
  return Eigen::Vector3d(v[0], v[1], v[2]);
}

void Require(bool ok, const std::string& field, double value, const std::string& why) {
  if (ok) return;
  std::ostringstream s;
  s << "VehicleParams: " << field << " = " << value << " " << why;
  throw std::invalid_argument(s.str());
}

}  // namespace

const char* ToString(FrameLayout layout) {
  switch (layout) {
    case FrameLayout::kX:
      return "x";
    case FrameLayout::kPlus:
      return "plus";
  }
  return "unknown";
}

double VehicleParams::HoverMotorSpeedRadps() const {
  return std::sqrt(HoverThrustN() / (4.0 * thrust_coeff_N_per_radps2));
}

std::array<Eigen::Vector3d, 4> VehicleParams::RotorPositionsBody() const {
  const double a = arm_length_m;
  if (frame_layout == FrameLayout::kPlus) {
    // front, left, back, right
    return {Eigen::Vector3d(a, 0, 0), Eigen::Vector3d(0, a, 0), Eigen::Vector3d(-a, 0, 0),
            Eigen::Vector3d(0, -a, 0)};
  }
  const double d = a / std::sqrt(2.0);
  // front-left, back-left, back-right, front-right
  return {Eigen::Vector3d(d, d, 0), Eigen::Vector3d(-d, d, 0), Eigen::Vector3d(-d, -d, 0),
          Eigen::Vector3d(d, -d, 0)};
}

std::array<double, 4> VehicleParams::RotorSpinDirections() const {
  // Diagonally opposite rotors spin the same way so that yaw torques cancel at hover.
  return {1.0, -1.0, 1.0, -1.0};
}

Eigen::Matrix4d VehicleParams::Mixer() const {
  const auto r = RotorPositionsBody();
  const auto spin = RotorSpinDirections();
  Eigen::Matrix4d m;
  for (int i = 0; i < 4; ++i) {
    // Thrust f_i = kf w^2 along body +z at r_i gives moment r_i x (0, 0, f_i) = (y_i f_i, -x_i f_i, 0); a
    // rotor spinning counter-clockwise (spin +1) pushes the body clockwise: -km w^2 about z.
    m(0, i) = thrust_coeff_N_per_radps2;
    m(1, i) = r[i].y() * thrust_coeff_N_per_radps2;
    m(2, i) = -r[i].x() * thrust_coeff_N_per_radps2;
    m(3, i) = -spin[i] * torque_coeff_Nm_per_radps2;
  }
  return m;
}

void VehicleParams::Validate() const {
  Require(std::isfinite(mass_kg) && mass_kg > 0, "mass_kg", mass_kg, "must be > 0");
  Require(std::isfinite(gravity_mps2) && gravity_mps2 > 0, "gravity_mps2", gravity_mps2, "must be > 0");
  for (int i = 0; i < 3; ++i) {
    Require(std::isfinite(inertia_kgm2(i, i)) && inertia_kgm2(i, i) > 0, "inertia_kgm2 diagonal",
            inertia_kgm2(i, i), "must be > 0");
  }
  Require(inertia_kgm2.allFinite() && (inertia_kgm2 - inertia_kgm2.transpose()).norm() < 1e-12,
          "inertia_kgm2", inertia_kgm2.norm(), "must be finite and symmetric");
  Require(std::isfinite(arm_length_m) && arm_length_m > 0, "arm_length_m", arm_length_m, "must be > 0");
  Require(std::isfinite(thrust_coeff_N_per_radps2) && thrust_coeff_N_per_radps2 > 0,
          "thrust_coeff_N_per_radps2", thrust_coeff_N_per_radps2, "must be > 0");
  Require(std::isfinite(torque_coeff_Nm_per_radps2) && torque_coeff_Nm_per_radps2 > 0,
          "torque_coeff_Nm_per_radps2", torque_coeff_Nm_per_radps2, "must be > 0");
  Require(std::isfinite(motor_time_constant_s) && motor_time_constant_s > 0, "motor_time_constant_s",
          motor_time_constant_s, "must be > 0");
  Require(std::isfinite(min_motor_speed_radps) && min_motor_speed_radps >= 0, "min_speed_radps",
          min_motor_speed_radps, "must be >= 0");
  Require(std::isfinite(max_motor_speed_radps) && max_motor_speed_radps > min_motor_speed_radps,
          "max_speed_radps", max_motor_speed_radps, "must be > min_speed_radps");
  Require(MaxThrustN() > HoverThrustN(), "max_speed_radps", max_motor_speed_radps,
          "gives a maximum thrust below the weight: the vehicle cannot hover");
  for (int i = 0; i < 3; ++i) {
    Require(std::isfinite(drag_coeff_Ns_per_m[i]) && drag_coeff_Ns_per_m[i] >= 0, "drag_coeff_Ns_per_m",
            drag_coeff_Ns_per_m[i], "must be >= 0");
    Require(std::isfinite(collision_box_m[i]) && collision_box_m[i] > 0, "collision_box_m",
            collision_box_m[i], "must be > 0");
  }
}

VehicleParams ReadVehicleParams(quad_core::StrictYaml* y) {
  using quad_core::NonNegative;
  using quad_core::Positive;
  VehicleParams p;
  p.mass_kg = y->Get<double>("mass_kg", Positive());
  p.gravity_mps2 = y->Get<double>("gravity_mps2", Positive());
  p.inertia_kgm2 = ReadVector3(y, "inertia_kgm2", Positive()).asDiagonal();
  p.arm_length_m = y->Get<double>("arm_length_m", Positive());
  const std::string layout = y->Get<std::string>("frame_layout");
  if (layout == "x") {
    p.frame_layout = FrameLayout::kX;
  } else if (layout == "plus") {
    p.frame_layout = FrameLayout::kPlus;
  } else {
    throw quad_core::ConfigError(y->source() + ": key 'frame_layout' has value '" + layout +
                                 "' which is not one of 'x', 'plus'");
  }
  p.thrust_coeff_N_per_radps2 = y->Get<double>("rotor.thrust_coeff_N_per_radps2", Positive());
  p.torque_coeff_Nm_per_radps2 = y->Get<double>("rotor.torque_coeff_Nm_per_radps2", Positive());
  p.motor_time_constant_s = y->Get<double>("rotor.motor_time_constant_s", Positive());
  p.min_motor_speed_radps = y->Get<double>("rotor.min_speed_radps", NonNegative());
  p.max_motor_speed_radps = y->Get<double>("rotor.max_speed_radps", Positive());
  p.drag_coeff_Ns_per_m = ReadVector3(y, "drag_coeff_Ns_per_m", NonNegative());
  p.collision_box_m = ReadVector3(y, "collision_box_m", Positive());
  try {
    p.Validate();
  } catch (const std::invalid_argument& e) {
    throw quad_core::ConfigError(y->source() + ": " + e.what());
  }
  return p;
}

VehicleParams LoadVehicleParams(const std::string& yaml_path) {
  quad_core::StrictYaml y = quad_core::StrictYaml::FromFile(yaml_path);
  VehicleParams p = ReadVehicleParams(&y);
  y.CheckAllKeysUsed();
  return p;
}

}  // namespace quad_core
