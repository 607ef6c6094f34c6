// Parameters of fast_planner_node: every one is required (no default in code; the values live in the launch
// files and config/planner.yaml), and a missing one is an error naming it.
#pragma once

#include <ros/console.h>
#include <ros/node_handle.h>

#include <cstdio>
#include <memory>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "fast_planner/plan_collector.h"

namespace fast_planner::ros_conv {

// A private parameter that must be set: throws std::runtime_error naming it when it is not, or has another
// type.
template <typename T>
T RequiredParam(const ros::NodeHandle& pnh, const std::string& name) {
  T value{};
  if (!pnh.hasParam(name)) {
    throw std::runtime_error("required parameter " + pnh.resolveName(name) +
                             " is not set (the launch file that starts the node must set it; "
                             "launch/planner.launch shows every one)");
  }
  if (!pnh.getParam(name, value)) {
    throw std::runtime_error("parameter " + pnh.resolveName(name) + " has the wrong type");
  }
  return value;
}

// ~collector_run_info: a mapping of scalars for the dataset manifest's run_info (seeds, episodes, ...). The
// one optional parameter: a launch without run information (il_expert.launch) records none. Throws
// std::runtime_error if it is set but not a mapping.
inline std::vector<std::pair<std::string, std::string>> ReadRunInfo(const ros::NodeHandle& pnh) {
  std::vector<std::pair<std::string, std::string>> out;
  XmlRpc::XmlRpcValue v;
  if (!pnh.getParam("collector_run_info", v)) return out;
  if (v.getType() != XmlRpc::XmlRpcValue::TypeStruct) {
    throw std::runtime_error("~collector_run_info must be a mapping of key: value");
  }
  for (auto it = v.begin(); it != v.end(); ++it) {
    XmlRpc::XmlRpcValue& x = it->second;
    std::string text;
    switch (x.getType()) {
      case XmlRpc::XmlRpcValue::TypeString:
        text = static_cast<std::string>(x);
        break;
      case XmlRpc::XmlRpcValue::TypeInt:
        text = std::to_string(static_cast<int>(x));
        break;
      case XmlRpc::XmlRpcValue::TypeBoolean:
        text = static_cast<bool>(x) ? "true" : "false";
        break;
      case XmlRpc::XmlRpcValue::TypeDouble: {
        char buf[64];
        std::snprintf(buf, sizeof(buf), "%.17g", static_cast<double>(x));
        text = buf;
        break;
      }
      default:
        text = x.toXml();
    }
    out.emplace_back(it->first, text);
  }
  return out;
}

// The embedded data collector from ~collector_output_dir ("" = no recording: nullptr), ~collector_config,
// ~collector_commit ("" = the collector config's software_commit), ~collector_append (collect.launch
// resume:=true, docs/collect.md "Resuming") and ~collector_run_info. Its warnings are logged, throttled.
inline std::shared_ptr<PlanCollector> MakeCollector(const ros::NodeHandle& pnh, double log_throttle_s) {
  const auto out_dir = RequiredParam<std::string>(pnh, "collector_output_dir");
  if (out_dir.empty()) return nullptr;
  // Read in this order, so the first missing one is the one named.
  const auto config = RequiredParam<std::string>(pnh, "collector_config");
  const auto commit = RequiredParam<std::string>(pnh, "collector_commit");
  const bool append = RequiredParam<bool>(pnh, "collector_append");
  return std::make_shared<PlanCollector>(
      config, out_dir, commit, ReadRunInfo(pnh),
      append ? cpp_data_collector::OpenMode::kAppend : cpp_data_collector::OpenMode::kCreate,
      [log_throttle_s](CollectorWarning kind, const std::string& text) {  // one throttle per kind
        if (kind == CollectorWarning::kHeld) {
          ROS_INFO_THROTTLE(log_throttle_s, "fast_planner: %s", text.c_str());
        } else if (kind == CollectorWarning::kNotRecorded) {
          ROS_WARN_THROTTLE(log_throttle_s, "fast_planner: %s", text.c_str());
        } else {
          ROS_WARN_THROTTLE(log_throttle_s, "fast_planner: %s", text.c_str());
        }
      });
}

}  // namespace fast_planner::ros_conv
