#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>

#include "fast_planner/kinodynamic_astar.h"
#include "fast_planner/obvp.h"
#include "test_util.h"

namespace fast_planner {
namespace {

// ---------------------------------------------------------------- closed-form pieces

TEST(ObvpTest, QuarticRootsAreRootsAndNoneIsMissed) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int trial = 0; trial < 2000; ++trial) {
    // Build from known roots half of the time so that multiple real roots occur.
    double p, q, r;
    if (trial % 2 == 0) {
      const double a = 3 * u(rng), b = 3 * u(rng), c = 3 * u(rng);
      const double d = -(a + b + c);  // depressed: the roots sum to zero
      p = a * b + a * c + a * d + b * c + b * d + c * d;
      q = -(a * b * c + a * b * d + a * c * d + b * c * d);
      r = a * b * c * d;
    } else {
      p = 10 * u(rng);
      q = 10 * u(rng);
      r = 10 * u(rng);
    }
    double roots[4];
    const int n = SolveDepressedQuartic(p, q, r, roots);
    const auto quartic = [&](double y) { return ((y * y + p) * y + q) * y + r; };
    for (int i = 0; i < n; ++i) {
      EXPECT_NEAR(quartic(roots[i]), 0.0, 1e-7 * (1 + std::pow(std::abs(roots[i]), 4))) << trial;
    }
    // Every sign change on a fine grid lies near a returned root.
    const double lo = -12, step = 1e-3;
    for (double y = lo; y < -lo; y += step) {
      if (quartic(y) * quartic(y + step) < 0.0) {
        bool found = false;
        for (int i = 0; i < n; ++i) found |= roots[i] >= y - 1e-6 && roots[i] <= y + step + 1e-6;
        EXPECT_TRUE(found) << "trial " << trial << " missed the root near " << y;
      }
    }
  }
}

TEST(ObvpTest, SegmentMeetsBoundaryConditionsAndItsEffortIsTheClosedFormCost) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-3.0, 3.0);
  for (int trial = 0; trial < 50; ++trial) {
    const Eigen::Vector3d p0(u(rng), u(rng), u(rng)), v0(u(rng), u(rng), u(rng));
    const Eigen::Vector3d p1(u(rng), u(rng), u(rng)), v1(u(rng), u(rng), u(rng));
    const double T = 0.5 + std::abs(u(rng));
    const double rho = 7.0;
    const PolySegment s = ObvpSegment(p0, v0, p1, v1, T);
    EXPECT_LT((s.Position(0) - p0).norm(), 1e-12);
    EXPECT_LT((s.Velocity(0) - v0).norm(), 1e-12);
    EXPECT_LT((s.Position(T) - p1).norm(), 1e-9);
    EXPECT_LT((s.Velocity(T) - v1).norm(), 1e-9);
    // Simpson's rule is exact for the quadratic |a(t)|^2.
    const double effort = T / 6.0 *
                          (s.Acceleration(0).squaredNorm() + 4 * s.Acceleration(T / 2).squaredNorm() +
                           s.Acceleration(T).squaredNorm());
    EXPECT_NEAR(ObvpCost(p0, v0, p1, v1, T, rho), effort + rho * T, 1e-9 * (1 + effort));
  }
}

TEST(ObvpTest, OptimalTimeMinimisesTheCostOverADenseGrid) {
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> u(-3.0, 3.0);
  for (int trial = 0; trial < 200; ++trial) {
    const Eigen::Vector3d p0(u(rng), u(rng), u(rng)), v0(u(rng), u(rng), u(rng));
    const Eigen::Vector3d p1 = p0 + 2 * Eigen::Vector3d(u(rng), u(rng), u(rng));
    const double rho = 0.5 + 10 * std::abs(u(rng));
    const double t_min = trial % 3 == 0 ? 0.0 : 0.3 * std::abs(u(rng));
    const ObvpSolution sol = SolveObvp(p0, v0, p1, Eigen::Vector3d::Zero(), rho, t_min);
    ASSERT_GE(sol.duration_s, t_min);
    EXPECT_NEAR(sol.cost, ObvpCost(p0, v0, p1, Eigen::Vector3d::Zero(), sol.duration_s, rho), 1e-9);
    double best = std::numeric_limits<double>::infinity();
    for (double T = std::max(t_min, 1e-3); T < 40.0; T += 1e-3) {
      best = std::min(best, ObvpCost(p0, v0, p1, Eigen::Vector3d::Zero(), T, rho));
    }
    EXPECT_LE(sol.cost, best + 1e-9) << "trial " << trial;
    EXPECT_NEAR(sol.cost, best, 1e-3 * (1 + best)) << "trial " << trial;
  }
}

