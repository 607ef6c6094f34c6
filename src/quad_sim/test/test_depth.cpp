// The depth camera against an independent analytic reference (ray/face-plane intersections) on hand-built
// scenes, and against brute force over all boxes in the default world.
#include "quad_sim/depth_camera.h"
#include "quad_sim/math_utils.h"
#include "quad_sim/simulator.h"
#include "quad_sim/world_index.h"

#include "test_util.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>
#include <random>

using quad_core::DepthImage;
using quad_sim::DepthCameraConfig;
using quad_sim::DepthRenderer;
using quad_sim::OrientedBox;
using quad_sim::World;
using quad_sim::WorldIndex;

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kInf = std::numeric_limits<double>::infinity();

OrientedBox Box(const Eigen::Vector3d& c, const Eigen::Vector3d& size, double yaw = 0.0) {
  OrientedBox b;
  b.center_world_m = c;
  b.size_m = size;
  b.q_world_box = quad_sim::QuatFromRpy(0, 0, yaw);
  return b;
}

DepthCameraConfig Camera(int w, int h, int threads = 1) {
  DepthCameraConfig c;
  c.intrinsics = DepthCameraConfig::FastPlannerFov(w, h);
  c.min_depth_m = 0.1;
  c.max_depth_m = 20.0;
  c.num_threads = threads;
  return c;
}

// Camera at p looking along world +x (optical z = world x, optical x = -world y, optical y = -world z).
Eigen::Quaterniond LookAlongX() { return quad_sim::OpticalMountRotation(0, 0, 0); }

// Independent reference: intersect the pixel's ray with each face plane of each box (point-in-rectangle test
// in the face's own coordinates) and with the ground plane; depth = (hit - o) . optical axis.
double ReferenceDepth(const World& world, const Eigen::Vector3d& o, const Eigen::Matrix3d& R_wc,
                      const quad_core::CameraIntrinsics& k, int u, int v, double max_depth) {
  const Eigen::Vector3d dir = R_wc * Eigen::Vector3d((u - k.cx) / k.fx, (v - k.cy) / k.fy, 1.0);
  const Eigen::Vector3d axis = R_wc.col(2);
  double best = kInf;
  auto consider = [&](const Eigen::Vector3d& hit) {
    const double depth = (hit - o).dot(axis);
    if (depth >= 0.0 && depth < best) best = depth;
  };
  if (dir.z() < 0.0) consider(o + (-o.z() / dir.z()) * dir);
  for (const OrientedBox& b : world.boxes) {
    const Eigen::Matrix3d R = b.q_world_box.toRotationMatrix();
    const Eigen::Vector3d h = b.HalfExtents();
    for (int axis_i = 0; axis_i < 3; ++axis_i) {
      for (int side = -1; side <= 1; side += 2) {
        const Eigen::Vector3d n = side * R.col(axis_i);
        const Eigen::Vector3d p0 = b.center_world_m + h(axis_i) * n;
        const double denom = n.dot(dir);
        if (std::abs(denom) < 1e-15) continue;
        const double t = n.dot(p0 - o) / denom;
        if (t <= 0.0) continue;
        const Eigen::Vector3d hit = o + t * dir;
        const Eigen::Vector3d local = R.transpose() * (hit - b.center_world_m);
        const int a1 = (axis_i + 1) % 3;
        const int a2 = (axis_i + 2) % 3;
        if (std::abs(local(a1)) <= h(a1) + 1e-12 && std::abs(local(a2)) <= h(a2) + 1e-12) consider(hit);
      }
    }
  }
  return best > max_depth ? kInf : best;
}

// Compares every pixel with the reference; returns the number of pixels showing a box (for coverage checks).
int ExpectMatchesReference(const World& world, const Eigen::Vector3d& o, const Eigen::Quaterniond& q_wc,
                           const DepthCameraConfig& cfg) {
  WorldIndex index;
  index.Build(world);
  const DepthRenderer renderer(cfg);
  const quad_core::DepthImage img = renderer.Render(index, o, q_wc);
  const Eigen::Matrix3d R = q_wc.toRotationMatrix();
  int box_pixels = 0;
  int mismatches = 0;
  for (int v = 0; v < img.height; ++v) {
    for (int u = 0; u < img.width; ++u) {
      const double ref = ReferenceDepth(world, o, R, cfg.intrinsics, u, v, cfg.max_depth_m);
      const double got = img.at(v, u);
      const bool ok = std::isinf(ref) ? (std::isinf(got) && got > 0) : std::abs(got - ref) <= 1e-3;
      if (!ok && ++mismatches <= 5)
        ADD_FAILURE() << "pixel (" << u << ", " << v << "): " << got << " vs " << ref;
      // A pixel "shows a box" when its ray ends before the ground would be hit.
      const Eigen::Vector3d dir = R * Eigen::Vector3d((u - cfg.intrinsics.cx) / cfg.intrinsics.fx,
                                                      (v - cfg.intrinsics.cy) / cfg.intrinsics.fy, 1.0);
      const double ground = dir.z() < 0 ? -o.z() / dir.z() : kInf;
      if (std::isfinite(ref) && ref < ground - 1e-6) ++box_pixels;
    }
  }
  EXPECT_EQ(mismatches, 0);
  return box_pixels;
}

}  // namespace

