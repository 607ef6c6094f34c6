"""Trajectory -> quad_msgs/Bspline (ROS message classes; imported by the node and the benchmark only)."""

from __future__ import annotations

import rospy
from geometry_msgs.msg import Point

from quad_il.inference.trajectory import UniformBspline
from quad_msgs.msg import Bspline


def bspline_message(traj: UniformBspline, traj_id: int, start_time: rospy.Time | None = None) -> Bspline:
    """Order 3, knots (i - 3) dt, start_time = the depth frame's stamp; yaw points only when the trajectory
    has a heading (else the tracker yaws along the direction of travel), as the C++ ToBsplineMessage.
    `start_time`: the depth frame's exact stamp (a float round trip through rospy.Time.from_sec truncates to
    the nanosecond below)."""
    msg = Bspline()
    msg.order = 3
    msg.traj_id = int(traj_id)
    msg.start_time = start_time if start_time is not None else rospy.Time.from_sec(traj.start_time_s)
    msg.knots = traj.knots().tolist()
    msg.pos_pts = [Point(float(x), float(y), float(z)) for x, y, z in traj.ctrl_world]
    if traj.yaw_ctrl is None:
        msg.yaw_pts = []
        msg.yaw_dt = 0.0
    else:
        msg.yaw_pts = [float(y) for y in traj.yaw_ctrl]
        msg.yaw_dt = float(traj.knot_dt_s)
    return msg
