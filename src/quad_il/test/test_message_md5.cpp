// The wire compatibility promise of quad_msgs: MD5 sums equal to Fast-Planner's Bspline and kr_mav_msgs'.
#include <gtest/gtest.h>
#include <quad_msgs/AuxCommand.h>
#include <quad_msgs/Bspline.h>
#include <quad_msgs/PositionCommand.h>
#include <quad_msgs/SO3Command.h>
#include <quad_msgs/TRPYCommand.h>
#include <ros/message_traits.h>

template <typename M>
std::string Md5() {
  return ros::message_traits::MD5Sum<M>::value();
}

TEST(MessageMd5, BsplineMatchesFastPlanner) {
  EXPECT_EQ(Md5<quad_msgs::Bspline>(), "b352d4f7278a546180de67cbe6793e49");
}

TEST(MessageMd5, CommandMessagesMatchKrMavMsgs) {
  EXPECT_EQ(Md5<quad_msgs::SO3Command>(), "6778903d02fc8f91a4ade288d0a1f3d6");
  EXPECT_EQ(Md5<quad_msgs::TRPYCommand>(), "f80239b313b23c6da7a6269aae03beb6");
  EXPECT_EQ(Md5<quad_msgs::PositionCommand>(), "0311a8eaed8b83c776def91b77632ae6");
  EXPECT_EQ(Md5<quad_msgs::AuxCommand>(), "94f75840e4b1e03675da764692f2c839");
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
