"""Message conversion of the interactive collector, without importing rospy (messages are duck-typed, so the
conversions are tested with plain objects): quad_msgs/Bspline -> SplineAction, sensor_msgs/Image 32FC1 ->
depth array, (depth frame, odometry, goal) -> Observation, and back to the B-spline message's fields."""

from __future__ import annotations

from typing import Any

import numpy as np

from quad_il.imitation.bspline import SplineAction
from quad_il.imitation.types import ImitationError, Observation


def spline_from_msg(msg: Any) -> SplineAction | None:
    """A quad_msgs/Bspline -> SplineAction; None for an empty message (a source saying "no plan for this
    frame"); ValueError for a malformed one."""
    if len(msg.pos_pts) == 0:
        return None
    ctrl = np.array([[p.x, p.y, p.z] for p in msg.pos_pts], dtype=np.float64).reshape(-1, 3)
    return SplineAction(
        ctrl,
        np.asarray(msg.knots, dtype=np.float64),
        int(msg.order),
        msg.start_time.to_sec(),
        int(msg.traj_id),
    )


def depth_from_msg(msg: Any) -> np.ndarray:
    if msg.encoding != "32FC1":
        raise ImitationError(f"depth image encoding must be 32FC1, got {msg.encoding!r}")
    row = np.frombuffer(bytes(msg.data), dtype=np.float32 if not msg.is_bigendian else ">f4")
    return row.reshape(msg.height, msg.step // 4)[:, : msg.width].astype(np.float32)


def observation_from_msgs(depth: Any, odom: Any, episode_id: int, goal_world: np.ndarray) -> Observation:
    """The observation of a depth frame with the odometry paired to it (ImitationError when malformed)."""
    pose, twist = odom.pose.pose, odom.twist.twist
    return Observation(
        stamp_s=depth.header.stamp.to_sec(),
        frame_seq=depth.header.seq,
        episode_id=episode_id,
        p_world_body=[pose.position.x, pose.position.y, pose.position.z],
        v_world=[twist.linear.x, twist.linear.y, twist.linear.z],
        q_world_body=[pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w],
        goal_world=goal_world,
        depth_m=depth_from_msg(depth),
        odom_stamp_s=odom.header.stamp.to_sec(),
    )
