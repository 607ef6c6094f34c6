#include "kr_tracker/config.h"

#include <quad_core/strict_yaml.h>

namespace kr_tracker {
namespace {

Eigen::Vector3d GetVec3(quad_core::StrictYaml* y, const std::string& key) {
  const auto v = y->Get<std::vector<double>>(key, quad_core::NonNegative());
  if (v.size() != 3) {
    throw quad_core::ConfigError(y->source() + ": key '" + key + "' has " + std::to_string(v.size()) +
                                 " elements, expected 3 (x, y, z)");
  }
  return Eigen::Vector3d(v[0], v[1], v[2]);
}

}  // namespace

TrackerConfig ReadTrackerConfig(quad_core::StrictYaml* y) {
  TrackerConfig c;
  c.gains.kx = GetVec3(y, "controller.kx");
  c.gains.kv = GetVec3(y, "controller.kv");
  c.gains.ki = GetVec3(y, "controller.ki");
  c.gains.max_pos_int_mps2 = y->Get<double>("controller.max_pos_int_mps2", quad_core::NonNegative());
  c.gains.kR = GetVec3(y, "controller.kR");
  c.gains.kOm = GetVec3(y, "controller.kOm");
  c.gains.max_tilt_rad = y->Get<double>("controller.max_tilt_rad", quad_core::InRange(0.05, 1.5));
  c.gains.min_accel_z_mps2 = y->Get<double>("controller.min_accel_z_mps2", quad_core::Positive());
  c.gains.max_thrust_fraction =
      y->Get<double>("controller.max_thrust_fraction", quad_core::InRange(0.1, 1.0));

  c.line.default_max_vel_mps = y->Get<double>("line.default_max_vel_mps", quad_core::Positive());
  c.line.default_max_acc_mps2 = y->Get<double>("line.default_max_acc_mps2", quad_core::Positive());
  c.line.max_yaw_rate_radps = y->Get<double>("line.max_yaw_rate_radps", quad_core::Positive());

  c.bspline.max_start_delay_s = y->Get<double>("bspline.max_start_delay_s", quad_core::NonNegative());
  c.bspline.max_start_age_s = y->Get<double>("bspline.max_start_age_s", quad_core::NonNegative());
  c.bspline.max_start_error_m = y->Get<double>("bspline.max_start_error_m", quad_core::Positive());
  c.bspline.max_yaw_rate_radps = y->Get<double>("bspline.max_yaw_rate_radps", quad_core::Positive());
  c.bspline.min_speed_for_yaw_mps = y->Get<double>("bspline.min_speed_for_yaw_mps", quad_core::NonNegative());
  c.bspline_auto_activate = y->Get<bool>("bspline.auto_activate");

  c.initial_tracker = y->Get<std::string>("node.initial_tracker");
  if (c.initial_tracker != "hover" && c.initial_tracker != "line" && c.initial_tracker != "bspline") {
    throw quad_core::ConfigError(y->source() + ": key 'node.initial_tracker' has value '" +
                                 c.initial_tracker + "' which is not one of hover, line, bspline");
  }
  c.odom_timeout_s = y->Get<double>("node.odom_timeout_s", quad_core::Positive());
  c.watchdog_rate_hz = y->Get<double>("node.watchdog_rate_hz", quad_core::InRange(1.0, 2000.0));
  c.feedback_rate_hz = y->Get<double>("node.feedback_rate_hz", quad_core::InRange(0.1, 1000.0));
  // Optional (GetOr): added after config/tracker.yaml was first written; the default is the documented value.
  c.max_odom_jump_m = y->GetOr<double>("node.max_odom_jump_m", c.max_odom_jump_m, quad_core::Positive());
  y->CheckAllKeysUsed();
  // Cross-field checks of the structs themselves (messages name the field).
  try {
    c.gains.Validate();
    c.line.Validate();
    c.bspline.Validate();
  } catch (const std::invalid_argument& e) {
    throw quad_core::ConfigError(y->source() + ": " + e.what());
  }
  return c;
}

TrackerConfig LoadTrackerConfig(const std::string& yaml_path) {
  quad_core::StrictYaml y = quad_core::StrictYaml::FromFile(yaml_path);
  return ReadTrackerConfig(&y);
}

}  // namespace kr_tracker
