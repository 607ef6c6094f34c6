// Required ROS parameters: no default in node code (docs/CONVENTIONS.md, Configuration). A missing or
// mistyped parameter is an error naming its resolved key.
#pragma once

#include <ros/ros.h>

#include <stdexcept>
#include <string>

namespace quad_sim_ros {

template <typename T>
T RequireParam(const ros::NodeHandle& nh, const std::string& key) {
  T value;
  const std::string name = nh.resolveName(key);
  if (!nh.hasParam(key)) throw std::runtime_error("missing required parameter " + name);
  if (!nh.getParam(key, value)) throw std::runtime_error("parameter " + name + " has the wrong type");
  return value;
}

}  // namespace quad_sim_ros
