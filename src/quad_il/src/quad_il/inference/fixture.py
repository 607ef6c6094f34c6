"""Recorded decision inputs on disk (the layout of quad_policy/fixture.h), read and written by both languages.

A directory of .npy arrays for N frames of H x W: depth_m (N, H, W) <f4; stamp_s (N,) <f8; p_world_body,
v_world, goal_world (N, 3) <f8; q_world_body (N, 4) <f8 (x, y, z, w); camera_k (4,) <f8 (fx, fy, cx, cy);
T_body_camera (4, 4) <f8. The parity test and the inference benchmark feed the same directory to the C++ and
the Python pipelines."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quad_il.inference.core import CameraModel

FloatArray = NDArray[np.float64]

_FILES = {
    "depth_m": ("<f4", 3),
    "stamp_s": ("<f8", 1),
    "p_world_body": ("<f8", 2),
    "v_world": ("<f8", 2),
    "q_world_body": ("<f8", 2),
    "goal_world": ("<f8", 2),
    "camera_k": ("<f8", 1),
    "T_body_camera": ("<f8", 2),
}


class FixtureError(ValueError):
    """A fixture directory is incomplete or inconsistent; the message names the file."""


@dataclass(frozen=True)
class DecisionFixture:
    depth_m: NDArray[np.float32]
    stamp_s: FloatArray
    p_world_body: FloatArray
    v_world: FloatArray
    q_world_body: FloatArray
    goal_world: FloatArray
    camera_k: FloatArray
    T_body_camera: FloatArray

    def __len__(self) -> int:
        return int(self.depth_m.shape[0])

    def camera(self, i: int) -> CameraModel:
        """Intrinsics and the camera pose T_world_body(frame i) T_body_camera."""
        fx, fy, cx, cy = (float(v) for v in self.camera_k)
        T_world_body = np.eye(4)
        T_world_body[:3, :3] = Rotation.from_quat(self.q_world_body[i]).as_matrix()
        T_world_body[:3, 3] = self.p_world_body[i]
        T = T_world_body @ self.T_body_camera
        h, w = self.depth_m.shape[1:]
        return CameraModel(int(w), int(h), fx, fy, cx, cy, T)

    def validate(self, source: str = "<fixture>") -> None:
        n = len(self)
        expected = {
            "depth_m": (n,),
            "stamp_s": (n,),
            "p_world_body": (n, 3),
            "v_world": (n, 3),
            "q_world_body": (n, 4),
            "goal_world": (n, 3),
            "camera_k": (4,),
            "T_body_camera": (4, 4),
        }
        for name, shape in expected.items():
            got = getattr(self, name).shape
            if got[: len(shape)] != shape or len(got) != _FILES[name][1]:
                tail = " + (H, W)" if name == "depth_m" else ""
                raise FixtureError(f"{source}/{name}.npy: shape {got}, expected {shape}{tail}")


def write_fixture(directory: str | Path, fx: DecisionFixture) -> Path:
    d = Path(directory)
    fx.validate(str(d))
    d.mkdir(parents=True, exist_ok=True)
    for name, (dtype, _) in _FILES.items():
        np.save(d / f"{name}.npy", np.ascontiguousarray(getattr(fx, name), dtype=dtype))
    return d


def read_fixture(directory: str | Path) -> DecisionFixture:
    d = Path(directory)
    arrays = {}
    for name, (dtype, _) in _FILES.items():
        path = d / f"{name}.npy"
        if not path.is_file():
            raise FixtureError(f"{path}: missing")
        a = np.load(path, allow_pickle=False)
        if a.dtype != np.dtype(dtype):
            raise FixtureError(f"{path}: dtype {a.dtype}, expected {np.dtype(dtype)}")
        arrays[name] = a
    fx = DecisionFixture(**arrays)
    fx.validate(str(d))
    return fx
