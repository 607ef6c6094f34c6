// Deterministic synthetic plan records for tests and benchmarks (not for training): record number i depends
// only on the config (seed included) and i. Each episode is a seeded world of yaw-rotated boxes on a ground
// plane; the vehicle flies a smooth path through it; the depth image is rendered exactly (ray/box and
// ray/plane intersections, REP 118 special values, a few invalid pixels); the B-spline is a Fast-Planner-like
// uniform cubic spline (0.25 s knot spacing, 8..32 control points) following the path ahead.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "cpp_data_collector/plan_record.h"

namespace cpp_data_collector {

struct SyntheticConfig {
  uint64_t seed = 1;
  uint32_t width = 96;
  uint32_t height = 72;
  uint32_t records_per_episode = 40;
  uint32_t boxes_per_world = 30;
  double record_period_s = 0.1;           // one plan every 0.1 s of sim time
  double max_range_m = 20.0;              // beyond: +Inf
  double min_range_m = 0.15;              // closer: -Inf
  double invalid_pixel_fraction = 0.002;  // NaN pixels
};

// Owns the storage a PlanRecord views; not copyable because `record.depth.data` points into `depth_m`.
struct SyntheticRecord {
  SyntheticRecord() = default;
  SyntheticRecord(const SyntheticRecord&) = delete;
  SyntheticRecord& operator=(const SyntheticRecord&) = delete;

  PlanRecord record;
  std::vector<float> depth_m;
  std::string status_text;
};

// Whether Generate renders the depth image (kSkip leaves `depth_m` untouched, for benchmarks that reuse
// images).
enum class DepthMode { kRender, kSkip };

class SyntheticGenerator {
 public:
  // Throws std::invalid_argument for zero sizes, non-positive periods or ranges.
  explicit SyntheticGenerator(const SyntheticConfig& config);

  // Fills `out` with record `index` (reusing its buffers).
  void Generate(uint64_t index, SyntheticRecord* out, DepthMode depth_mode = DepthMode::kRender) const;

  const SyntheticConfig& config() const { return config_; }
  // Pinhole intrinsics: Fast-Planner's simulated camera (640x480, f = 387.2 px) scaled to width x height.
  double fx_px() const { return fx_; }
  double fy_px() const { return fy_; }
  double cx_px() const { return cx_; }
  double cy_px() const { return cy_; }

 private:
  SyntheticConfig config_;
  double fx_ = 0.0;
  double fy_ = 0.0;
  double cx_ = 0.0;
  double cy_ = 0.0;
};

}  // namespace cpp_data_collector
