// Exact box geometry against closed forms, dense sampling and Bullet's GJK distance.
#include "quad_sim/geometry.h"
#include "quad_sim/math_utils.h"

#include <BulletCollision/CollisionShapes/btBoxShape.h>
#include <BulletCollision/NarrowPhaseCollision/btGjkEpaPenetrationDepthSolver.h>
#include <BulletCollision/NarrowPhaseCollision/btGjkPairDetector.h>
#include <BulletCollision/NarrowPhaseCollision/btPointCollector.h>
#include <BulletCollision/NarrowPhaseCollision/btVoronoiSimplexSolver.h>
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>

using quad_sim::OrientedBox;

namespace {

constexpr double kPi = 3.14159265358979323846;

OrientedBox Box(const Eigen::Vector3d& c, const Eigen::Vector3d& size, double roll = 0, double pitch = 0,
                double yaw = 0) {
  OrientedBox b;
  b.center_world_m = c;
  b.size_m = size;
  b.q_world_box = quad_sim::QuatFromRpy(roll, pitch, yaw);
  return b;
}

OrientedBox RandomBox(std::mt19937_64* rng, double spread) {
  std::uniform_real_distribution<double> pos(-spread, spread);
  std::uniform_real_distribution<double> size(0.1, 2.0);
  std::uniform_real_distribution<double> ang(-kPi, kPi);
  return Box(Eigen::Vector3d(pos(*rng), pos(*rng), pos(*rng)),
             Eigen::Vector3d(size(*rng), size(*rng), size(*rng)), ang(*rng), ang(*rng), ang(*rng));
}

// Bullet's GJK distance between two separated boxes (single precision).
double GjkDistance(const OrientedBox& a, const OrientedBox& b) {
  auto tf = [](const OrientedBox& x) {
    const Eigen::Quaterniond& q = x.q_world_box;
    return btTransform(btQuaternion(q.x(), q.y(), q.z(), q.w()),
                       btVector3(x.center_world_m.x(), x.center_world_m.y(), x.center_world_m.z()));
  };
  btBoxShape sa(btVector3(a.HalfExtents().x(), a.HalfExtents().y(), a.HalfExtents().z()));
  btBoxShape sb(btVector3(b.HalfExtents().x(), b.HalfExtents().y(), b.HalfExtents().z()));
  sa.setMargin(0.0);
  sb.setMargin(0.0);
  btVoronoiSimplexSolver simplex;
  btGjkEpaPenetrationDepthSolver epa;
  btGjkPairDetector gjk(&sa, &sb, &simplex, &epa);
  btGjkPairDetector::ClosestPointInput in;
  in.m_transformA = tf(a);
  in.m_transformB = tf(b);
  btPointCollector out;
  gjk.getClosestPoints(in, out, nullptr);
  return out.m_distance;
}

// Minimum distance over a dense grid of surface points of a to the solid b: an upper bound on the exact
// distance.
double SampledUpperBound(const OrientedBox& a, const OrientedBox& b, int n) {
  const Eigen::Matrix3d R = a.q_world_box.toRotationMatrix();
  const Eigen::Vector3d h = a.HalfExtents();
  double best = std::numeric_limits<double>::infinity();
  for (int axis = 0; axis < 3; ++axis) {
    for (int side = -1; side <= 1; side += 2) {
      for (int i = 0; i <= n; ++i) {
        for (int j = 0; j <= n; ++j) {
          Eigen::Vector3d l;
          l(axis) = side * h(axis);
          l((axis + 1) % 3) = (2.0 * i / n - 1.0) * h((axis + 1) % 3);
          l((axis + 2) % 3) = (2.0 * j / n - 1.0) * h((axis + 2) % 3);
          best = std::min(best, quad_sim::PointBoxDistance(a.center_world_m + R * l, b));
        }
      }
    }
  }
  return best;
}

}  // namespace

TEST(RayBox, AxisAlignedHitMissAndInside) {
  const OrientedBox b = Box(Eigen::Vector3d(5, 0, 1), Eigen::Vector3d(2, 2, 2));
  EXPECT_DOUBLE_EQ(quad_sim::RayBoxEntry(Eigen::Vector3d(0, 0, 1), Eigen::Vector3d(1, 0, 0), b), 4.0);
  // Non-unit direction: t is in units of |d|.
  EXPECT_DOUBLE_EQ(quad_sim::RayBoxEntry(Eigen::Vector3d(0, 0, 1), Eigen::Vector3d(2, 0, 0), b), 2.0);
  EXPECT_TRUE(std::isinf(quad_sim::RayBoxEntry(Eigen::Vector3d(0, 0, 1), Eigen::Vector3d(-1, 0, 0), b)));
  EXPECT_TRUE(std::isinf(quad_sim::RayBoxEntry(Eigen::Vector3d(0, 3, 1), Eigen::Vector3d(1, 0, 0), b)));
  EXPECT_DOUBLE_EQ(quad_sim::RayBoxEntry(Eigen::Vector3d(5, 0, 1), Eigen::Vector3d(1, 0, 0), b), 0.0);
}

