#include <gtest/gtest.h>

#include <cmath>
#include <cstring>

#include "cpp_data_collector/dataset_writer.h"
#include "cpp_data_collector/synthetic.h"

namespace cdc = cpp_data_collector;

namespace {

cdc::SyntheticConfig Config(uint32_t boxes) {
  cdc::SyntheticConfig c;
  c.seed = 17;
  c.width = 64;
  c.height = 48;
  c.boxes_per_world = boxes;
  c.records_per_episode = 10;
  return c;
}

TEST(SyntheticGenerator, RecordIDependsOnlyOnSeedAndI) {
  const cdc::SyntheticGenerator gen(Config(20));
  cdc::SyntheticRecord a, b, other;
  gen.Generate(13, &a);
  gen.Generate(2, &b);
  gen.Generate(13, &b);
  EXPECT_EQ(a.depth_m.size(), b.depth_m.size());
  EXPECT_EQ(0, std::memcmp(a.depth_m.data(), b.depth_m.data(), a.depth_m.size() * sizeof(float)));
  EXPECT_EQ(a.record.bspline.ctrl_pts_world, b.record.bspline.ctrl_pts_world);
  EXPECT_EQ(a.record.sim_time_s, b.record.sim_time_s);
  cdc::SyntheticConfig c = Config(20);
  c.seed = 18;
  cdc::SyntheticGenerator(c).Generate(13, &other);
  EXPECT_NE(a.record.world_seed, other.record.world_seed);
}

TEST(SyntheticGenerator, DepthWithoutBoxesIsTheExactGroundPlaneDistance) {
  const cdc::SyntheticGenerator gen(Config(0));
  cdc::SyntheticRecord r;
  gen.Generate(5, &r);
  const auto& q = r.record.odom.q_world_body;  // x y z w
  const double x = q[0], y = q[1], z = q[2], w = q[3];
  const double R20 = 2 * (x * z - y * w), R21 = 2 * (y * z + x * w), R22 = 1 - 2 * (x * x + y * y);
  int finite = 0, too_far = 0;
  for (uint32_t v = 0; v < 48; ++v) {
    for (uint32_t u = 0; u < 64; ++u) {
      const float d = r.depth_m[v * 64 + u];
      if (std::isnan(d)) continue;
      // Optical (xc, yc, 1) * d -> body (d, -xc d, -yc d); its world z must be 0 (the ground).
      const double xc = (u + 0.5 - gen.cx_px()) / gen.fx_px(), yc = (v + 0.5 - gen.cy_px()) / gen.fy_px();
      const double zw = r.record.odom.p_world_body[2] + d * (R20 * 1.0 + R21 * -xc + R22 * -yc);
      if (std::isinf(d)) {
        ++too_far;
        continue;
      }
      ++finite;
      EXPECT_NEAR(zw, 0.0, 1e-5 * d) << u << "," << v;
    }
  }
  EXPECT_GT(finite, 200);   // the lower image sees the ground
  EXPECT_GT(too_far, 200);  // the upper image sees nothing within range
}

TEST(SyntheticGenerator, RecordsAreValidAndSynchronised) {
  const cdc::SyntheticGenerator gen(Config(30));
  cdc::WriterConfig wc;
  wc.output_dir = "unused";
  wc.image_width = 64;
  wc.image_height = 48;
  cdc::SyntheticRecord r;
  int nan_pixels = 0;
  for (uint64_t i = 0; i < 30; ++i) {
    gen.Generate(i, &r);
    EXPECT_EQ(cdc::ValidatePlanRecord(r.record, wc), "") << i;
    EXPECT_LE(r.record.depth_stamp_s - r.record.odom.stamp_s, 0.005 + 1e-12);
    EXPECT_GE(r.record.depth_stamp_s - r.record.odom.stamp_s, 0.0);
    EXPECT_GT(r.record.sim_time_s, r.record.depth_stamp_s);
    EXPECT_EQ(r.record.episode_id, static_cast<int64_t>(i / 10));
    for (float d : r.depth_m) nan_pixels += std::isnan(d) ? 1 : 0;
  }
  EXPECT_GT(nan_pixels, 0);
}

}  // namespace