// ---------------------------------------------------------------- search on hand-made maps

// The default search with a 7 m horizon (and shot radius), so that the hand-made scenes fit in it.
SearchConfig Search7() {
  SearchConfig s;
  s.horizon_m = 7.0;
  s.shot_radius_m = 7.0;
  return s;
}

// A 20 x 10 x 4 m map, ground at z = 0 (inflated up to 0.3 m), no obstacles yet.
class AstarTest : public ::testing::Test {
 protected:
  AstarTest()
      : map_(test::SmallMapConfig(Eigen::Vector3d(20.0, 10.0, 4.0), 0.1, 0.3, 0.0, 4.0)),
        astar_(Search7(), LimitsConfig{}) {}

  // Every point of the path, sampled every 5 ms, is outside the inflated map; speed and |acc| within limits.
  void ExpectSafeAndFeasible(const PolyPath& path) {
    for (double t = 0.0; t <= path.duration_s(); t += 0.005) {
      ASSERT_FALSE(map_.IsInflated(path.Position(t))) << "t=" << t << " p=" << path.Position(t).transpose();
      ASSERT_LE(path.Velocity(t).norm(), 3.0 + 1e-6) << "t=" << t;
      ASSERT_LE(path.Acceleration(t).norm(), 2.0 + 1e-6) << "t=" << t;
    }
  }

  VoxelMap map_;
  KinodynamicAstar astar_;
};

TEST_F(AstarTest, OpenSpaceGivesAStraightPathToTheGoalAtRest) {
  const Eigen::Vector3d start(2.0, 5.0, 1.5), goal(8.0, 5.0, 1.5);
  const SearchResult r = astar_.Search(map_, start, Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero(), goal);
  ASSERT_EQ(r.status, SearchStatus::kReachedGoal) << r.reason;
  EXPECT_TRUE(r.ends_with_shot);
  EXPECT_LT((r.path.Position(r.path.duration_s()) - goal).norm(), 1e-9);
  EXPECT_LT(r.path.Velocity(r.path.duration_s()).norm(), 1e-9);
  for (double t = 0.0; t <= r.path.duration_s(); t += 0.01) {
    const Eigen::Vector3d p = r.path.Position(t);
    EXPECT_LT(std::hypot(p.y() - 5.0, p.z() - 1.5), 0.05) << "t=" << t;
  }
  ExpectSafeAndFeasible(r.path);
}

TEST_F(AstarTest, WallBetweenStartAndGoalGivesADetour) {
  test::AddBox(&map_, Eigen::Vector3d(5.0, 2.0, 0.0), Eigen::Vector3d(5.3, 8.0, 4.0));
  const Eigen::Vector3d start(2.0, 5.0, 1.5), goal(8.0, 5.0, 1.5);
  const SearchResult r = astar_.Search(map_, start, Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero(), goal);
  ASSERT_EQ(r.status, SearchStatus::kReachedGoal) << r.reason;
  double max_dev = 0.0;
  for (double t = 0.0; t <= r.path.duration_s(); t += 0.01)
    max_dev = std::max(max_dev, std::abs(r.path.Position(t).y() - 5.0));
  EXPECT_GT(max_dev, 3.3);  // around an end of the wall (y = 2 or 8, plus the inflation)
  ExpectSafeAndFeasible(r.path);
}

