#!/usr/bin/env python3
"""Scripted controller of sim_lockstep_count.test: the lockstep depth consumer `count_controller` that
acknowledges every depth frame except those whose 1-based position in its stream is listed in ~skip_frames
(each of which the simulator then waits out as one acknowledgement timeout), and answers every goal on
/planner/status as the expert planner does ("goal accepted: ...") without flying it."""

import rospy
from geometry_msgs.msg import PoseStamped
from sensor_msgs.msg import Image
from std_msgs.msg import String

from quad_msgs.msg import FrameAck


def main() -> None:
    rospy.init_node("count_controller")
    skip = {int(s) for s in str(rospy.get_param("~skip_frames")).split(",") if s.strip()}
    ack_pub = rospy.Publisher("/sim/frame_ack", FrameAck, queue_size=100, tcp_nodelay=True)
    status_pub = rospy.Publisher("/planner/status", String, queue_size=10, latch=True)
    seen = [0]

    def on_depth(msg: Image) -> None:
        seen[0] += 1
        if seen[0] in skip:
            rospy.loginfo(
                f"count_controller: not acknowledging frame {seen[0]} ({msg.header.stamp.to_sec():.3f})"
            )
            return
        ack_pub.publish(
            FrameAck(consumer="count_controller", frame_seq=msg.header.seq, stamp=msg.header.stamp)
        )

    def on_goal(msg: PoseStamped) -> None:
        p = msg.pose.position
        status_pub.publish(String(f"goal accepted: ({p.x:.3f}, {p.y:.3f}, {p.z:.3f}) (scripted)"))

    rospy.Subscriber("/planner/goal", PoseStamped, on_goal, queue_size=10)
    rospy.Subscriber("/camera/depth/image", Image, on_depth, queue_size=10, tcp_nodelay=True)
    rospy.spin()


if __name__ == "__main__":
    main()
