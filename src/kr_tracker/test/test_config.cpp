// tracker.yaml loads into the typed config; missing, unknown and out-of-range keys are errors naming the key.
#include <gtest/gtest.h>

#include <fstream>
#include <sstream>

#include <quad_core/strict_yaml.h>

#include "kr_tracker/config.h"

namespace kr_tracker {
namespace {

std::string ReadRepoConfig() {
  std::ifstream f(KR_TRACKER_CONFIG_DIR "/tracker.yaml");
  std::stringstream s;
  s << f.rdbuf();
  return s.str();
}

std::string LoadError(const std::string& text) {
  quad_core::StrictYaml y = quad_core::StrictYaml::FromString(text, "tracker.yaml");
  try {
    ReadTrackerConfig(&y);
  } catch (const quad_core::ConfigError& e) {
    return e.what();
  }
  return "";
}

std::string Replace(std::string text, const std::string& from, const std::string& to) {
  const size_t pos = text.find(from);
  EXPECT_NE(pos, std::string::npos) << from;
  return text.replace(pos, from.size(), to);
}

TEST(TrackerConfig, RepositoryFileLoadsWithKrMavControlDefaultGains) {
  const TrackerConfig c = LoadTrackerConfig(KR_TRACKER_CONFIG_DIR "/tracker.yaml");
  EXPECT_TRUE(c.gains.kx.isApprox(Eigen::Vector3d(7.4, 7.4, 10.4)));
  EXPECT_TRUE(c.gains.kv.isApprox(Eigen::Vector3d(4.8, 4.8, 6.0)));
  EXPECT_TRUE(c.gains.kR.isApprox(Eigen::Vector3d(1.5, 1.5, 1.0)));
  EXPECT_TRUE(c.gains.kOm.isApprox(Eigen::Vector3d(0.13, 0.13, 0.1)));
  EXPECT_EQ(c.initial_tracker, "hover");
}

TEST(TrackerConfig, MissingUnknownAndOutOfRangeKeysAreNamed) {
  const std::string base = ReadRepoConfig();
  EXPECT_EQ(LoadError(base), "");
  EXPECT_NE(LoadError(Replace(base, "  kOm: [", "  kOmega: [")).find("missing required key 'controller.kOm'"),
            std::string::npos);
  EXPECT_NE(LoadError(base + "extra_key: 1\n").find("unknown config key(s): 'extra_key'"), std::string::npos);
  EXPECT_NE(LoadError(Replace(base, "kx: [7.4, 7.4, 10.4]", "kx: [7.4, 7.4]"))
                .find("key 'controller.kx' has 2 elements, expected 3"),
            std::string::npos);
  EXPECT_NE(LoadError(Replace(base, "kv: [4.8, 4.8, 6.0]", "kv: [4.8, -4.8, 6.0]")).find("controller.kv"),
            std::string::npos);
  EXPECT_NE(LoadError(Replace(base, "odom_timeout_s: 0.1", "odom_timeout_s: 0")).find("node.odom_timeout_s"),
            std::string::npos);
  EXPECT_NE(LoadError(Replace(base, "initial_tracker: hover", "initial_tracker: mpc"))
                .find("'node.initial_tracker' has value 'mpc'"),
            std::string::npos);
}

TEST(TrackerConfig, OdometryJumpLimitIsOptionalAndChecked) {
  // The repository file without the key (whether or not it has it): the documented default.
  std::istringstream lines(ReadRepoConfig());
  std::string without, line;
  while (std::getline(lines, line)) {
    if (line.find("max_odom_jump_m") == std::string::npos) without += line + "\n";
  }
  quad_core::StrictYaml y0 = quad_core::StrictYaml::FromString(without, "tracker.yaml");
  EXPECT_DOUBLE_EQ(ReadTrackerConfig(&y0).max_odom_jump_m, 1.0);
  auto with_value = [&](const std::string& v) {
    return Replace(without, "node:\n", "node:\n  max_odom_jump_m: " + v + "\n");
  };
  quad_core::StrictYaml y1 = quad_core::StrictYaml::FromString(with_value("2.5"), "tracker.yaml");
  EXPECT_DOUBLE_EQ(ReadTrackerConfig(&y1).max_odom_jump_m, 2.5);
  for (const char* bad : {"0", "-1"}) {
    const std::string why = LoadError(with_value(bad));
    EXPECT_NE(why.find("node.max_odom_jump_m"), std::string::npos) << why;
  }
}

}  // namespace
}  // namespace kr_tracker
