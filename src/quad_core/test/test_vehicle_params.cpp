#include "quad_core/vehicle_params.h"

#include "test_util.h"

#include <gtest/gtest.h>
#include <quad_core/strict_yaml.h>

#include <Eigen/Geometry>
#include <Eigen/LU>

#include <regex>
#include <string>

using quad_core::LoadVehicleParams;
using quad_core::VehicleParams;
using quad_core_test::ReadFile;
using quad_core_test::RepoPath;
using quad_core_test::TempFile;

namespace {

std::string VehicleYaml() { return ReadFile(RepoPath("config/vehicle.yaml")); }

// Expects loading `text` to throw a ConfigError whose message contains `needle`.
void ExpectConfigError(const std::string& text, const std::string& needle) {
  TempFile f(".yaml");
  f.Write(text);
  try {
    LoadVehicleParams(f.path());
    FAIL() << "expected a ConfigError mentioning '" << needle << "'";
  } catch (const quad_core::ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
  }
}

}  // namespace

TEST(VehicleParams, DefaultFileLoadsFalcon250Values) {
  const VehicleParams p = quad_core_test::DefaultVehicle();
  EXPECT_DOUBLE_EQ(p.mass_kg, 0.75);
  EXPECT_DOUBLE_EQ(p.gravity_mps2, 9.81);
  EXPECT_DOUBLE_EQ(p.inertia_kgm2(0, 0), 2.5e-3);
  EXPECT_DOUBLE_EQ(p.inertia_kgm2(2, 2), 4.3e-3);
  EXPECT_DOUBLE_EQ(p.inertia_kgm2(0, 1), 0.0);
  EXPECT_EQ(p.collision_box_m, Eigen::Vector3d(0.25, 0.25, 0.25));
  EXPECT_EQ(p.frame_layout, quad_core::FrameLayout::kX);
  EXPECT_GT(p.MaxThrustN(), 2.0 * p.HoverThrustN());
}

TEST(VehicleParams, HoverSpeedGivesWeight) {
  const VehicleParams p = quad_core_test::DefaultVehicle();
  const double w = p.HoverMotorSpeedRadps();
  EXPECT_NEAR(4.0 * p.thrust_coeff_N_per_radps2 * w * w, p.mass_kg * p.gravity_mps2, 1e-12);
}

TEST(VehicleParams, MixerMapsEachRotorToItsLeverArm) {
  for (const auto layout : {quad_core::FrameLayout::kX, quad_core::FrameLayout::kPlus}) {
    VehicleParams p = quad_core_test::DefaultVehicle();
    p.frame_layout = layout;
    const Eigen::Matrix4d m = p.Mixer();
    const auto r = p.RotorPositionsBody();
    const auto spin = p.RotorSpinDirections();
    for (int i = 0; i < 4; ++i) {
      // Moment of rotor i's unit-speed thrust computed as r x F independently of the mixer.
      const Eigen::Vector3d f(0, 0, p.thrust_coeff_N_per_radps2);
      const Eigen::Vector3d moment = r[i].cross(f);
      EXPECT_NEAR(m(0, i), p.thrust_coeff_N_per_radps2, 1e-18);
      EXPECT_NEAR(m(1, i), moment.x(), 1e-15);
      EXPECT_NEAR(m(2, i), moment.y(), 1e-15);
      EXPECT_NEAR(m(3, i), -spin[i] * p.torque_coeff_Nm_per_radps2, 1e-18);
      EXPECT_NEAR(r[i].norm(), p.arm_length_m, 1e-12);
    }
    // Invertible, and equal speeds give pure thrust.
    EXPECT_GT(std::abs(m.determinant()), 0.0);
    const Eigen::Vector4d fm = m * Eigen::Vector4d::Constant(1000.0 * 1000.0);
    EXPECT_NEAR(fm.tail<3>().norm(), 0.0, 1e-12);
  }
}

TEST(VehicleParams, MissingKeyIsNamed) {
  const std::string text = std::regex_replace(VehicleYaml(), std::regex("\nmass_kg: [^\n]*"), "");
  ExpectConfigError(text, "missing required key 'mass_kg'");
}

TEST(VehicleParams, UnknownKeyIsNamed) {
  ExpectConfigError(VehicleYaml() + "\nmass_kgg: 0.7\n", "'mass_kgg'");
}

TEST(VehicleParams, MisspeltNestedKeyIsNamed) {
  const std::string text =
      std::regex_replace(VehicleYaml(), std::regex("motor_time_constant_s"), "motor_time_const_s");
  ExpectConfigError(text, "rotor.motor_time_constant_s");
}

TEST(VehicleParams, OutOfRangeValueIsNamed) {
  const std::string text = std::regex_replace(VehicleYaml(), std::regex("mass_kg: 0.75"), "mass_kg: -1.0");
  ExpectConfigError(text, "'mass_kg' has value -1.0");
}

TEST(VehicleParams, UnknownLayoutIsNamed) {
  const std::string text =
      std::regex_replace(VehicleYaml(), std::regex("frame_layout: x"), "frame_layout: h");
  ExpectConfigError(text, "'frame_layout' has value 'h'");
}

TEST(VehicleParams, TooWeakMotorsAreRejected) {
  const std::string text =
      std::regex_replace(VehicleYaml(), std::regex("max_speed_radps: 3000.0"), "max_speed_radps: 1000.0");
  ExpectConfigError(text, "cannot hover");
}

TEST(VehicleParams, WrongVectorLengthIsNamed) {
  const std::string text = std::regex_replace(
      VehicleYaml(), std::regex("collision_box_m: \\[0.25, 0.25, 0.25\\]"), "collision_box_m: [0.25, 0.25]");
  ExpectConfigError(text, "'collision_box_m' must be a list of 3 numbers");
}
