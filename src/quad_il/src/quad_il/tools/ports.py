"""A free TCP port on localhost, for private ROS masters (tests, evaluation, collection, the manager)."""

from __future__ import annotations

import socket


def free_port() -> int:
    """A port the OS reports free right now (another process may still take it before it is used)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])
