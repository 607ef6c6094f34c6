// quad_sim_node's message conversion (src/ros/conversions.h), without a ROS master.
#include "ros/conversions.h"
#include "test_util.h"

#include <gtest/gtest.h>

#include <cstring>

namespace quad_sim_ros {
namespace {

TEST(Conversions, OdometryCarriesTheStateWithTheTwistInTheWorldFrame) {
  quad_core::VehicleState s;
  s.p_world_body = Eigen::Vector3d(1.0, -2.0, 3.0);
  s.v_world = Eigen::Vector3d(0.5, 0.25, -0.125);
  s.q_world_body = Eigen::Quaterniond(Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitZ()));
  s.w_body = Eigen::Vector3d(1.0, 0.0, 0.0);  // roll rate about body x = world y after the 90 deg yaw
  const nav_msgs::Odometry o = ToOdometry(s, StampOf(1005000000ULL));
  EXPECT_EQ(o.header.stamp.toNSec(), 1005000000ULL);
  EXPECT_EQ(o.header.frame_id, "world");
  EXPECT_EQ(o.child_frame_id, "base_link");
  EXPECT_EQ(o.pose.pose.position.y, -2.0);
  EXPECT_DOUBLE_EQ(o.pose.pose.orientation.w, s.q_world_body.w());
  EXPECT_EQ(o.twist.twist.linear.z, -0.125);
  EXPECT_NEAR(o.twist.twist.angular.x, 0.0, 1e-12);
  EXPECT_NEAR(o.twist.twist.angular.y, 1.0, 1e-12);
  const tf2_msgs::TFMessage tf = ToTf(o);
  ASSERT_EQ(tf.transforms.size(), 1u);
  EXPECT_EQ(tf.transforms[0].header.frame_id, "world");
  EXPECT_EQ(tf.transforms[0].child_frame_id, "base_link");
  EXPECT_EQ(tf.transforms[0].transform.translation.z, 3.0);
}

TEST(Conversions, DepthImageIs32FC1RowMajorWithItsCameraInfo) {
  quad_core::DepthImage img;
  img.width = 3;
  img.height = 2;
  img.depth_m = {1.f, 2.f, 3.f, 4.f, 5.f, std::numeric_limits<float>::infinity()};
  const sensor_msgs::Image m = ToImage(img, StampOf(2000000000ULL), 7);
  EXPECT_EQ(m.encoding, "32FC1");
  EXPECT_EQ(m.header.frame_id, "camera");
  EXPECT_EQ(m.header.seq, 7u);
  EXPECT_EQ(m.step, 12u);
  ASSERT_EQ(m.data.size(), 24u);
  float last;
  std::memcpy(&last, m.data.data() + 20, 4);
  EXPECT_TRUE(std::isinf(last));
  quad_core::CameraIntrinsics k;
  k.width = 3;
  k.height = 2;
  k.fx = 10.0;
  k.fy = 11.0;
  k.cx = 1.5;
  k.cy = 1.0;
  const sensor_msgs::CameraInfo c = ToCameraInfo(k, m.header);
  EXPECT_EQ(c.header.stamp, m.header.stamp);
  EXPECT_EQ(c.K[0], 10.0);
  EXPECT_EQ(c.K[4], 11.0);
  EXPECT_EQ(c.K[2], 1.5);
  EXPECT_EQ(c.P[6], 1.0);
  EXPECT_EQ(c.D.size(), 5u);
}

TEST(Conversions, ZeroGainsKeepTheOnboardDefaults) {
  quad_msgs::SO3Command m;
  m.force.z = 5.0;
  m.orientation.w = 1.0;
  m.aux.enable_motors = true;
  quad_sim::So3Command c = FromMsg(m);
  EXPECT_EQ(c.force_world_N.z(), 5.0);
  EXPECT_EQ(c.kR, quad_sim::So3Command().kR);
  EXPECT_EQ(c.kOm, quad_sim::So3Command().kOm);
  EXPECT_TRUE(c.enable_motors);
  m.kR = {2.0, 2.0, 1.0};
  c = FromMsg(m);
  EXPECT_EQ(c.kR, Eigen::Vector3d(2.0, 2.0, 1.0));
  EXPECT_EQ(c.kOm, Eigen::Vector3d::Zero());  // given gains are taken as they are
  quad_msgs::TRPYCommand t;
  t.thrust = 4.0;
  t.yaw = 0.3;
  const quad_sim::TrpyCommand tc = FromMsg(t);
  EXPECT_EQ(tc.thrust_N, 4.0);
  EXPECT_EQ(tc.yaw_rad, 0.3);
  EXPECT_FALSE(tc.enable_motors);
}

TEST(Conversions, ResetRequestKeepsTheOrientationAsGiven) {
  quad_msgs::ResetEpisode::Request r;
  r.seed = 42;
  r.world_file = "w.yaml";
  r.start.position.x = -5.0;
  r.start.orientation.z = 1.0;
  r.goal.y = 3.0;
  const quad_sim::EpisodeRequest e = FromMsg(r);
  EXPECT_EQ(e.seed, 42u);
  EXPECT_EQ(e.world_file, "w.yaml");
  EXPECT_EQ(e.start_world_m.x(), -5.0);
  EXPECT_EQ(e.q_start_wxyz, Eigen::Vector4d(0.0, 0.0, 0.0, 1.0));  // w, x, y, z
  EXPECT_EQ(e.goal_world_m.y(), 3.0);
}

TEST(Conversions, WorldMarkersStatusAndCloudDescribeTheSimulator) {
  quad_sim::SimConfig c = quad_sim_test::DefaultSimConfig();
  quad_sim::Simulator sim(c);
  sim.ResetDefault(5);
  const visualization_msgs::MarkerArray arr = WorldMarkers(sim, StampOf(3000000000ULL));
  // DELETEALL, one cube per box, the ground, the goal, the vehicle.
  ASSERT_EQ(arr.markers.size(), sim.world().boxes.size() + 4);
  EXPECT_EQ(arr.markers.front().action, visualization_msgs::Marker::DELETEALL);
  EXPECT_EQ(arr.markers.back().header.frame_id, "base_link");
  EXPECT_EQ(arr.markers[arr.markers.size() - 2].pose.position.x, sim.goal_world().x());

  quad_msgs::EpisodeStatus s = ToEpisodeStatus(sim, StampOf(3000000000ULL), StampOf(1000000000ULL), 0, 0);
  EXPECT_EQ(s.world_seed, 5u);
  EXPECT_EQ(s.reason, sim.episode().reason);
  EXPECT_EQ(s.collision_box_id, quad_msgs::EpisodeStatus::COLLISION_NONE);
  s = ToEpisodeStatus(sim, StampOf(3000000000ULL), StampOf(1000000000ULL), 2, 1);
  EXPECT_EQ(s.reason, sim.episode().reason + "; lockstep timeouts: 2 command, 1 ack");

  const sensor_msgs::PointCloud2 cloud =
      ToCloud({Eigen::Vector3f(1, 2, 3), Eigen::Vector3f(4, 5, 6)}, s.sim_time);
  EXPECT_EQ(cloud.width * cloud.height, 2u);
  EXPECT_EQ(cloud.header.frame_id, "world");
  float x1;
  std::memcpy(&x1, cloud.data.data() + cloud.point_step, 4);
  EXPECT_EQ(x1, 4.0f);
}

}  // namespace
}  // namespace quad_sim_ros
