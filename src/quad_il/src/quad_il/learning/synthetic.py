"""Small synthetic demonstration datasets in the collector's `.npz` layout, for tests and the training
benchmark.

Not a simulator: each sample is a vehicle flying towards its goal with one box-shaped obstacle in view; the
"expert" B-spline heads towards the goal and swerves away from the obstacle's side of the image, climbing a
little when the obstacle is near. The label therefore depends on both the depth image and the state, so a
policy can learn it, which is all the tests and the benchmark need. Every number is seeded.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from quad_il.learning.dataset import SUPPORTED_FORMAT_VERSIONS


def _yaw_quaternion(yaw: np.ndarray, roll: np.ndarray, pitch: np.ndarray) -> np.ndarray:
    """xyzw quaternion of R_z(yaw) R_y(pitch) R_x(roll)."""
    cy, sy = np.cos(yaw / 2), np.sin(yaw / 2)
    cp, sp = np.cos(pitch / 2), np.sin(pitch / 2)
    cr, sr = np.cos(roll / 2), np.sin(roll / 2)
    w = cr * cp * cy + sr * sp * sy
    x = sr * cp * cy - cr * sp * sy
    y = cr * sp * cy + sr * cp * sy
    z = cr * cp * sy - sr * sp * cy
    return np.stack([x, y, z, w], axis=1)


def make_synthetic_arrays(
    num_episodes: int = 4,
    samples_per_episode: int = 8,
    height: int = 48,
    width: int = 64,
    num_ctrl_pts: int = 10,
    horizon_s: float = 2.0,
    seed: int = 0,
    first_world_seed: int = 1000,
    format_version: int = SUPPORTED_FORMAT_VERSIONS[-1],
) -> dict[str, Any]:
    """Arrays of a dataset with `num_episodes` episodes (world seeds first_world_seed, +1, ...)."""
    rng = np.random.default_rng(seed)
    n = num_episodes * samples_per_episode
    episode_id = np.repeat(np.arange(num_episodes, dtype=np.int64), samples_per_episode)
    world_seed = (first_world_seed + episode_id).astype(np.uint64)
    step = np.tile(np.arange(samples_per_episode), num_episodes)
    sim_time_s = step * 0.5 + rng.uniform(0, 0.01, n)
    # State: along a straight course towards the goal, heading roughly at the goal.
    start = rng.uniform(-5, 5, (num_episodes, 3)) * np.array([1, 1, 0]) + np.array([0, 0, 1.5])
    heading = rng.uniform(-np.pi, np.pi, num_episodes)
    goal = start + 25.0 * np.stack([np.cos(heading), np.sin(heading), np.zeros(num_episodes)], 1)
    speed = rng.uniform(1.0, 2.5, n)
    yaw = np.repeat(heading, samples_per_episode) + rng.normal(0, 0.15, n)
    fwd = np.stack([np.cos(yaw), np.sin(yaw), np.zeros(n)], 1)
    p = np.repeat(start, samples_per_episode, 0) + (step * 0.5 * 2.0)[:, None] * np.stack(
        [
            np.cos(np.repeat(heading, samples_per_episode)),
            np.sin(np.repeat(heading, samples_per_episode)),
            0 * yaw,
        ],
        1,
    )
    p[:, 2] += rng.normal(0, 0.2, n)
    v = speed[:, None] * fwd + rng.normal(0, 0.1, (n, 3))
    q = _yaw_quaternion(yaw, rng.normal(0, 0.05, n), rng.normal(0, 0.05, n))
    w_body = rng.normal(0, 0.1, (n, 3))
    # Depth: floor gradient in the lower half, far/no-return elsewhere, one box obstacle.
    rows = np.arange(height)[:, None]
    floor = np.where(rows > height // 2, 1.5 * height / np.maximum(rows - height // 2, 1), np.inf)
    depth = np.broadcast_to(floor, (n, height, width)).astype(np.float32).copy()
    depth[:, : height // 2, :] = np.where(rng.random((n, 1, 1)) < 0.5, np.inf, 20.0)
    obs_col = rng.uniform(0.15, 0.85, n)  # obstacle centre as a fraction of the width
    obs_dist = rng.uniform(1.5, 8.0, n)
    half_w = np.maximum(2, (width * 0.6 / obs_dist).astype(int))
    half_h = np.maximum(2, (height * 0.8 / obs_dist).astype(int))
    for i in range(n):
        c = int(obs_col[i] * width)
        r = height // 2
        depth[i, max(0, r - half_h[i]) : r + half_h[i], max(0, c - half_w[i]) : c + half_w[i]] = obs_dist[i]
    depth += rng.normal(0, 0.01, depth.shape).astype(np.float32)
    # Expert: forward at the current speed, lateral swerve away from the obstacle's side, climb when close.
    t = np.linspace(0.0, horizon_s, num_ctrl_pts)
    side = np.sign(
        obs_col - 0.5
    )  # obstacle right of centre in the image (camera x right) -> swerve left (+y)
    swerve = side * np.clip(3.0 / obs_dist, 0, 1.5)
    bump = np.sin(np.pi * t / horizon_s / 1.2)
    ctrl_local = np.zeros((n, num_ctrl_pts, 3))
    ctrl_local[:, :, 0] = speed[:, None] * t[None, :]
    ctrl_local[:, :, 1] = swerve[:, None] * bump[None, :]
    ctrl_local[:, :, 2] = (obs_dist < 3.0)[:, None] * 0.3 * (t / horizon_s)[None, :]
    # The label frame is the yaw-only frame of the recorded attitude (yaw from q).
    yaw_q = np.arctan2(2 * (q[:, 3] * q[:, 2] + q[:, 0] * q[:, 1]), 1 - 2 * (q[:, 1] ** 2 + q[:, 2] ** 2))
    c, s = np.cos(yaw_q)[:, None], np.sin(yaw_q)[:, None]
    ctrl_world = np.stack(
        [
            c * ctrl_local[..., 0] - s * ctrl_local[..., 1] + p[:, None, 0],
            s * ctrl_local[..., 0] + c * ctrl_local[..., 1] + p[:, None, 1],
            ctrl_local[..., 2] + p[:, None, 2],
        ],
        axis=-1,
    ).astype(np.float32)
    # Recompute the local points from the float32 world points, as a collector would.
    d = ctrl_world.astype(np.float64) - p.astype(np.float32).astype(np.float64)[:, None, :]
    ctrl_local = np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1], d[..., 2]], axis=-1)
    return {
        "depth_m": depth.astype(np.float16),
        "episode_id": episode_id,
        "world_seed": world_seed,
        "sim_time_s": sim_time_s.astype(np.float64),
        "depth_stamp_s": sim_time_s.astype(np.float64),
        "odom_stamp_s": (sim_time_s - 0.002).astype(np.float64),
        "p_world_body": p.astype(np.float32),
        "v_world": v.astype(np.float32),
        "q_world_body": q.astype(np.float32),
        "w_body": w_body.astype(np.float32),
        "goal_world": np.repeat(goal, samples_per_episode, 0).astype(np.float32),
        "bspline_ctrl_world": ctrl_world,
        "bspline_ctrl_local": ctrl_local.astype(np.float32),
        "num_ctrl_pts": np.int64(num_ctrl_pts),
        "horizon_s": np.float64(horizon_s),
        "format_version": np.int64(format_version),
    }


def write_synthetic_npz(path: str | Path, **kwargs: Any) -> Path:
    """Write `make_synthetic_arrays(**kwargs)` as an uncompressed `.npz` (as the postprocessing does)."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    np.savez(p, **make_synthetic_arrays(**kwargs))
    return p
