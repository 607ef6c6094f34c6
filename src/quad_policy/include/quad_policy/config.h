// config/policy.yaml, the configuration of both policy nodes (the Python node loads it through the bindings;
// docs/inference.md lists every key). Loaded strictly: a missing or unknown key, a wrong type or an
// out-of-range value is a quad_core::ConfigError naming the file, the key and the value.
//
// Overlays: a variant holds only the keys it changes and names its base with `overlay_of: PATH` (relative to
// the overlay's directory; a base may itself be an overlay). The rule is quad_il.tools.config_overlay's:
// every key of the overlay must exist in its base with the same kind of value (a section stays a section); a
// section merges key by key, any other value (lists included) replaces the base's.
#pragma once

#include <yaml-cpp/yaml.h>

#include <string>

#include "quad_policy/policy_decider.h"
#include "quad_policy/safety.h"

namespace quad_policy {

struct PolicyNodeConfig {
  std::string policy_file;      // exported policy (policy.ts); the node's ~policy_file parameter overrides it
  int num_threads = 1;          // LibTorch intra-op threads (Python: torch.set_num_threads)
  double replan_rate_hz = 0.0;  // 0: decide on every depth frame; > 0: at most this often (sim time)
  double goal_tolerance_m = 0.5;  // no new plans within this distance of the goal
  double max_odom_age_s = 0.1;    // odometry older than this at the depth stamp: no decision (counted)
  double odom_period_s = 0.005;   // the simulator's odometry period (the frame/odometry pairing rule)
  double odom_wait_s = 0.2;       // wall-time bound on waiting for a frame's own odometry
  double tracker_accept_timeout_s = 1.0;  // wall-time bound on waiting for the tracker to take a trajectory
  std::string lockstep_consumer = "policy";  // FrameAck.consumer of every depth frame
  bool send_to_tracker = true;  // send trajectories to the tracker action (else only publish them)
  RefusalConfig refusal;
  RecoveryConfig recovery;
  KeepingConfig keeping;
  SafetyConfig safety;
};

// Throws quad_core::ConfigError.
PolicyNodeConfig LoadPolicyNodeConfig(const std::string& path);
// A complete config (no overlay_of) from YAML text; `source` names it in errors.
PolicyNodeConfig PolicyNodeConfigFromString(const std::string& yaml_text, const std::string& source);
// The complete YAML tree of a file: the file itself, or its base's tree with the overlay's keys set. Throws
// quad_core::ConfigError (unreadable file, cycle, a key the base does not have).
YAML::Node LoadOverlayTree(const std::string& path);

}  // namespace quad_policy
