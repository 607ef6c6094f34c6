#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>

#include "fast_planner/esdf.h"
#include "test_util.h"

namespace fast_planner {
namespace {

TEST(DistanceTransform1dTest, EqualsBruteForceOnRandomSampledFunctions) {
  std::mt19937 rng(7);
  std::uniform_int_distribution<int32_t> val(0, 900);
  std::bernoulli_distribution inf(0.6);
  for (int trial = 0; trial < 500; ++trial) {
    const int n = 1 + trial % 57;
    std::vector<int32_t> f(n), out(n);
    std::vector<int> v(n);
    std::vector<int64_t> zn(n + 1), zd(n + 1);
    for (auto& x : f) x = inf(rng) ? kEdtInfinity : val(rng);
    DistanceTransform1d(f.data(), n, out.data(), v.data(), zn.data(), zd.data());
    for (int q = 0; q < n; ++q) {
      int64_t best = kEdtInfinity;
      for (int p = 0; p < n; ++p) {
        if (f[p] != kEdtInfinity)
          best = std::min<int64_t>(best, static_cast<int64_t>(q - p) * (q - p) + f[p]);
      }
      EXPECT_EQ(out[q], best) << "trial " << trial << " q " << q;
    }
  }
}

// Brute-force signed distance of a voxel over the window (centre to centre): a free voxel's distance to the
// nearest observed obstacle of the window or ground/ceiling layer; an observed obstacle's (negative) distance
// to the nearest free voxel of the window.
double BruteForce(const VoxelMap& map, const Eigen::Vector3i& lo, const Eigen::Vector3i& hi,
                  const Eigen::Vector3i& v) {
  const bool occ = map.IsOccupied(v);
  double best = std::numeric_limits<double>::infinity();
  for (int z = lo.z(); z <= hi.z(); ++z) {
    for (int y = lo.y(); y <= hi.y(); ++y) {
      for (int x = lo.x(); x <= hi.x(); ++x) {
        const Eigen::Vector3i w(x, y, z);
        if (map.IsOccupied(w) == occ) continue;
        best = std::min(best, static_cast<double>((w - v).squaredNorm()));
      }
    }
  }
  if (!occ) {
    const double below = v.z() - map.ground_layer(), above = map.ceiling_layer() - v.z();
    best = std::min({best, below * below, above * above});
  }
  if (std::isinf(best)) return occ ? -Esdf::kFarDistance : Esdf::kFarDistance;
  return (occ ? -1.0 : 1.0) * std::sqrt(best) * map.resolution();
}

class EsdfRandomMapTest : public ::testing::TestWithParam<int> {};

TEST_P(EsdfRandomMapTest, EqualsBruteForceDistancesInsideAndOutsideObstacles) {
  std::mt19937 rng(GetParam());
  // With ground (z < 0 in the map) on odd seeds; a sub-window of the map on every seed.
  MapConfig c = test::SmallMapConfig(Eigen::Vector3d(1.8, 1.6, 1.4), 0.1, 0.1, 0.0);
  if (GetParam() % 2) {
    c.origin_m.z() = -0.3;  // ground layers inside the map
    c.ceiling_z_m = 0.85;   // and ceiling layers
  }
  VoxelMap map(c);
  std::bernoulli_distribution occupied(0.02 + 0.03 * (GetParam() % 3));
  std::vector<Eigen::Vector3d> pts;
  for (int z = 0; z < map.size_voxels().z(); ++z) {
    for (int y = 0; y < map.size_voxels().y(); ++y) {
      for (int x = 0; x < map.size_voxels().x(); ++x) {
        if (occupied(rng)) pts.push_back(map.ToPosition(Eigen::Vector3i(x, y, z)));
      }
    }
  }
  map.SetOccupied(pts);
  std::uniform_int_distribution<int> off(0, 3);
  const Eigen::Vector3i lo(off(rng), off(rng), off(rng));
  const Eigen::Vector3i hi = map.size_voxels() - Eigen::Vector3i(1 + off(rng), 1 + off(rng), 1 + off(rng));
  // Truncated at 0.35 m on seeds 5..8 and 0.75 m on seeds 9..12: exact up to there, clamped beyond (the
  // outside field by windowed passes of radius 3 and 7, the untruncated one by the lower envelope).
  const double trunc = GetParam() > 8 ? 0.75 : GetParam() > 4 ? 0.35 : Esdf::kFarDistance;
  Esdf esdf(trunc);
  esdf.Update(map, lo, hi);
  // The window less the ground and ceiling layers.
  ASSERT_EQ(esdf.window_min().z(), std::max(lo.z(), map.ground_layer() + 1));
  ASSERT_EQ(esdf.window_max().z(), std::min(hi.z(), map.ceiling_layer() - 1));
  for (int z = esdf.window_min().z(); z <= esdf.window_max().z(); ++z) {
    for (int y = lo.y(); y <= hi.y(); ++y) {
      for (int x = lo.x(); x <= hi.x(); ++x) {
        const Eigen::Vector3i v(x, y, z);
        const double exact = BruteForce(map, esdf.window_min(), esdf.window_max(), v);
        const double expected = std::copysign(std::min(std::abs(exact), trunc), exact);
        ASSERT_NEAR(esdf.VoxelDistance(v), expected, 1e-5) << v.transpose();
      }
    }
  }
  EXPECT_EQ(esdf.VoxelDistance(hi + Eigen::Vector3i(1, 0, 0)), Esdf::kFarDistance);
}

INSTANTIATE_TEST_SUITE_P(Seeds, EsdfRandomMapTest, ::testing::Range(1, 13));

TEST(EsdfTest, GradientEqualsFiniteDifferencesOfTheInterpolatedDistance) {
  VoxelMap map(test::SmallMapConfig(Eigen::Vector3d(3.0, 3.0, 3.0)));
  test::AddBox(&map, Eigen::Vector3d(1.2, 1.0, 0.9), Eigen::Vector3d(1.6, 2.0, 1.7));
  test::AddBox(&map, Eigen::Vector3d(0.3, 0.3, 2.0), Eigen::Vector3d(0.5, 0.6, 2.2));
  Esdf esdf;
  esdf.Update(map, Eigen::Vector3i::Zero(), map.size_voxels() - Eigen::Vector3i::Ones());
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(0.1, 2.9);
  const double h = 1e-6;
  int checked = 0;
  for (int i = 0; i < 500; ++i) {
    const Eigen::Vector3d p(u(rng), u(rng), u(rng));
    Eigen::Vector3d g;
    const double d = esdf.DistanceAndGradient(p, &g);
    EXPECT_DOUBLE_EQ(d, esdf.Distance(p));
    for (int a = 0; a < 3; ++a) {
      Eigen::Vector3d e = Eigen::Vector3d::Zero();
      e[a] = h;
      const double fd = (esdf.Distance(p + e) - esdf.Distance(p - e)) / (2 * h);
      EXPECT_NEAR(g[a], fd, 1e-5) << p.transpose() << " axis " << a;
      ++checked;
    }
  }
  EXPECT_EQ(checked, 1500);
}

TEST(EsdfTest, InterpolationIsExactAtVoxelCentresAndPointsAwayFromObstacles) {
  VoxelMap map(test::SmallMapConfig(Eigen::Vector3d(3.0, 3.0, 3.0)));
  test::AddBox(&map, Eigen::Vector3d(1.0, 0.0, 0.0),
               Eigen::Vector3d(1.1, 3.0, 3.0));  // a wall x in [1.0, 1.1)
  Esdf esdf;
  esdf.Update(map, Eigen::Vector3i::Zero(), map.size_voxels() - Eigen::Vector3i::Ones());
  EXPECT_NEAR(esdf.Distance(Eigen::Vector3d(1.55, 1.55, 1.55)), 0.5, 1e-6);
  EXPECT_NEAR(esdf.Distance(Eigen::Vector3d(0.55, 1.55, 1.55)), 0.5, 1e-6);
  EXPECT_NEAR(esdf.Distance(Eigen::Vector3d(1.05, 1.55, 1.55)), -0.1, 1e-6);
  Eigen::Vector3d g;
  esdf.DistanceAndGradient(Eigen::Vector3d(1.62, 1.5, 1.5), &g);
  EXPECT_NEAR(g.x(), 1.0, 1e-5);
  EXPECT_NEAR(g.y(), 0.0, 1e-5);
  esdf.DistanceAndGradient(Eigen::Vector3d(0.42, 1.5, 1.5), &g);
  EXPECT_NEAR(g.x(), -1.0, 1e-5);
}

TEST(EsdfTest, WithoutObstaclesTheDistanceIsToTheGroundAndBadWindowsThrow) {
  MapConfig c = test::SmallMapConfig(Eigen::Vector3d(1.0, 1.0, 1.0));
  c.origin_m.z() = -0.5;
  VoxelMap map(c);
  Esdf esdf;
  EXPECT_EQ(esdf.Distance(Eigen::Vector3d(0.5, 0.5, 0.25)), Esdf::kFarDistance);  // never updated
  esdf.Update(map, Eigen::Vector3i::Zero(), Eigen::Vector3i(9, 9, 9));
  EXPECT_EQ(esdf.window_min().z(), 5);  // the ground layers 0..4 are left out
  EXPECT_NEAR(esdf.Distance(Eigen::Vector3d(0.5, 0.5, 0.25)), 0.3, 1e-6);  // to the centre of layer 4 (-0.05)
  EXPECT_THROW(esdf.Update(map, Eigen::Vector3i(5, 5, 5), Eigen::Vector3i(4, 9, 9)), std::invalid_argument);
  EXPECT_THROW(esdf.Update(map, Eigen::Vector3i(0, 0, 0), Eigen::Vector3i(10, 9, 9)), std::invalid_argument);
  EXPECT_THROW(esdf.Update(map, Eigen::Vector3i(0, 0, 0), Eigen::Vector3i(9, 9, 4)), std::invalid_argument);
}

}  // namespace
}  // namespace fast_planner
