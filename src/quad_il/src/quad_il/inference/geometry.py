"""Small pose helpers shared by the inference modules (quaternions are x, y, z, w: docs/CONVENTIONS.md)."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


def rotation_matrix(q_xyzw: FloatArray) -> FloatArray:
    """3 x 3 rotation of a (not necessarily unit, non-zero) quaternion (x, y, z, w)."""
    x, y, z, w = np.asarray(q_xyzw, dtype=np.float64) / np.linalg.norm(q_xyzw)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def pose_matrix(p: FloatArray, q_xyzw: FloatArray) -> FloatArray:
    """4 x 4 homogeneous transform of a position and a rotation (x, y, z, w)."""
    T = np.eye(4)
    T[:3, :3] = rotation_matrix(q_xyzw)
    T[:3, 3] = np.asarray(p, dtype=np.float64)
    return T


def yaw_of(q_xyzw: FloatArray) -> float:
    """Heading (rad) of the body x axis: atan2 of rotation_matrix's (1, 0) and (0, 0) entries, as the C++
    decider computes it from Eigen's rotation matrix."""
    r = rotation_matrix(q_xyzw)
    return math.atan2(float(r[1, 0]), float(r[0, 0]))
