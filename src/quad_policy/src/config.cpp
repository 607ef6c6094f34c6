#include "quad_policy/config.h"

#include <quad_core/strict_yaml.h>

#include <filesystem>
#include <stdexcept>
#include <vector>

namespace quad_policy {

namespace {

constexpr const char* kOverlayKey = "overlay_of";

PolicyNodeConfig Load(quad_core::StrictYaml y) {
  using quad_core::AtLeast;
  using quad_core::NonNegative;
  using quad_core::Positive;
  PolicyNodeConfig c;
  c.policy_file = y.Get<std::string>("policy_file");
  c.num_threads = y.Get<int>("num_threads", quad_core::InRange(1, 64));
  c.replan_rate_hz = y.Get<double>("replan_rate_hz", NonNegative());
  c.goal_tolerance_m = y.Get<double>("goal_tolerance_m", NonNegative());
  c.max_odom_age_s = y.Get<double>("max_odom_age_s", Positive());
  c.odom_period_s = y.Get<double>("odom_period_s", Positive());
  c.odom_wait_s = y.Get<double>("odom_wait_s", Positive());
  c.tracker_accept_timeout_s = y.Get<double>("tracker_accept_timeout_s", Positive());
  c.lockstep_consumer = y.Get<std::string>("lockstep_consumer");
  if (c.lockstep_consumer.empty()) {
    throw quad_core::ConfigError(y.source() + ": key 'lockstep_consumer' must not be empty");
  }
  c.send_to_tracker = y.Get<bool>("send_to_tracker");
  const std::string action = y.Get<std::string>("refusal.action");
  if (action == "stop") {
    c.refusal.action = RefusalAction::kStop;
  } else if (action == "hover") {
    c.refusal.action = RefusalAction::kHover;
  } else {
    throw quad_core::ConfigError(y.source() + ": key 'refusal.action' has value '" + action +
                                 "' which must be 'stop' or 'hover'");
  }
  c.refusal.stop_max_decel_mps2 = y.Get<double>("refusal.stop_max_decel_mps2", Positive());
  c.refusal.stop_min_duration_s = y.Get<double>("refusal.stop_min_duration_s", Positive());
  c.recovery.goal_yaw_offsets_deg = y.Get<std::vector<double>>("recovery.goal_yaw_offsets_deg");
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
  try {
    ValidateRecoveryConfig(c.recovery);
  } catch (const std::invalid_argument& e) {
    throw quad_core::ConfigError(y.source() + ": " + e.what());
  }
  y.CheckAllKeysUsed();
  return c;
}

// `overlay` over `base` (both mappings), keys checked against the base; `name` is the key path so far.
void MergeInto(YAML::Node base, const YAML::Node& overlay, const std::string& source,
               const std::string& prefix) {
  for (const auto& kv : overlay) {
    const std::string key = kv.first.as<std::string>();
    const std::string name = prefix + key;
    if (!base[key])
      throw quad_core::ConfigError(source + ": key '" + name + "' does not exist in the base config");
    const bool base_map = base[key].IsMap(), overlay_map = kv.second.IsMap();
    if (base_map != overlay_map) {
      throw quad_core::ConfigError(source + ": key '" + name + "' is " +
                                   (base_map ? "a section" : "a value") +
                                   " in the base config, the overlay gives " + YAML::Dump(kv.second));
    }
    if (overlay_map) {
      MergeInto(base[key], kv.second, source, name + ".");
    } else {
      base[key] = YAML::Clone(kv.second);
    }
  }
}

YAML::Node LoadTree(const std::filesystem::path& path, std::vector<std::filesystem::path>* seen) {
  const std::filesystem::path canonical = std::filesystem::weakly_canonical(path);
  for (const auto& s : *seen) {
    if (s == canonical) throw quad_core::ConfigError("overlay cycle: " + path.string() + " is its own base");
  }
  seen->push_back(canonical);
  YAML::Node tree;
  try {
    tree = YAML::LoadFile(path.string());
  } catch (const YAML::BadFile&) {
    throw quad_core::ConfigError(path.string() + ": cannot open config file");
  } catch (const YAML::ParserException& e) {
    throw quad_core::ConfigError(path.string() + ": YAML syntax error: " + e.what());
  }
  if (tree.IsNull()) tree = YAML::Node(YAML::NodeType::Map);
  if (!tree.IsMap())
    throw quad_core::ConfigError(path.string() + ": top level must be a mapping of keys to values");
  if (!tree[kOverlayKey]) return tree;
  const YAML::Node ref = tree[kOverlayKey];
  if (!ref.IsScalar() || ref.as<std::string>().empty()) {
    throw quad_core::ConfigError(path.string() + ": '" + kOverlayKey +
                                 "' must be the path of the base config");
  }
  std::filesystem::path base_path = ref.as<std::string>();
  if (base_path.is_relative()) base_path = canonical.parent_path() / base_path;
  YAML::Node merged = YAML::Clone(LoadTree(base_path, seen));
  YAML::Node overlay = YAML::Clone(tree);
  overlay.remove(kOverlayKey);
  MergeInto(merged, overlay, path.string() + " (overlay of " + base_path.string() + ")", "");
  return merged;
}

}  // namespace

YAML::Node LoadOverlayTree(const std::string& path) {
  std::vector<std::filesystem::path> seen;
  return LoadTree(path, &seen);
}

PolicyNodeConfig LoadPolicyNodeConfig(const std::string& path) {
  const YAML::Node tree = LoadOverlayTree(path);
  const bool overlay = YAML::LoadFile(path)[kOverlayKey].IsDefined();
  return Load(quad_core::StrictYaml(tree, overlay ? path + " (merged over its base)" : path));
}

PolicyNodeConfig PolicyNodeConfigFromString(const std::string& yaml_text, const std::string& source) {
  return Load(quad_core::StrictYaml::FromString(yaml_text, source));
}

}  // namespace quad_policy
