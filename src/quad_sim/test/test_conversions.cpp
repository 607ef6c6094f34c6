// quad_sim_node's message conversion (src/ros/conversions.h), without a ROS master.
#include "quad_ros/vocabulary.h"
#include "ros/conversions.h"
#include "test_util.h"

#include <gtest/gtest.h>

#include <cstring>

namespace quad_sim_ros {
namespace {

TEST(Conversions, TfOfTheOdometryIsWorldToBaseLink) {
  quad_core::VehicleState s;
  s.p_world_body = Eigen::Vector3d(1.0, -2.0, 3.0);
  const tf2_msgs::TFMessage tf = ToTf(quad_ros::ToOdometryMsg(s, StampOf(1005000000ULL)));
  ASSERT_EQ(tf.transforms.size(), 1u);
  EXPECT_EQ(tf.transforms[0].header.stamp.toNSec(), 1005000000ULL);
  EXPECT_EQ(tf.transforms[0].header.frame_id, "world");
  EXPECT_EQ(tf.transforms[0].child_frame_id, "base_link");
  EXPECT_EQ(tf.transforms[0].transform.translation.z, 3.0);
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
  EXPECT_FALSE(e.keyed);  // the message default: an unkeyed episode
}

TEST(Conversions, ResetRequestPassesTheEpisodeKey) {
  quad_msgs::ResetEpisode::Request r;
  r.keyed = true;
  r.episode_index = 4000000;
  const quad_sim::EpisodeRequest e = FromMsg(r);
  EXPECT_TRUE(e.keyed);
  EXPECT_EQ(e.episode_index, 4000000u);
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
