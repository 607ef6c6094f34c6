// quad_ros: ROS messages <-> quad_core's vocabulary, without a ROS master.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>

#include "quad_ros/vocabulary.h"

namespace {

TEST(Odometry, CarriesTheStateWithTheTwistInTheWorldFrame) {
  quad_core::VehicleState s;
  s.p_world_body = Eigen::Vector3d(1.0, -2.0, 3.0);
  s.v_world = Eigen::Vector3d(0.5, 0.25, -0.125);
  s.q_world_body = Eigen::Quaterniond(Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitZ()));
  s.w_body = Eigen::Vector3d(1.0, 0.0, 0.0);  // roll rate about body x = world y after the 90 deg yaw
  ros::Time stamp;
  stamp.fromNSec(1005000000ULL);
  const nav_msgs::Odometry o = quad_ros::ToOdometryMsg(s, stamp);
  EXPECT_EQ(o.header.stamp.toNSec(), 1005000000ULL);
  EXPECT_EQ(o.header.frame_id, "world");
  EXPECT_EQ(o.child_frame_id, "base_link");
  EXPECT_EQ(o.pose.pose.position.y, -2.0);
  EXPECT_DOUBLE_EQ(o.pose.pose.orientation.w, s.q_world_body.w());
  EXPECT_EQ(o.twist.twist.linear.z, -0.125);
  EXPECT_NEAR(o.twist.twist.angular.x, 0.0, 1e-12);
  EXPECT_NEAR(o.twist.twist.angular.y, 1.0, 1e-12);

  // Back: the same stamp, pose and velocity; the angular velocity as the message holds it (world axes).
  const quad_core::VehicleState r = quad_ros::ToVehicleState(o);
  EXPECT_DOUBLE_EQ(r.t_s, 1.005);
  EXPECT_EQ(r.p_world_body, s.p_world_body);
  EXPECT_EQ(r.v_world, s.v_world);
  EXPECT_TRUE(r.q_world_body.isApprox(s.q_world_body, 0.0));
  EXPECT_NEAR(r.w_body.y(), 1.0, 1e-12);
  EXPECT_FALSE(r.has_accel);
}

TEST(Odometry, NonFiniteValuesPassThroughForTheConsumersToRefuse) {
  nav_msgs::Odometry o;
  o.pose.pose.orientation.w = 1.0;
  o.twist.twist.linear.x = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(quad_ros::ToVehicleState(o).AllFinite());
}

TEST(Camera, IntrinsicsRoundTripThroughCameraInfo) {
  const quad_core::CameraIntrinsics k{3, 2, 10.0, 11.0, 1.5, 1.0};
  std_msgs::Header h;
  h.frame_id = "camera";
  const sensor_msgs::CameraInfo c = quad_ros::ToCameraInfo(k, h);
  EXPECT_EQ(c.header.frame_id, "camera");
  EXPECT_EQ(c.K[0], 10.0);
  EXPECT_EQ(c.K[4], 11.0);
  EXPECT_EQ(c.P[6], 1.0);
  EXPECT_EQ(c.D.size(), 5u);
  const quad_core::CameraIntrinsics back = quad_ros::ToIntrinsics(c);
  EXPECT_EQ(back.width, 3);
  EXPECT_EQ(back.height, 2);
  EXPECT_EQ(back.fx, 10.0);
  EXPECT_EQ(back.fy, 11.0);
  EXPECT_EQ(back.cx, 1.5);
  EXPECT_EQ(back.cy, 1.0);
}

TEST(Depth, ImageIs32FC1RowMajorAndItsViewReadsItBack) {
  quad_core::DepthImage img{3, 2, {1.f, 2.f, 3.f, 4.f, 5.f, std::numeric_limits<float>::infinity()}};
  ros::Time stamp;
  stamp.fromNSec(2000000000ULL);
  const sensor_msgs::Image m = quad_ros::ToImageMsg(img, stamp, 7);
  EXPECT_EQ(m.encoding, "32FC1");
  EXPECT_EQ(m.header.frame_id, "camera");
  EXPECT_EQ(m.header.seq, 7u);
  EXPECT_EQ(m.step, 12u);
  ASSERT_EQ(m.data.size(), 24u);
  const quad_core::DepthImageView v = quad_ros::DepthViewOf(m);
  EXPECT_EQ(v.width, 3);
  EXPECT_EQ(v.row_stride, 3u);
  EXPECT_EQ(v.at(1, 1), 5.f);
  EXPECT_TRUE(std::isinf(v.at(1, 2)));
  // Padded rows: the view steps over the padding.
  sensor_msgs::Image padded = m;
  padded.step = 16;
  padded.data.assign(32, 0);
  const float six = 6.f;
  std::memcpy(padded.data.data() + 16 + 8, &six, 4);
  EXPECT_EQ(quad_ros::DepthViewOf(padded).at(1, 2), 6.f);
}

}  // namespace
