// Typed configuration of the tracker node (config/tracker.yaml), loaded strictly: missing or unknown keys and
// out-of-range values throw quad_core::ConfigError naming the key and value. Mass and gravity are NOT here:
// they come from config/vehicle.yaml through quad_core::LoadVehicleParams, the file the simulator flies with.
#pragma once

#include <string>

#include "kr_tracker/bspline_tracker.h"
#include "kr_tracker/line_tracker.h"
#include "kr_tracker/so3_controller.h"

namespace quad_core {
class StrictYaml;
}

namespace kr_tracker {

struct TrackerConfig {
  So3Gains gains;
  LineTrackerConfig line;
  BsplineTrackerConfig bspline;
  // Node behaviour.
  std::string initial_tracker = "hover";  // tracker active at start-up: hover, line or bspline
  double odom_timeout_s = 0.1;            // odometry older than this is stale: the last safe command is held
  double watchdog_rate_hz = 200.0;        // rate of the stale-odometry check and of the held command
  double feedback_rate_hz = 20.0;         // TrackBspline feedback rate
  bool bspline_auto_activate = true;      // accepting a TrackBspline goal switches to the B-spline tracker
  // Safety net for resets the node does not hear about on /sim/status: odometry that moves farther than this
  // in one message re-anchors the trackers (docs/kr_tracker.md, "Episode resets"). Optional key, default 1 m.
  double max_odom_jump_m = 1.0;
};

TrackerConfig LoadTrackerConfig(const std::string& yaml_path);
TrackerConfig ReadTrackerConfig(quad_core::StrictYaml* y);

}  // namespace kr_tracker
