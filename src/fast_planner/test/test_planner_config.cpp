#include <gtest/gtest.h>
#include <quad_core/strict_yaml.h>

#include <fstream>
#include <sstream>
#include <string>

#include "fast_planner/planner_config.h"

namespace fast_planner {
namespace {

std::string DefaultYaml() {
  std::ifstream in(PLANNER_CONFIG_PATH);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

PlannerConfig FromText(const std::string& text) {
  quad_core::StrictYaml y = quad_core::StrictYaml::FromString(text, "planner.yaml");
  return ReadPlannerConfig(y);
}

// Replaces the first occurrence of `from` in the default file (which must exist) by `to`.
std::string Edited(const std::string& from, const std::string& to) {
  std::string t = DefaultYaml();
  const size_t pos = t.find(from);
  EXPECT_NE(pos, std::string::npos) << from;
  return pos == std::string::npos ? t : t.replace(pos, from.size(), to);
}

void ExpectConfigError(const std::string& text, const std::string& fragment) {
  try {
    FromText(text);
    FAIL() << "expected a ConfigError containing: " << fragment;
  } catch (const quad_core::ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find(fragment), std::string::npos) << e.what();
  }
}

TEST(PlannerConfigTest, DefaultFileHasThePaperDefaults) {
  const PlannerConfig c = LoadPlannerConfig(PLANNER_CONFIG_PATH);
  EXPECT_EQ(c.limits.max_vel_mps, 3.0);
  EXPECT_EQ(c.limits.max_acc_mps2, 2.0);
  EXPECT_EQ(c.map.resolution_m, 0.1);
  EXPECT_EQ(c.optimizer.ctrl_pt_dist_m, 0.5);
  EXPECT_EQ(c.map.source, MapSource::kDepth);
  EXPECT_TRUE(c.fsm.replan_final_approach);  // ours, for datasets that cover the final approach
}

// The node's settings were parameter defaults in the node's code; they are required keys now.
TEST(PlannerConfigTest, NodeSettingsAreRequiredKeysOfTheFile) {
  const PlannerConfig c = LoadPlannerConfig(PLANNER_CONFIG_PATH);
  EXPECT_EQ(c.node.odom_period_s, 0.005);
  EXPECT_EQ(c.node.tracker_accept_timeout_s, 1.0);
  EXPECT_EQ(c.node.label_acc_window_s, 0.05);
  EXPECT_EQ(c.node.collector_stats_period_s, 30.0);
  EXPECT_EQ(FromText(Edited("label_acc_window_s: 0.05", "label_acc_window_s: 0")).node.label_acc_window_s,
            0.0);
  ExpectConfigError(Edited("  tracker_accept_timeout_s: 1.0", "  #"),
                    "missing required key 'node.tracker_accept_timeout_s'");
  ExpectConfigError(Edited("label_acc_window_s: 0.05", "label_acc_window_s: -0.1"),
                    "node.label_acc_window_s");
  ExpectConfigError(Edited("odom_period_s: 0.005", "odom_period_s: 0"), "node.odom_period_s");
}

TEST(PlannerConfigTest, FinalApproachSwitchIsABoolean) {
  EXPECT_FALSE(FromText(Edited("replan_final_approach: true", "replan_final_approach: false"))
                   .fsm.replan_final_approach);
  ExpectConfigError(Edited("replan_final_approach: true", "replan_final_approach: 2"),
                    "fsm.replan_final_approach");
  ExpectConfigError(Edited("  replan_final_approach: true", "  #"),
                    "missing required key 'fsm.replan_final_approach'");
}

TEST(PlannerConfigTest, UnknownKeyIsAnErrorNamingIt) {
  ExpectConfigError(Edited("  max_acc_mps2: 2.0", "  max_acc_mps2: 2.0\n  max_jerk_mps3: 4.0"),
                    "unknown config key(s): 'limits.max_jerk_mps3'");
}

TEST(PlannerConfigTest, MissingKeyIsAnErrorNamingIt) {
  ExpectConfigError(Edited("  horizon_m: 5.0", "  #"), "missing required key 'search.horizon_m'");
}

TEST(PlannerConfigTest, OutOfRangeValuesAreErrorsNamingKeyAndValue) {
  ExpectConfigError(Edited("max_vel_mps: 3.0", "max_vel_mps: -1.0"), "'limits.max_vel_mps' has value -1.0");
  ExpectConfigError(Edited("acc_levels_per_axis: 5", "acc_levels_per_axis: 4"),
                    "'search.acc_levels_per_axis' has value 4 which must be odd");
  ExpectConfigError(Edited("source: depth", "source: lidar"), "'map.source' has value 'lidar'");
  ExpectConfigError(Edited("resolution_m: 0.1", "resolution_m: .nan"),
                    "'map.resolution_m' has non-finite value");
  ExpectConfigError(Edited("size_m: [50.0, 50.0, 6.5]", "size_m: [50.0, 50.0]"),
                    "'map.size_m' must be a list of 3 numbers");
  ExpectConfigError(Edited("ceiling_z_m: 5.5", "ceiling_z_m: 0.2"), "'map.ceiling_z_m' has value 0.2");
}

TEST(PlannerConfigTest, HorizonBeyondTheLocalWindowIsRejectedForTheDepthSource) {
  const std::string text = Edited("horizon_m: 5.0", "horizon_m: 9.0");
  ExpectConfigError(text, "'search.horizon_m' has value 9 which must be <= min(map.local_update_range_m");
  // With the global map the ESDF covers the whole map: any horizon is fine.
  std::string global = text;
  global.replace(global.find("source: depth"), 13, "source: global");
  EXPECT_EQ(FromText(global).search.horizon_m, 9.0);
}

TEST(PlannerConfigTest, HandBuiltConfigsAreValidatedToo) {
  PlannerConfig c;
  EXPECT_NO_THROW(ValidatePlannerConfig(c));
  c.search.collision_step_m = 0.5;  // coarser than a voxel: thin obstacles could be skipped
  try {
    ValidatePlannerConfig(c);
    FAIL();
  } catch (const quad_core::ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("search.collision_step_m"), std::string::npos);
  }
}

}  // namespace
}  // namespace fast_planner