// A hollow box around (7.5, 5, 1.75), walls 0.2 m thick.
void AddHollowBox(VoxelMap* map) {
  const Eigen::Vector3d lo(6.0, 3.0, 0.5), hi(9.0, 7.0, 3.0);
  test::AddBox(map, lo, Eigen::Vector3d(hi.x(), hi.y(), lo.z() + 0.2));
  test::AddBox(map, Eigen::Vector3d(lo.x(), lo.y(), hi.z() - 0.2), hi);
  test::AddBox(map, lo, Eigen::Vector3d(lo.x() + 0.2, hi.y(), hi.z()));
  test::AddBox(map, Eigen::Vector3d(hi.x() - 0.2, lo.y(), lo.z()), hi);
  test::AddBox(map, lo, Eigen::Vector3d(hi.x(), lo.y() + 0.2, hi.z()));
  test::AddBox(map, Eigen::Vector3d(lo.x(), hi.y() - 0.2, lo.z()), hi);
}

TEST_F(AstarTest, EnclosedGoalGivesNoPath) {
  AddHollowBox(&map_);
  // A coarse pruning grid so that every reachable state within the horizon can be expanded in a unit test.
  SearchConfig s = Search7();
  s.resolution_m = 0.3;
  s.horizon_m = 6.0;
  s.max_nodes = 50000;
  KinodynamicAstar coarse(s, LimitsConfig{});
  const SearchResult r = coarse.Search(map_, Eigen::Vector3d(2.0, 5.0, 1.5), Eigen::Vector3d::Zero(),
                                       Eigen::Vector3d::Zero(), Eigen::Vector3d(7.5, 5.0, 1.75));
  EXPECT_EQ(r.status, SearchStatus::kNoPath) << r.reason;
  EXPECT_FALSE(r.ok());
  EXPECT_TRUE(r.path.empty());
  EXPECT_NE(r.reason.find("no path: every reachable state within 6 m was expanded"), std::string::npos)
      << r.reason;
}

TEST_F(AstarTest, EnclosedGoalWithTheDefaultGridEndsWhenTheNodeBudgetIsSpent) {
  AddHollowBox(&map_);
  SearchConfig s = Search7();
  s.max_nodes = 3000;
  KinodynamicAstar a(s, LimitsConfig{});
  const SearchResult r = a.Search(map_, Eigen::Vector3d(2.0, 5.0, 1.5), Eigen::Vector3d::Zero(),
                                  Eigen::Vector3d::Zero(), Eigen::Vector3d(7.5, 5.0, 1.75));
  EXPECT_EQ(r.status, SearchStatus::kNodeBudgetExhausted) << r.reason;
  EXPECT_FALSE(r.ok());
  EXPECT_NE(r.reason.find("node budget exhausted: more than 3000 nodes"), std::string::npos) << r.reason;
}

TEST_F(AstarTest, MovingTowardAWallWithNoWayAroundItEndsAtASafeStop) {
  // A wall across the whole corridor (y, and z up to the ceiling band): the goal behind it is unreachable.
  test::AddBox(&map_, Eigen::Vector3d(6.0, 0.0, 0.0), Eigen::Vector3d(6.3, 10.0, 4.0));
  SearchConfig s = Search7();
  s.max_nodes = 3000;
  KinodynamicAstar astar(s, LimitsConfig{});
  const SearchResult r = astar.Search(map_, Eigen::Vector3d(3.0, 5.0, 1.5), Eigen::Vector3d(2.5, 0.0, 0.0),
                                      Eigen::Vector3d::Zero(), Eigen::Vector3d(9.0, 5.0, 1.5));
  ASSERT_EQ(r.status, SearchStatus::kReachedSafeStop) << r.reason;
  EXPECT_TRUE(r.ok());
  EXPECT_TRUE(r.ends_at_rest());
  EXPECT_NE(r.reason.find("after node budget exhausted"), std::string::npos) << r.reason;
  const double T = r.path.duration_s();
  EXPECT_LT(r.path.Velocity(T).norm(), 1e-9);
  EXPECT_LT(r.path.Position(T).x(), 6.0 - 0.3);
  ExpectSafeAndFeasible(r.path);
  // From rest, standing still is no plan: the search fails.
  const SearchResult rest = astar.Search(map_, Eigen::Vector3d(3.0, 5.0, 1.5), Eigen::Vector3d::Zero(),
                                         Eigen::Vector3d::Zero(), Eigen::Vector3d(9.0, 5.0, 1.5));
  EXPECT_EQ(rest.status, SearchStatus::kNodeBudgetExhausted) << rest.reason;
  EXPECT_FALSE(rest.ok());
}

