"""Message conversion of the Python policy node, in one place (ROS message classes: imported by the node and
the benchmark only). The C++ node's is quad_policy/src/ros/messages.h."""

from __future__ import annotations

import numpy as np
import rospy
from geometry_msgs.msg import Point
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import Image
from visualization_msgs.msg import Marker

from quad_il.inference.core import UniformBspline, depth_layout_problem
from quad_msgs.msg import Bspline


def bspline_message(traj: UniformBspline, traj_id: int, start_time: rospy.Time | None = None) -> Bspline:
    """Order 3, knots (i - 3) dt, start_time = the depth frame's stamp, no yaw points (the tracker yaws along
    the direction of travel), as the C++ ToBsplineMessage. `start_time`: the depth frame's exact stamp (a
    float round trip through rospy.Time.from_sec truncates to the nanosecond below)."""
    msg = Bspline()
    msg.order = 3
    msg.traj_id = int(traj_id)
    msg.start_time = start_time if start_time is not None else rospy.Time.from_sec(traj.start_time_s)
    msg.knots = list(traj.knots())
    msg.pos_pts = [Point(float(x), float(y), float(z)) for x, y, z in traj.ctrl_world]
    msg.yaw_pts = []
    msg.yaw_dt = 0.0
    return msg


def depth_from_image(msg: Image) -> tuple[np.ndarray | None, str]:
    """32FC1 little-endian image -> ((H, W) float32 view, ""); any other layout: (None, the reason)."""
    problem = depth_layout_problem(
        msg.encoding, bool(msg.is_bigendian), msg.width, msg.height, msg.step, len(msg.data)
    )
    if problem:
        return None, problem
    flat = np.frombuffer(msg.data, dtype="<f4", count=(msg.step // 4) * msg.height)
    return flat.reshape(msg.height, msg.step // 4)[:, : msg.width], ""


def pose(p: np.ndarray, q_xyzw: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(q_xyzw).as_matrix()
    T[:3, 3] = p
    return T


def plan_marker(traj, header, ns: str) -> Marker:
    """The trajectory sent, as a line strip sampled every 0.05 s (rviz: config/rviz/sim.rviz)."""
    m = Marker(header=header, ns=ns, id=0, type=Marker.LINE_STRIP, action=Marker.ADD)
    m.header.frame_id = "world"
    m.pose.orientation.w = 1.0
    m.scale.x = 0.05
    m.color.r, m.color.g, m.color.b, m.color.a = 1.0, 0.5, 0.0, 1.0
    times = np.append(np.arange(0.0, traj.duration_s, 0.05), traj.duration_s)
    m.points = [Point(*map(float, p)) for p in traj.position(times)]
    return m
