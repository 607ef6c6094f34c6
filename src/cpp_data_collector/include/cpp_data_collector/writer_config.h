// Configuration of DatasetWriter, loaded strictly from YAML (docs/cpp_data_collector.md lists every key).
#pragma once

#include <cstdint>
#include <string>

#include "quad_core/strict_yaml.h"

namespace cpp_data_collector {

// What Record() does when every queue slot is taken: wait for the writer thread (nothing is lost; the caller
// may stall), or drop the record and count it (the caller never waits).
enum class FullQueuePolicy { kBlock, kDrop };

const char* ToString(FullQueuePolicy policy);
// "block" / "drop"; throws std::invalid_argument naming the value otherwise.
FullQueuePolicy ParseFullQueuePolicy(const std::string& text);

struct WriterConfig {
  std::string output_dir;        // created if missing; must not already hold a dataset
  double shard_size_mb = 256.0;  // shards rotate before exceeding this many 10^6 bytes (>= 1 record each)
  uint32_t queue_capacity = 32;  // preallocated record slots between caller and writer thread
  FullQueuePolicy full_queue_policy = FullQueuePolicy::kBlock;
  uint32_t image_width = 320;  // every recorded depth image must have this size
  uint32_t image_height = 240;
  uint32_t max_ctrl_pts = 128;  // longer B-splines are rejected (counted), never truncated
  uint32_t max_yaw_pts = 128;
  bool fsync = true;  // fsync shards and manifest when completed (power-loss safety)
  std::string software_commit = "unknown";
  double camera_fx_px = 0.0;  // intrinsics stored in headers and manifest; 0 = unknown
  double camera_fy_px = 0.0;
  double camera_cx_px = 0.0;
  double camera_cy_px = 0.0;

  // Throws std::invalid_argument naming the field and value.
  void Validate() const;
};

// Reads the keys of WriterConfig under `prefix` ("" for the top level, "collector" for a section). Every key
// but output_dir and the image size has the default above. Throws quad_core::ConfigError naming key and
// value. Does not call CheckAllKeysUsed (the caller owns the whole file).
WriterConfig LoadWriterConfig(quad_core::StrictYaml* yaml, const std::string& prefix);
// A whole file holding only writer keys; unknown keys are errors.
WriterConfig LoadWriterConfigFile(const std::string& path);

}  // namespace cpp_data_collector