TEST_F(AstarTest, FarGoalEndsAtTheHorizonHeadingToTheGoal) {
  const Eigen::Vector3d start(2.0, 5.0, 1.5), goal(18.0, 6.0, 1.5);
  const SearchResult r = astar_.Search(map_, start, Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero(), goal);
  ASSERT_EQ(r.status, SearchStatus::kReachedHorizon) << r.reason;
  const Eigen::Vector3d end = r.path.Position(r.path.duration_s());
  EXPECT_GE((end - start).norm(), 7.0);
  EXPECT_LT((end - start).norm(), 7.0 + 3.0 * 0.6);
  EXPECT_GT((end - start).normalized().dot((goal - start).normalized()), 0.95);
  ExpectSafeAndFeasible(r.path);
}

TEST_F(AstarTest, ThinWallIsNotCrossedByFastPrimitives) {
  // One voxel thick, everywhere except a gap near y = 9 (the path must go there).
  test::AddBox(&map_, Eigen::Vector3d(6.0, 0.0, 0.0), Eigen::Vector3d(6.1, 8.0, 4.0));
  const SearchResult r = astar_.Search(map_, Eigen::Vector3d(3.0, 5.0, 1.5), Eigen::Vector3d(2.5, 0.0, 0.0),
                                       Eigen::Vector3d::Zero(), Eigen::Vector3d(9.0, 5.0, 1.5));
  ASSERT_EQ(r.status, SearchStatus::kReachedGoal) << r.reason;
  for (double t = 0.0; t + 0.001 <= r.path.duration_s(); t += 0.001) {
    const Eigen::Vector3d a = r.path.Position(t), b = r.path.Position(t + 0.001);
    if ((a.x() - 6.05) * (b.x() - 6.05) <= 0.0) {
      EXPECT_GT(a.y(), 8.3) << "crossed the wall at " << a.transpose();
    }
  }
  ExpectSafeAndFeasible(r.path);
}

TEST_F(AstarTest, ShotIsRejectedWhenItWouldExceedTheVelocityLimit) {
  // A large time weight makes the optimal shot as short as Fast-Planner's bound T >= max|dp| / v_max allows;
  // a cubic from rest to rest then peaks at 1.5x the average speed, i.e. 4.5 m/s > 3 m/s.
  SearchConfig s = Search7();
  s.time_weight = 1000.0;
  KinodynamicAstar fast(s, LimitsConfig{});
  const Eigen::Vector3d start(2.0, 5.0, 1.5), goal(7.0, 5.0, 1.5);
  const ObvpSolution sol =
      SolveObvp(start, Eigen::Vector3d::Zero(), goal, Eigen::Vector3d::Zero(), 1000.0, 5.0 / 3.0);
  ASSERT_FALSE(fast.SegmentWithinLimits(
      ObvpSegment(start, Eigen::Vector3d::Zero(), goal, Eigen::Vector3d::Zero(), sol.duration_s)));
  const SearchResult r = fast.Search(map_, start, Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero(), goal);
  ASSERT_EQ(r.status, SearchStatus::kReachedGoal) << r.reason;
  ExpectSafeAndFeasible(r.path);
}

TEST_F(AstarTest, FastStartTowardACloseGoalStaysWithinTheAccelerationLimit) {
  const SearchResult r = astar_.Search(map_, Eigen::Vector3d(2.0, 5.0, 1.5), Eigen::Vector3d(2.9, 0.0, 0.0),
                                       Eigen::Vector3d::Zero(), Eigen::Vector3d(3.5, 5.0, 1.5));
  ASSERT_EQ(r.status, SearchStatus::kReachedGoal) << r.reason;
  ExpectSafeAndFeasible(r.path);
  // It cannot stop within 1.5 m at 2 m/s^2 from 2.9 m/s, so it overshoots and comes back.
  double max_x = 0.0;
  for (double t = 0.0; t <= r.path.duration_s(); t += 0.01) max_x = std::max(max_x, r.path.Position(t).x());
  EXPECT_GT(max_x, 3.5 + 0.5);
}

