// The odometry buffer depth frames are paired with (the rule is quad_core/pairing.h), the camera pose from
// the paired odometry, and the labeller's request.
#include <gtest/gtest.h>

#include <cmath>
#include <stdexcept>

#include "fast_planner/labeller.h"
#include "fast_planner/odometry_history.h"
#include "test_util.h"

namespace fast_planner {
namespace {

quad_core::VehicleState At(double t_s, const Eigen::Vector3d& v = Eigen::Vector3d(1.0, 0.0, 0.0)) {
  quad_core::VehicleState s;
  s.t_s = t_s;
  s.p_world_body = Eigen::Vector3d(t_s, 0.0, 1.0);
  s.v_world = v;
  return s;
}

TEST(OdometryHistory, AFrameIsCoveredOnceItsControlPeriodsOdometryArrived) {
  OdometryHistory h(200, 0.005);
  EXPECT_FALSE(h.Covers(1.0));  // nothing yet
  h.Push(At(0.990));
  EXPECT_FALSE(h.Covers(1.0));  // two periods before the frame
  h.Push(At(0.995));
  EXPECT_FALSE(h.Covers(1.0));  // exactly one period before: the frame's own period has not arrived
  h.Push(At(1.000));
  EXPECT_TRUE(h.Covers(1.0));
}

TEST(OdometryHistory, AFrameIsPairedWithTheNewestOdometryNotAfterIt) {
  OdometryHistory h(200, 0.005);
  EXPECT_EQ(h.PairedWith(1.0), nullptr);
  h.Push(At(0.995));
  h.Push(At(1.000));
  h.Push(At(1.005));  // overtook the frame: never paired with it
  ASSERT_NE(h.PairedWith(1.0), nullptr);
  EXPECT_EQ(h.PairedWith(1.0)->t_s, 1.000);
  EXPECT_EQ(h.PairedWith(1.003)->t_s, 1.000);
  EXPECT_EQ(h.PairedWith(0.990), nullptr);
}

TEST(OdometryHistory, KeepsTheNewestUpToItsCapacity) {
  OdometryHistory h(3, 0.005);
  for (int i = 0; i < 5; ++i) h.Push(At(0.005 * i));
  ASSERT_EQ(h.samples().size(), 3u);
  EXPECT_EQ(h.samples().front().t_s, 0.010);
  EXPECT_EQ(h.newest().t_s, 0.020);
  EXPECT_EQ(h.Since(0.015).size(), 2u);
  EXPECT_THROW(OdometryHistory(0, 0.005), std::invalid_argument);
  EXPECT_THROW(OdometryHistory(3, 0.0), std::invalid_argument);
}

TEST(CameraPoseAt, MovesTheOdometryOnToTheStampAndAppliesTheMount) {
  quad_core::VehicleState o = At(1.0, Eigen::Vector3d(2.0, 0.0, 0.0));
  o.q_world_body = Eigen::Quaterniond(Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitZ()));  // facing +y
  o.q_world_body.coeffs() *= 3.0;  // not normalised
  const CameraMount mount{Eigen::Vector3d(0.1, 0.0, 0.05), Eigen::Quaterniond::Identity()};
  const CameraPose pose = CameraPoseAt(o, 1.004, mount);
  // Body at (1 + 2 * 0.004, 0, 1); the mount's 0.1 m forward is +y in the world.
  EXPECT_NEAR((pose.p_world_camera - Eigen::Vector3d(1.008, 0.1, 1.05)).norm(), 0.0, 1e-12);
  EXPECT_NEAR(pose.q_world_camera.angularDistance(o.q_world_body.normalized()), 0.0, 1e-12);
}

TEST(Labeller, RequestStartsFromTheStateAtTheFrame) {
  OdometryHistory h(200, 0.005);
  // Accelerating at 1 m/s^2 along x, odometry every 5 ms.
  for (int i = 0; i <= 40; ++i) h.Push(At(0.005 * i, Eigen::Vector3d(0.005 * i, 0.0, 0.0)));
  Labeller labeller(0.05);
  EXPECT_FALSE(labeller.RequestAt(h, 0.2, 2.0).has_value());  // no goal yet
  PlannerConfig cfg;
  cfg.map = test::SmallMapConfig(Eigen::Vector3d(20.0, 10.0, 4.0), 0.1, 0.3, 0.0, 4.0);
  cfg.map.local_update_range_m = Eigen::Vector3d(8.0, 8.0, 2.0);
  const PlannerManager m(cfg);
  ASSERT_EQ(labeller.SetGoal(m, Eigen::Vector3d(5.0, 1.0, 1.0)), "");
  const auto r = labeller.RequestAt(h, 0.1024, 2.0);
  ASSERT_TRUE(r.has_value());
  EXPECT_EQ(r->odometry.t_s, 0.1);                                 // paired: the newest not after 0.1024
  EXPECT_NEAR(r->request.start_p.x(), 0.1 + 0.1 * 0.0024, 1e-12);  // moved on at its velocity
  EXPECT_NEAR((r->request.start_a - Eigen::Vector3d(1, 0, 0)).norm(), 0.0, 1e-9);  // window 0.05 s
  EXPECT_EQ(r->request.start_time_s, 0.1024);
  EXPECT_EQ(r->request.goal, Eigen::Vector3d(5.0, 1.0, 1.0));
  EXPECT_FALSE(labeller.RequestAt(h, -1.0, 2.0).has_value());            // no odometry at or before the frame
  EXPECT_NE(labeller.SetGoal(m, Eigen::Vector3d(500.0, 0.0, 1.0)), "");  // outside the map: refused
  EXPECT_EQ(*labeller.goal(), Eigen::Vector3d(5.0, 1.0, 1.0));           // the previous goal stays
  labeller.Reset();
  EXPECT_FALSE(labeller.goal().has_value());
  EXPECT_THROW(Labeller(-0.1), std::invalid_argument);
}

}  // namespace
}  // namespace fast_planner
