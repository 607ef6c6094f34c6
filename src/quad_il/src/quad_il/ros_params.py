"""Node parameters without silent defaults: a missing parameter is an error that names it and where to set it.

    value = require_param("~odom_period_s", "launch/collect.launch")

Every value comes from the YAML or launch file that starts the node (docs/CONVENTIONS.md); a misspelt or
forgotten key stops the node at start-up instead of running it with a guess. rospy is imported only when no
parameter server is passed, so the helper is tested without ROS.
"""

from __future__ import annotations

from typing import Any, Protocol


class MissingParameterError(KeyError):
    """A required ROS parameter is not set; str() is the whole message."""

    def __str__(self) -> str:
        return str(self.args[0])


class ParamServer(Protocol):
    def has_param(self, name: str) -> bool: ...

    def get_param(self, name: str) -> Any: ...

    def resolve_name(self, name: str) -> str: ...


def require_param(name: str, where: str, params: ParamServer | None = None) -> Any:
    """The value of parameter `name` (private `~x`, relative or global); MissingParameterError naming the
    parameter, its resolved name and `where` (the file that should set it) when it is not set."""
    if params is None:
        import rospy

        params = rospy
    if not params.has_param(name):
        raise MissingParameterError(
            f"missing parameter '{name}' (resolved: {params.resolve_name(name)}; set it in {where})"
        )
    return params.get_param(name)


def wait_for_param(name: str, timeout_s: float) -> bool:
    """True once the ROS master holds the parameter (polled every 0.1 s, wall clock); False after timeout_s.
    For a node that must not start before its launch file has set e.g. /use_sim_time (rospy reads it once)."""
    import time

    import rosgraph

    master = rosgraph.Master("/quad_il_param_probe")
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            if master.hasParam(name):
                return True
        except OSError:  # the master is not up yet
            pass
        time.sleep(0.1)
    return False