TEST_F(AstarTest, BadRequestsAreRejectedWithAReason) {
  test::AddBox(&map_, Eigen::Vector3d(10.0, 4.0, 1.0), Eigen::Vector3d(11.0, 6.0, 2.0));
  const Eigen::Vector3d start(2.0, 5.0, 1.5), zero = Eigen::Vector3d::Zero();
  SearchResult r = astar_.Search(map_, start, zero, Eigen::Vector3d::Zero(), Eigen::Vector3d(10.5, 5.0, 1.5));
  EXPECT_EQ(r.status, SearchStatus::kGoalInCollision);
  EXPECT_EQ(r.reason, "goal in collision: goal voxel is occupied");
  r = astar_.Search(map_, start, zero, Eigen::Vector3d::Zero(), Eigen::Vector3d(11.15, 5.0, 1.5));
  EXPECT_EQ(r.reason, "goal in collision: goal is within the inflation radius of an obstacle");
  r = astar_.Search(map_, start, zero, Eigen::Vector3d::Zero(), Eigen::Vector3d(25.0, 5.0, 1.5));
  EXPECT_EQ(r.reason, "outside the map: goal is outside the map");
  r = astar_.Search(map_, start, zero, Eigen::Vector3d::Zero(), Eigen::Vector3d(5.0, 5.0, -1.0));
  EXPECT_EQ(r.status, SearchStatus::kOutsideMap);
  r = astar_.Search(map_, Eigen::Vector3d(10.5, 5.0, 1.5), zero, Eigen::Vector3d::Zero(),
                    Eigen::Vector3d(5.0, 5.0, 1.5));
  EXPECT_EQ(r.reason, "start in collision: start voxel is occupied");
  r = astar_.Search(map_, start, Eigen::Vector3d(std::nan(""), 0, 0), Eigen::Vector3d::Zero(),
                    Eigen::Vector3d(5.0, 5.0, 1.5));
  EXPECT_EQ(r.reason, "invalid input: start or goal is not finite");
  // Goals on or near the ground (Fast-Planner planned below it).
  r = astar_.Search(map_, start, zero, Eigen::Vector3d::Zero(), Eigen::Vector3d(5.0, 5.0, 0.15));
  EXPECT_EQ(r.status, SearchStatus::kGoalInCollision);
}

TEST_F(AstarTest, PathsNeverGoBelowTheGround) {
  // A wall that is open only below the ground's inflation band: the planner must go around, not under.
  test::AddBox(&map_, Eigen::Vector3d(5.0, 0.0, 0.25), Eigen::Vector3d(5.3, 10.0, 4.0));
  const SearchResult r = astar_.Search(map_, Eigen::Vector3d(2.0, 5.0, 0.6), Eigen::Vector3d::Zero(),
                                       Eigen::Vector3d::Zero(), Eigen::Vector3d(8.0, 5.0, 0.6));
  EXPECT_FALSE(r.ok()) << r.reason;
}

TEST_F(AstarTest, StartInsideTheInflationRadiusCanEscape) {
  test::AddBox(&map_, Eigen::Vector3d(5.0, 0.0, 0.0), Eigen::Vector3d(5.3, 10.0, 4.0));
  const Eigen::Vector3d start(4.8, 5.0, 1.5);  // 0.15 m from the wall voxels' centres: inflated, not occupied
  ASSERT_TRUE(map_.IsInflated(start));
  ASSERT_FALSE(map_.IsOccupied(start));
  const SearchResult r = astar_.Search(map_, start, Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero(),
                                       Eigen::Vector3d(2.0, 5.0, 1.5));
  ASSERT_EQ(r.status, SearchStatus::kReachedGoal) << r.reason;
}

TEST(AstarConfigTest, BadSearchParametersThrowNamingTheKey) {
  SearchConfig s;
  s.acc_levels_per_axis = 6;
  try {
    KinodynamicAstar a(s, LimitsConfig{});
    FAIL();
  } catch (const std::exception& e) {
    EXPECT_NE(std::string(e.what()).find("search.acc_levels_per_axis"), std::string::npos);
  }
  LimitsConfig l;
  l.max_vel_mps = 0.0;
  EXPECT_THROW(KinodynamicAstar(SearchConfig{}, l), std::exception);
}

}  // namespace
}  // namespace fast_planner
