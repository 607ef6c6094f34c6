#include <gtest/gtest.h>

#include <string>

#include "cpp_data_collector/writer_config.h"

namespace cdc = cpp_data_collector;

namespace {

cdc::WriterConfig Load(const std::string& text) {
  quad_core::StrictYaml y = quad_core::StrictYaml::FromString(text, "collector.yaml");
  cdc::WriterConfig c = cdc::LoadWriterConfig(&y, "collector");
  y.CheckAllKeysUsed();
  return c;
}

void ExpectConfigError(const std::string& text, const std::string& needle) {
  try {
    Load(text);
    FAIL() << "no error, expected: " << needle;
  } catch (const quad_core::ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
  }
}

TEST(WriterConfig, LoadsASectionWithDefaults) {
  const cdc::WriterConfig c = Load("collector: {output_dir: /tmp/x, image_width: 320, image_height: 240}");
  EXPECT_EQ(c.output_dir, "/tmp/x");
  EXPECT_EQ(c.image_width, 320u);
  EXPECT_EQ(c.shard_size_mb, 256.0);
  EXPECT_EQ(c.queue_capacity, 32u);
  EXPECT_EQ(c.full_queue_policy, cdc::FullQueuePolicy::kBlock);
  EXPECT_EQ(c.max_ctrl_pts, 128u);
  EXPECT_TRUE(c.fsync);
}

TEST(WriterConfig, LoadsEveryKey) {
  const cdc::WriterConfig c = Load(
      "collector:\n  output_dir: d\n  image_width: 64\n  image_height: 48\n  shard_size_mb: 8\n"
      "  queue_capacity: 4\n  full_queue_policy: drop\n  max_ctrl_pts: 40\n  max_yaw_pts: 0\n  fsync: false\n"
      "  software_commit: abc\n  camera: {fx_px: 1, fy_px: 2, cx_px: 3, cy_px: 4}\n");
  EXPECT_EQ(c.full_queue_policy, cdc::FullQueuePolicy::kDrop);
  EXPECT_EQ(c.queue_capacity, 4u);
  EXPECT_EQ(c.max_yaw_pts, 0u);
  EXPECT_FALSE(c.fsync);
  EXPECT_EQ(c.software_commit, "abc");
  EXPECT_EQ(c.camera_cy_px, 4.0);
}

TEST(WriterConfig, ErrorsNameTheKeyAndValue) {
  ExpectConfigError("collector: {image_width: 320, image_height: 240}",
                    "missing required key 'collector.output_dir'");
  ExpectConfigError(
      "collector: {output_dir: d, image_width: 320, image_height: 240, full_queue_policy: wait}",
      "key 'collector.full_queue_policy' has value 'wait' which is not one of: block, drop");
  ExpectConfigError("collector: {output_dir: d, image_width: 320, image_height: 240, shard_size_mb: -1}",
                    "key 'collector.shard_size_mb' has value -1 which must be > 0");
  ExpectConfigError("collector: {output_dir: d, image_width: 320, image_height: 240, queue_capacity: 0}",
                    "'collector.queue_capacity' has value 0");
  ExpectConfigError("collector: {output_dir: d, image_width: 320, image_height: 240, shard_sise_mb: 4}",
                    "unknown config key(s): 'collector.shard_sise_mb'");
}

TEST(WriterConfig, TheShippedFileHoldsTheDefaultsButYawPoints) {
  // config/collector.yaml, the one writer config of the project (collect.launch, il_expert.launch): every key
  // at the library's default except max_yaw_pts, 0 because the expert sends no yaw points.
  const cdc::WriterConfig c = cdc::LoadWriterConfigFile(CDC_CONFIG_FILE);
  const cdc::WriterConfig defaults;
  EXPECT_EQ(c.output_dir, "data/collect");
  EXPECT_EQ(c.image_width, defaults.image_width);
  EXPECT_EQ(c.image_height, defaults.image_height);
  EXPECT_EQ(c.shard_size_mb, defaults.shard_size_mb);
  EXPECT_EQ(c.queue_capacity, defaults.queue_capacity);
  EXPECT_EQ(c.full_queue_policy, defaults.full_queue_policy);
  EXPECT_EQ(c.max_ctrl_pts, defaults.max_ctrl_pts);
  EXPECT_EQ(c.max_yaw_pts, 0u);
  EXPECT_NE(defaults.max_yaw_pts, 0u);
  EXPECT_EQ(c.fsync, defaults.fsync);
  EXPECT_EQ(c.software_commit, defaults.software_commit);
}

TEST(WriterConfig, ValidateRejectsBadValuesWithTheirName) {
  cdc::WriterConfig c;
  c.output_dir = "d";
  c.max_ctrl_pts = 2;
  try {
    c.Validate();
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("max_ctrl_pts 2"), std::string::npos) << e.what();
  }
  EXPECT_THROW(cdc::ParseFullQueuePolicy("sometimes"), std::invalid_argument);
}

}  // namespace