TEST(RayBox, RotatedCubeIsHitOnItsEdge) {
  // A cube turned 45 deg about z presents a vertical edge at distance h * sqrt(2) from its centre.
  const OrientedBox b = Box(Eigen::Vector3d(4, 0, 0), Eigen::Vector3d(1, 1, 1), 0, 0, kPi / 4);
  EXPECT_NEAR(quad_sim::RayBoxEntry(Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(1, 0, 0), b),
              4.0 - std::sqrt(0.5), 1e-12);
  // Offset by y: the face at 45 deg is hit at x = 4 - sqrt(0.5) + |y|.
  EXPECT_NEAR(quad_sim::RayBoxEntry(Eigen::Vector3d(0, 0.2, 0), Eigen::Vector3d(1, 0, 0), b),
              4.0 - std::sqrt(0.5) + 0.2, 1e-12);
}

TEST(RayBox, EntryPointLiesOnTheSurfaceForRandomRays) {
  std::mt19937_64 rng(7);
  int hits = 0;
  for (int k = 0; k < 2000; ++k) {
    const OrientedBox b = RandomBox(&rng, 3.0);
    std::uniform_real_distribution<double> u(-1, 1);
    const Eigen::Vector3d o(u(rng) * 6, u(rng) * 6, u(rng) * 6);
    const Eigen::Vector3d d =
        (b.center_world_m + Eigen::Vector3d(u(rng), u(rng), u(rng)) * 0.5 - o).normalized();
    const double t = quad_sim::RayBoxEntry(o, d, b);
    if (std::isinf(t) || t == 0.0) continue;
    ++hits;
    const Eigen::Vector3d p = o + t * d;
    // On the surface: distance 0, and a step back along the ray is outside.
    EXPECT_LT(quad_sim::PointBoxDistance(p, b), 1e-9);
    EXPECT_GT(quad_sim::PointBoxDistance(o + (t - 1e-6) * d, b), 0.0);
  }
  EXPECT_GT(hits, 1000);
}

TEST(BoxDistance, AxisAlignedClosedForms) {
  const OrientedBox a = Box(Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(2, 2, 2));
  EXPECT_DOUBLE_EQ(
      quad_sim::BoxBoxDistance(a, Box(Eigen::Vector3d(3.5, 0.3, -0.2), Eigen::Vector3d(1, 1, 1))), 2.0);
  // Corner to corner: gaps (1, 2, 2) -> 3.
  EXPECT_NEAR(quad_sim::BoxBoxDistance(a, Box(Eigen::Vector3d(2.5, 3.5, 3.5), Eigen::Vector3d(1, 1, 1))), 3.0,
              1e-12);
  EXPECT_DOUBLE_EQ(quad_sim::BoxBoxDistance(a, Box(Eigen::Vector3d(1.2, 0, 0), Eigen::Vector3d(1, 1, 1))),
                   0.0);
  EXPECT_TRUE(
      quad_sim::BoxesOverlap(a, Box(Eigen::Vector3d(1.5, 0, 0), Eigen::Vector3d(1, 1, 1))));  // touching
  EXPECT_FALSE(quad_sim::BoxesOverlap(a, Box(Eigen::Vector3d(1.5001, 0, 0), Eigen::Vector3d(1, 1, 1))));
  EXPECT_DOUBLE_EQ(quad_sim::PointBoxDistance(Eigen::Vector3d(4, 5, 0.5), a), 5.0);
}

TEST(BoxDistance, EdgeToEdgeOfCrossedBars) {
  // Two bars crossing at right angles, one above the other: the closest points are interior points of edges.
  const OrientedBox a = Box(Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(4, 0.2, 0.2), kPi / 4, 0, 0);
  const OrientedBox b = Box(Eigen::Vector3d(0, 0, 1), Eigen::Vector3d(0.2, 4, 0.2), 0, kPi / 4, 0);
  // Each bar rotated 45 deg about its long axis has its lowest/highest edge at 0.1 * sqrt(2) from its axis.
  EXPECT_NEAR(quad_sim::BoxBoxDistance(a, b), 1.0 - 2.0 * 0.1 * std::sqrt(2.0), 1e-12);
}

TEST(BoxDistance, PlateThroughBarOverlapsWithoutContainedVertices) {
  const OrientedBox plate = Box(Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(0.1, 2, 2));
  const OrientedBox bar = Box(Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(3, 0.2, 0.2), 0.3, 0, 0);
  EXPECT_TRUE(quad_sim::BoxesOverlap(plate, bar));
  EXPECT_EQ(quad_sim::BoxBoxDistance(plate, bar), 0.0);
}

TEST(BoxDistance, RandomPairsAgreeWithSamplingAndBulletGjk) {
  std::mt19937_64 rng(42);
  int separated = 0;
  for (int k = 0; k < 300; ++k) {
    const OrientedBox a = RandomBox(&rng, 3.0);
    const OrientedBox b = RandomBox(&rng, 3.0);
    const double d = quad_sim::BoxBoxDistance(a, b);
    EXPECT_NEAR(d, quad_sim::BoxBoxDistance(b, a), 1e-12);
    const double upper = std::min(SampledUpperBound(a, b, 40), SampledUpperBound(b, a, 40));
    if (d == 0.0) {
      EXPECT_TRUE(quad_sim::BoxesOverlap(a, b));
      continue;
    }
    ++separated;
    // Exact: never above any sampled pair, and within the sampling resolution of the best one.
    EXPECT_LE(d, upper + 1e-12);
    EXPECT_GT(d, upper - 0.06);
    EXPECT_NEAR(d, GjkDistance(a, b), 2e-4 * std::max(1.0, d));
  }
  EXPECT_GT(separated, 100);
}