TEST(DepthCamera, IntrinsicsKeepFastPlannersFieldOfView) {
  const auto k640 = DepthCameraConfig::FastPlannerFov(640, 480);
  EXPECT_DOUBLE_EQ(k640.fx, 387.2);
  for (const auto& wh : {std::pair<int, int>{160, 120}, {320, 240}}) {
    const auto k = DepthCameraConfig::FastPlannerFov(wh.first, wh.second);
    EXPECT_NEAR(std::atan(0.5 * k.width / k.fx), std::atan(0.5 * 640 / 387.2), 1e-12);
    EXPECT_NEAR(std::atan(0.5 * k.height / k.fy), std::atan(0.5 * 480 / 387.2), 1e-12);
    EXPECT_DOUBLE_EQ(k.cx, 0.5 * (k.width - 1));
  }
}

TEST(DepthCamera, BoxStraightAheadAt3m) {
  World world;
  world.boxes.push_back(Box(Eigen::Vector3d(3.5, 0, 1.5), Eigen::Vector3d(1.0, 2.0, 2.0)));
  const Eigen::Vector3d o(0, 0, 1.5);
  const DepthCameraConfig cfg = Camera(320, 240);
  const int box_pixels = ExpectMatchesReference(world, o, LookAlongX(), cfg);
  EXPECT_GT(box_pixels, 5000);
  // The centre of a face-on wall: exactly 3 m at the four central pixels (symmetric principal point).
  WorldIndex index;
  index.Build(world);
  const quad_core::DepthImage img = DepthRenderer(cfg).Render(index, o, LookAlongX());
  EXPECT_FLOAT_EQ(img.at(119, 159), 3.0f);
  EXPECT_FLOAT_EQ(img.at(120, 160), 3.0f);
  // A face-on wall has the same depth (not range) everywhere on it.
  EXPECT_FLOAT_EQ(img.at(100, 120), 3.0f);
}

TEST(DepthCamera, BoxRotated30Degrees) {
  World world;
  world.boxes.push_back(
      Box(Eigen::Vector3d(4.0, 0.3, 1.2), Eigen::Vector3d(1.0, 2.5, 1.5), 30.0 * kPi / 180.0));
  const int box_pixels =
      ExpectMatchesReference(world, Eigen::Vector3d(0, 0, 1.5), LookAlongX(), Camera(320, 240));
  EXPECT_GT(box_pixels, 3000);
}

TEST(DepthCamera, PartialOcclusion) {
  World world;
  world.boxes.push_back(Box(Eigen::Vector3d(6.0, 0.0, 1.5), Eigen::Vector3d(1.0, 4.0, 3.0)));  // far wall
  world.boxes.push_back(
      Box(Eigen::Vector3d(3.0, 0.8, 1.5), Eigen::Vector3d(0.5, 1.0, 1.0), 0.4));  // occluder
  const Eigen::Vector3d o(0, 0, 1.5);
  const DepthCameraConfig cfg = Camera(320, 240);
  ExpectMatchesReference(world, o, LookAlongX(), cfg);
  // Both boxes are visible: some pixels near 3 m (occluder), some at 5.5 m (wall behind it).
  WorldIndex index;
  index.Build(world);
  const quad_core::DepthImage img = DepthRenderer(cfg).Render(index, o, LookAlongX());
  int near = 0, far = 0;
  for (float z : img.depth_m) {
    if (z > 2.0f && z < 3.5f) ++near;
    if (std::abs(z - 5.5f) < 1e-4f) ++far;
  }
  EXPECT_GT(near, 1000);
  EXPECT_GT(far, 5000);
}

TEST(DepthCamera, TiltedCameraAndGround) {
  World world;
  world.boxes.push_back(Box(Eigen::Vector3d(3.0, -1.0, 0.5), Eigen::Vector3d(1.0, 1.0, 1.0), 0.7));
  const Eigen::Quaterniond q =
      quad_sim::OpticalMountRotation(0.1, 0.35, -0.2);  // pitched down, rolled, yawed
  ExpectMatchesReference(world, Eigen::Vector3d(0, 0, 2.0), q, Camera(160, 120));
}

