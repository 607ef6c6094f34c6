// Publishes one fixed Bspline on ~bspline (latched, and again at 10 Hz) so that a rospy test can check the
// C++ -> Python wire round trip field by field. The content is a pure function of the index i.
#include <geometry_msgs/Point.h>
#include <quad_msgs/Bspline.h>
#include <ros/ros.h>

namespace {
quad_msgs::Bspline MakeKnownBspline() {
  quad_msgs::Bspline msg;
  msg.order = 3;
  msg.traj_id = 4242424242LL;  // does not fit in 32 bits: checks int64 on the wire
  msg.start_time = ros::Time(12, 345000000);
  const int num_ctrl = 7;
  for (int i = 0; i < num_ctrl + msg.order + 1; ++i) {
    msg.knots.push_back(0.25 * i);
  }
  for (int i = 0; i < num_ctrl; ++i) {
    geometry_msgs::Point p;
    p.x = 0.5 * i;
    p.y = -0.125 * i * i;
    p.z = 1.0 + 1e-9 * i;
    msg.pos_pts.push_back(p);
    msg.yaw_pts.push_back(0.1 * i);
  }
  msg.yaw_dt = 0.3;
  return msg;
}
}  // namespace

int main(int argc, char** argv) {
  ros::init(argc, argv, "bspline_test_publisher");
  ros::NodeHandle pnh("~");
  ros::Publisher pub = pnh.advertise<quad_msgs::Bspline>("bspline", 1, /*latch=*/true);
  const quad_msgs::Bspline msg = MakeKnownBspline();
  ros::Rate rate(10.0);
  while (ros::ok()) {
    pub.publish(msg);
    ros::spinOnce();
    rate.sleep();
  }
  return 0;
}
