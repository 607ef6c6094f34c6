#include "quad_policy/config.h"

#include <quad_common/strict_yaml.h>

#include <stdexcept>

namespace quad_policy {

namespace {

PolicyNodeConfig Load(quad_common::StrictYaml y) {
  using quad_common::AtLeast;
  using quad_common::NonNegative;
  using quad_common::Positive;
  PolicyNodeConfig c;
  c.policy_file = y.Get<std::string>("policy_file");
  c.num_threads = y.Get<int>("num_threads", quad_common::InRange(1, 64));
  c.replan_rate_hz = y.Get<double>("replan_rate_hz", NonNegative());
  c.goal_tolerance_m = y.Get<double>("goal_tolerance_m", NonNegative());
  c.max_odom_age_s = y.Get<double>("max_odom_age_s", Positive());
  c.lockstep_consumer = y.Get<std::string>("lockstep_consumer");
  if (c.lockstep_consumer.empty()) {
    throw quad_common::ConfigError(y.source() + ": key 'lockstep_consumer' must not be empty");
  }
  c.send_to_tracker = y.Get<bool>("send_to_tracker");
  const std::string action = y.Get<std::string>("refusal.action");
  if (action == "stop") {
    c.refusal.action = RefusalAction::kStop;
  } else if (action == "hover") {
    c.refusal.action = RefusalAction::kHover;
  } else {
    throw quad_common::ConfigError(y.source() + ": key 'refusal.action' has value '" + action +
                                   "' which must be 'stop' or 'hover'");
  }
  c.refusal.stop_max_decel_mps2 = y.Get<double>("refusal.stop_max_decel_mps2", Positive());
  c.refusal.stop_min_duration_s = y.Get<double>("refusal.stop_min_duration_s", Positive());
  c.recovery.goal_yaw_offsets_deg = y.Get<std::vector<double>>("recovery.goal_yaw_offsets_deg");
  c.recovery.steer_clearance_m = y.Get<double>("recovery.steer_clearance_m", NonNegative());
  c.recovery.turn_after_stops = y.Get<int>("recovery.turn_after_stops", AtLeast(0));
  c.recovery.turn_rate_dps = y.Get<double>("recovery.turn_rate_dps", Positive());
  c.recovery.turn_clearance_m = y.Get<double>("recovery.turn_clearance_m", NonNegative());
  c.recovery.final_approach_m = y.Get<double>("recovery.final_approach_m", NonNegative());
  c.recovery.final_approach_acc_mps2 = y.Get<double>("recovery.final_approach_acc_mps2", Positive());
  c.keeping.commit_s = y.Get<double>("keeping.commit_s", NonNegative());
  c.keeping.on_refusal = y.Get<bool>("keeping.on_refusal");
  c.safety.enabled = y.Get<bool>("safety.enabled");
  c.safety.max_vel_mps = y.Get<double>("safety.max_vel_mps", Positive());
  c.safety.max_acc_mps2 = y.Get<double>("safety.max_acc_mps2", Positive());
  c.safety.max_start_error_m = y.Get<double>("safety.max_start_error_m", Positive());
  c.safety.vehicle_radius_m = y.Get<double>("safety.vehicle_radius_m", Positive());
  c.safety.sample_dt_s = y.Get<double>("safety.sample_dt_s", Positive());
  c.safety.check_horizon_s = y.Get<double>("safety.check_horizon_s", NonNegative());
  c.safety.collision_min_pixels = y.Get<int>("safety.collision_min_pixels", AtLeast(1));
  c.safety.memory_frames = y.Get<int>("safety.memory_frames", quad_common::InRange(0, 64));
  c.safety.memory_spacing_s = y.Get<double>("safety.memory_spacing_s", NonNegative());
  try {
    ValidateRecoveryConfig(c.recovery, c.safety);
    ValidateTurning(c.recovery, c.refusal);
  } catch (const std::invalid_argument& e) {
    throw quad_common::ConfigError(y.source() + ": " + e.what());
  }
  y.CheckAllKeysUsed();
  return c;
}

}  // namespace

PolicyNodeConfig LoadPolicyNodeConfig(const std::string& path) {
  return Load(quad_common::StrictYaml::FromFile(path));
}

PolicyNodeConfig PolicyNodeConfigFromString(const std::string& yaml_text, const std::string& source) {
  return Load(quad_common::StrictYaml::FromString(yaml_text, source));
}

}  // namespace quad_policy
