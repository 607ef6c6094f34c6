"""Shared by the rostest nodes that drive both policy nodes side by side with hand-published inputs
(infer_node_parity_check.py, policy_bad_input_check.py): the camera mount and the two nodes' launch."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Any

import rospy
import tf2_ros
from geometry_msgs.msg import TransformStamped

# One namespace per node: the C++ (LibTorch) node and the Python node.
NAMESPACES = ("cpp", "py")
NODES = {"cpp": ("quad_policy", "policy_node"), "py": ("quad_il", "policy_node.py")}


def broadcast_camera_mount() -> tf2_ros.StaticTransformBroadcaster:
    """base_link -> camera as the simulator mounts it: 0.1 m ahead, optical frame looking along +x. Keep the
    returned broadcaster alive as long as the nodes need the transform."""
    tf = tf2_ros.StaticTransformBroadcaster()
    t = TransformStamped()
    t.header.frame_id, t.child_frame_id = "base_link", "camera"
    t.transform.translation.x = 0.1
    t.transform.rotation.x, t.transform.rotation.y = -0.5, 0.5
    t.transform.rotation.z, t.transform.rotation.w = -0.5, 0.5
    tf.sendTransform(t)
    return tf


@contextlib.contextmanager
def policy_nodes(params: dict[str, Any]) -> Iterator[list]:
    """Both policy nodes, /<ns>/policy_node with the private parameters `params`, stopped on exit. Yields
    the processes (check `is_alive()` before leaving)."""
    import roslaunch

    launch = roslaunch.scriptapi.ROSLaunch()
    launch.start()
    procs = []
    try:
        for ns in NAMESPACES:
            for key, value in params.items():
                rospy.set_param(f"/{ns}/policy_node/{key}", value)
            pkg, node_type = NODES[ns]
            procs.append(
                launch.launch(
                    roslaunch.core.Node(pkg, node_type, name="policy_node", namespace=ns, output="log")
                )
            )
        yield procs
    finally:
        for p in procs:
            p.stop()
        launch.stop()
