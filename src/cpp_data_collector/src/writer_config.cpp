#include "cpp_data_collector/writer_config.h"

#include <cmath>
#include <stdexcept>

namespace cpp_data_collector {

const char* ToString(FullQueuePolicy policy) {
  switch (policy) {
    case FullQueuePolicy::kBlock:
      return "block";
    case FullQueuePolicy::kDrop:
      return "drop";
  }
  return "unknown";
}

FullQueuePolicy ParseFullQueuePolicy(const std::string& text) {
  if (text == "block") return FullQueuePolicy::kBlock;
  if (text == "drop") return FullQueuePolicy::kDrop;
  throw std::invalid_argument("full_queue_policy '" + text + "' is not one of: block, drop");
}

void WriterConfig::Validate() const {
  auto fail = [](const std::string& what) { throw std::invalid_argument("writer config: " + what); };
  if (output_dir.empty()) fail("output_dir must not be empty");
  if (!(shard_size_mb > 0.0) || !std::isfinite(shard_size_mb)) {
    fail("shard_size_mb " + std::to_string(shard_size_mb) + " must be a positive number");
  }
  if (queue_capacity < 1 || queue_capacity > 100000) {
    fail("queue_capacity " + std::to_string(queue_capacity) + " must be in [1, 100000]");
  }
  if (image_width < 1 || image_height < 1 || image_width > 16384 || image_height > 16384) {
    fail("image size " + std::to_string(image_width) + "x" + std::to_string(image_height) +
         " must be within 1..16384 per side");
  }
  if (max_ctrl_pts < 4 || max_ctrl_pts > 100000) {
    fail("max_ctrl_pts " + std::to_string(max_ctrl_pts) + " must be in [4, 100000]");
  }
  if (max_yaw_pts > 100000) fail("max_yaw_pts " + std::to_string(max_yaw_pts) + " must be <= 100000");
  for (double v : {camera_fx_px, camera_fy_px, camera_cx_px, camera_cy_px}) {
    if (!std::isfinite(v) || v < 0.0) fail("camera intrinsics must be finite and >= 0");
  }
}

WriterConfig LoadWriterConfig(quad_core::StrictYaml* yaml, const std::string& prefix) {
  const std::string p = prefix.empty() ? "" : prefix + ".";
  WriterConfig c;
  c.output_dir = yaml->Get<std::string>(p + "output_dir");
  c.shard_size_mb = yaml->GetOr<double>(p + "shard_size_mb", c.shard_size_mb, quad_core::Positive());
  c.queue_capacity = static_cast<uint32_t>(yaml->GetOr<int>(
      p + "queue_capacity", static_cast<int>(c.queue_capacity), quad_core::InRange(1, 100000)));
  const std::string policy = yaml->GetOr<std::string>(p + "full_queue_policy", "block");
  try {
    c.full_queue_policy = ParseFullQueuePolicy(policy);
  } catch (const std::invalid_argument& e) {
    throw quad_core::ConfigError(yaml->source() + ": key '" + p + "full_queue_policy' has value '" + policy +
                                 "' which is not one of: block, drop");
  }
  c.image_width = static_cast<uint32_t>(yaml->Get<int>(p + "image_width", quad_core::InRange(1, 16384)));
  c.image_height = static_cast<uint32_t>(yaml->Get<int>(p + "image_height", quad_core::InRange(1, 16384)));
  c.max_ctrl_pts = static_cast<uint32_t>(
      yaml->GetOr<int>(p + "max_ctrl_pts", static_cast<int>(c.max_ctrl_pts), quad_core::InRange(4, 100000)));
  c.max_yaw_pts = static_cast<uint32_t>(
      yaml->GetOr<int>(p + "max_yaw_pts", static_cast<int>(c.max_yaw_pts), quad_core::InRange(0, 100000)));
  c.fsync = yaml->GetOr<bool>(p + "fsync", c.fsync);
  c.software_commit = yaml->GetOr<std::string>(p + "software_commit", c.software_commit);
  c.camera_fx_px = yaml->GetOr<double>(p + "camera.fx_px", 0.0, quad_core::NonNegative());
  c.camera_fy_px = yaml->GetOr<double>(p + "camera.fy_px", 0.0, quad_core::NonNegative());
  c.camera_cx_px = yaml->GetOr<double>(p + "camera.cx_px", 0.0, quad_core::NonNegative());
  c.camera_cy_px = yaml->GetOr<double>(p + "camera.cy_px", 0.0, quad_core::NonNegative());
  try {
    c.Validate();
  } catch (const std::invalid_argument& e) {
    throw quad_core::ConfigError(yaml->source() + ": " + e.what());
  }
  return c;
}

WriterConfig LoadWriterConfigFile(const std::string& path) {
  quad_core::StrictYaml yaml = quad_core::StrictYaml::FromFile(path);
  WriterConfig c = LoadWriterConfig(&yaml, "");
  yaml.CheckAllKeysUsed();
  return c;
}

}  // namespace cpp_data_collector