TEST(DepthCamera, Rep118NoReturnIsPositiveInfAndTooCloseIsNegativeInf) {
  World world;
  world.boxes.push_back(
      Box(Eigen::Vector3d(0.55, 0, 10.0), Eigen::Vector3d(1.0, 1.0, 1.0)));  // face at 0.05 m
  WorldIndex index;
  index.Build(world);
  DepthCameraConfig cfg = Camera(64, 48);
  cfg.max_depth_m = 5.0;
  const DepthRenderer r(cfg);
  // Looking up at the sky from high above: no return anywhere.
  const quad_core::DepthImage sky =
      r.Render(index, Eigen::Vector3d(0, 0, 100.0), quad_sim::OpticalMountRotation(0, -1.2, 0));
  for (float z : sky.depth_m) EXPECT_TRUE(std::isinf(z) && z > 0);
  // A box face 5 cm ahead: closer than min_depth_m -> -Inf.
  const quad_core::DepthImage close = r.Render(index, Eigen::Vector3d(0, 0, 10.0), LookAlongX());
  EXPECT_TRUE(std::isinf(close.at(24, 32)) && close.at(24, 32) < 0);
  // The ground 6 m below a camera looking straight down is beyond max_depth_m = 5: +Inf.
  const quad_core::DepthImage down =
      r.Render(index, Eigen::Vector3d(20, 0, 6.0), quad_sim::OpticalMountRotation(0, kPi / 2, 0));
  EXPECT_TRUE(std::isinf(down.at(24, 32)) && down.at(24, 32) > 0);
  const quad_core::DepthImage down4 =
      r.Render(index, Eigen::Vector3d(20, 0, 4.0), quad_sim::OpticalMountRotation(0, kPi / 2, 0));
  EXPECT_FLOAT_EQ(down4.at(5, 10), 4.0f);  // flat ground seen straight down: constant depth
}

TEST(DepthCamera, DbvtTraversalEqualsBruteForceInTheDefaultWorld) {
  const quad_sim::SimConfig sim_cfg = quad_sim_test::DefaultSimConfig();
  const World world = quad_sim::GenerateWorld(sim_cfg.world_gen, 3);
  WorldIndex index;
  index.Build(world);
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  int hits = 0;
  for (int k = 0; k < 20000; ++k) {
    const Eigen::Vector3d o(18 * u(rng), 18 * u(rng), 2.5 + 2.5 * u(rng));
    const Eigen::Vector3d d = Eigen::Vector3d(u(rng), u(rng), 0.3 * u(rng));
    const quad_sim::RayHit hit = index.CastRay(o, d, 15.0);
    double best = (d.z() < 0) ? -o.z() / d.z() : kInf;
    int best_id = std::isfinite(best) ? quad_sim::kHitGround : quad_sim::kHitNone;
    for (size_t i = 0; i < world.boxes.size(); ++i) {
      const double t = quad_sim::RayBoxEntry(o, d, world.boxes[i]);
      if (t < best) {
        best = t;
        best_id = static_cast<int>(i);
      }
    }
    if (best > 15.0) {
      best = kInf;
      best_id = quad_sim::kHitNone;
    }
    ASSERT_EQ(hit.box_index, best_id) << "ray " << k;
    if (std::isfinite(best)) {
      ASSERT_NEAR(hit.t, best, 1e-9);
      hits += best_id >= 0;
    }
  }
  EXPECT_GT(hits, 2000);
}

TEST(DepthCamera, ThreadCountDoesNotChangeTheImage) {
  const World world = quad_sim::GenerateWorld(quad_sim_test::DefaultSimConfig().world_gen, 5);
  WorldIndex index;
  index.Build(world);
  const Eigen::Vector3d o(-15, 0, 1.5);
  const quad_core::DepthImage a = DepthRenderer(Camera(160, 120, 1)).Render(index, o, LookAlongX());
  const quad_core::DepthImage b = DepthRenderer(Camera(160, 120, 2)).Render(index, o, LookAlongX());
  ASSERT_EQ(a.depth_m.size(), b.depth_m.size());
  EXPECT_EQ(0, std::memcmp(a.depth_m.data(), b.depth_m.data(), a.depth_m.size() * sizeof(float)));
}

