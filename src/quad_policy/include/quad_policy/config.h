// config/policy.yaml, shared by the C++ and the Python policy nodes (docs/inference.md lists every key).
// Loaded strictly: a missing or unknown key, a wrong type or an out-of-range value is a
// quad_common::ConfigError naming the key and the value. The Python twin is quad_il/inference/config.py
// (pydantic, extra="forbid").
#pragma once

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
  std::string lockstep_consumer = "policy";  // FrameAck.consumer of every depth frame
  bool send_to_tracker = true;  // send trajectories to the tracker action (else only publish them)
  RefusalConfig refusal;
  RecoveryConfig recovery;
  KeepingConfig keeping;
  SafetyConfig safety;
};

// Throws quad_common::ConfigError.
PolicyNodeConfig LoadPolicyNodeConfig(const std::string& path);
PolicyNodeConfig PolicyNodeConfigFromString(const std::string& yaml_text, const std::string& source);

}  // namespace quad_policy
