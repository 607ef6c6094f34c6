// The small vocabulary types: vehicle state, camera intrinsics, depth images, the pairing rule.
#include <gtest/gtest.h>

#include <cmath>
#include <deque>
#include <limits>

#include "quad_core/camera.h"
#include "quad_core/depth_image.h"
#include "quad_core/pairing.h"
#include "quad_core/vehicle_state.h"

namespace {

TEST(VehicleState, FiniteAndYaw) {
  quad_core::VehicleState s;
  EXPECT_TRUE(s.AllFinite());
  s.q_world_body = Eigen::Quaterniond(Eigen::AngleAxisd(2.0, Eigen::Vector3d::UnitZ()));
  EXPECT_NEAR(s.Yaw(), 2.0, 1e-12);
  s.v_world.x() = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(s.AllFinite());
  s.v_world.x() = 0.0;
  s.q_world_body = Eigen::Quaterniond(0.0, 0.0, 0.0, 0.0);
  EXPECT_FALSE(s.AllFinite());
}

TEST(VehicleState, WrapAngleIsHalfOpen) {
  EXPECT_DOUBLE_EQ(quad_core::WrapAngle(M_PI), M_PI);
  EXPECT_DOUBLE_EQ(quad_core::WrapAngle(-M_PI), M_PI);
  EXPECT_NEAR(quad_core::WrapAngle(3.0 * M_PI / 2.0), -M_PI / 2.0, 1e-12);
}

TEST(CameraIntrinsics, ValidateNamesTheProblem) {
  quad_core::CameraIntrinsics k{320, 240, 193.6, 193.6, 159.5, 119.5};
  EXPECT_EQ(k.Validate(), "");
  k.width = 0;
  EXPECT_NE(k.Validate().find("image size 0 x 240"), std::string::npos);
  k.width = 320;
  k.fy = -1.0;
  EXPECT_NE(k.Validate().find("fy=-1"), std::string::npos);
  k.fy = 193.6;
  k.cx = std::numeric_limits<double>::infinity();
  EXPECT_NE(k.Validate().find("principal point"), std::string::npos);
}

TEST(DepthImage, ViewIndexesRowMajor) {
  quad_core::DepthImage img{3, 2, {0.f, 1.f, 2.f, 3.f, 4.f, 5.f}};
  EXPECT_EQ(img.at(1, 2), 5.f);
  const quad_core::DepthImageView v = img.view();
  EXPECT_EQ(v.row_stride, 3u);
  EXPECT_EQ(v.at(1, 0), 3.f);
  // A strided view of the right column.
  const quad_core::DepthImageView col{1, 2, 3, img.depth_m.data() + 2};
  EXPECT_EQ(col.at(1, 0), 5.f);
}

TEST(Pairing, CoverIsWithinOnePeriodBeforeTheFrame) {
  const double period = 0.005;
  // The odometry of the frame's own control period covers it...
  EXPECT_TRUE(quad_core::OdometryCoversFrame(1.000, 1.000, period));
  EXPECT_TRUE(quad_core::OdometryCoversFrame(0.996, 1.000, period));
  // ...one period older does not (exactly one period: not covered, the rule is strict with a margin).
  EXPECT_FALSE(quad_core::OdometryCoversFrame(0.995, 1.000, period));
  EXPECT_FALSE(quad_core::OdometryCoversFrame(0.990, 1.000, period));
}

TEST(Pairing, PicksTheNewestNotNewerThanTheFrame) {
  const std::deque<double> stamps{0.990, 0.995, 1.000, 1.005};
  const auto stamp_of = [](double s) { return s; };
  const double* p = quad_core::PairedOdometry(stamps, 1.000, stamp_of);
  ASSERT_NE(p, nullptr);
  EXPECT_DOUBLE_EQ(*p, 1.000);
  // A stamp that lost a nanosecond on the way still pairs.
  p = quad_core::PairedOdometry(stamps, 1.000 - 5e-10, stamp_of);
  ASSERT_NE(p, nullptr);
  EXPECT_DOUBLE_EQ(*p, 1.000);
  p = quad_core::PairedOdometry(stamps, 0.997, stamp_of);
  ASSERT_NE(p, nullptr);
  EXPECT_DOUBLE_EQ(*p, 0.995);
  EXPECT_EQ(quad_core::PairedOdometry(stamps, 0.5, stamp_of), nullptr);
}

}  // namespace