TEST(DepthCamera, GaussianNoiseIsSeededAndHasTheConfiguredSpread) {
  World world;
  world.boxes.push_back(
      Box(Eigen::Vector3d(3.5, 0, 20.0), Eigen::Vector3d(1.0, 8.0, 8.0)));  // fills the view
  WorldIndex index;
  index.Build(world);
  DepthCameraConfig cfg = Camera(160, 120);
  cfg.noise_std_at_1m_m = 0.002;  // sigma = 0.002 * 3^2 = 0.018 m on the wall
  const DepthRenderer r(cfg);
  const Eigen::Vector3d o(0, 0, 20.0);
  quad_core::DepthImage a = r.Render(index, o, LookAlongX());
  quad_core::DepthImage b = a;
  std::mt19937_64 rng_a(5), rng_b(5);
  r.AddNoise(&a, &rng_a);
  r.AddNoise(&b, &rng_b);
  EXPECT_EQ(a.depth_m, b.depth_m);
  double sum = 0, sum2 = 0;
  for (float z : a.depth_m) {
    sum += z - 3.0;
    sum2 += (z - 3.0) * (z - 3.0);
  }
  const double n = static_cast<double>(a.depth_m.size());
  EXPECT_NEAR(sum / n, 0.0, 0.001);
  EXPECT_NEAR(std::sqrt(sum2 / n), 0.018, 0.001);
}

TEST(DepthCamera, SimulatorRendersFromTheConfiguredMount) {
  quad_sim::SimConfig cfg = quad_sim_test::DefaultSimConfig();
  quad_sim::Simulator sim(cfg);
  World world;
  world.boxes.push_back(Box(Eigen::Vector3d(3.5, 0, 1.5), Eigen::Vector3d(1.0, 2.0, 2.0)));
  sim.Reset(world, Eigen::Vector3d(0, 0, 1.5), 0.0, Eigen::Vector3d(-10, 0, 1));
  const quad_core::DepthImage img = sim.RenderDepth();
  ASSERT_EQ(img.width, 320);
  // Wall at x = 3.0, camera 0.1 m ahead of the centre of mass.
  EXPECT_FLOAT_EQ(img.at(120, 160), static_cast<float>(3.0 - cfg.camera.p_body_camera_m.x()));
  // Yawed by 90 degrees the camera looks along +y: nothing there but the ground.
  sim.Reset(world, Eigen::Vector3d(0, 0, 1.5), kPi / 2, Eigen::Vector3d(-10, 0, 1));
  const quad_core::DepthImage side = sim.RenderDepth();
  EXPECT_TRUE(std::isinf(side.at(60, 160)));
}

TEST(DepthCamera, RasterisedRenderEqualsPerPixelTreeRayCastInTheDefaultWorld) {
  // The renderer's frustum cull, screen rectangles and tile occlusion culling must never lose a hit: compare
  // every pixel with an independent per-pixel Dbvt ray cast from random poses inside the default world.
  const World world = quad_sim::GenerateWorld(quad_sim_test::DefaultSimConfig().world_gen, 8);
  WorldIndex index;
  index.Build(world);
  const DepthCameraConfig cfg = Camera(160, 120, 2);
  const DepthRenderer renderer(cfg);
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  int box_pixels = 0;
  for (int k = 0; k < 30; ++k) {
    const Eigen::Vector3d o(18 * u(rng), 18 * u(rng), 2.0 + 1.8 * u(rng));
    const Eigen::Quaterniond q = quad_sim::OpticalMountRotation(0.3 * u(rng), 0.5 * u(rng), kPi * u(rng));
    const quad_core::DepthImage img = renderer.Render(index, o, q);
    const Eigen::Matrix3d R = q.toRotationMatrix();
    for (int v = 0; v < img.height; ++v) {
      for (int x = 0; x < img.width; ++x) {
        const Eigen::Vector3d d = R * Eigen::Vector3d((x - cfg.intrinsics.cx) / cfg.intrinsics.fx,
                                                      (v - cfg.intrinsics.cy) / cfg.intrinsics.fy, 1);
        const quad_sim::RayHit hit = index.CastRay(o, d, cfg.max_depth_m);
        const float got = img.at(v, x);
        if (hit.box_index == quad_sim::kHitNone) {
          ASSERT_TRUE(std::isinf(got) && got > 0)
              << "pose " << k << " pixel " << x << "," << v << ": " << got;
        } else if (hit.t < cfg.min_depth_m) {
          ASSERT_TRUE(std::isinf(got) && got < 0) << "pose " << k << " pixel " << x << "," << v;
        } else {
          ASSERT_NEAR(got, hit.t, 1e-6 * hit.t) << "pose " << k << " pixel " << x << "," << v;
          box_pixels += hit.box_index >= 0;
        }
      }
    }
  }
  EXPECT_GT(box_pixels, 30 * 160 * 120 / 10);
}
