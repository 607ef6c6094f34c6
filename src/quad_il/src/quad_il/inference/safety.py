"""The safety layer between the network and the tracker (issue 8), the Python twin of quad_policy/safety.h.

A proposed trajectory is refused, first failure wins, when: a control point is NaN/Inf (always checked); a
velocity control point V_i = (c_{i+1} - c_i) / dt is faster than `max_vel_mps`; an acceleration control point
(V_{i+1} - V_i) / dt exceeds `max_acc_mps2` (convex-hull bounds of the spline's speed and acceleration); the
trajectory starts more than `max_start_error_m` from the vehicle; or a sample (every `sample_dt_s` up to the
check horizon, and its end) enters space the latest depth frame shows occupied: the sphere of radius
`vehicle_radius_m` around the sample reaches, along some pixel's ray, beyond the depth measured there (d =
+inf and NaN are free, -inf counts as 0). Samples whose sphere holds the camera centre (the vehicle's own
place) and samples that no ray of the image meets are not judged. docs/inference.md."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np
from numpy.typing import NDArray

from quad_il.inference.config import SafetyConfig
from quad_il.inference.trajectory import UniformBspline

FloatArray = NDArray[np.float64]


class SafetyVerdict(IntEnum):
    ACCEPTED = 0
    NON_FINITE_OUTPUT = 1
    VELOCITY_LIMIT = 2
    ACCELERATION_LIMIT = 3
    START_FAR_FROM_VEHICLE = 4
    COLLISION_IN_DEPTH = 5

    @property
    def label(self) -> str:
        """The published and counted name ("accepted", "velocity_limit", ...), as the C++ ToString."""
        return self.name.lower()


@dataclass(frozen=True)
class CameraModel:
    """Pinhole camera of a depth frame (CameraInfo K, pixel centres at integer coordinates) and its pose."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    T_world_camera: FloatArray  # (4, 4), camera optical frame (z forward) in the world


@dataclass(frozen=True)
class SafetyResult:
    verdict: SafetyVerdict
    reason: str
    value: float = (
        0.0  # the offending quantity (speed, acceleration, distance, or the colliding sample's time)
    )

    @property
    def accepted(self) -> bool:
        return self.verdict == SafetyVerdict.ACCEPTED


@dataclass(frozen=True)
class DepthCollision:
    collides: bool
    sample_index: int = -1
    occupied_pixels: int = 0
    u: int = -1
    v: int = -1
    measured_depth_m: float = 0.0
    sphere_depth_m: float = 0.0


def _axis_range(a: float, z: float, r: float, f: float, c0: float, n: int) -> tuple[int, int] | None:
    """Pixels [lo, hi] of one image axis whose rays (a = z tan(angle), z > 0) can meet the sphere: between the
    tangents of its projection (a disc) on the (a, z) plane, widened by one pixel; None if no ray meets it."""
    rho2 = a * a + z * z
    if rho2 <= r * r:
        return 0, n - 1
    half_pi = 0.5 * math.pi
    theta = math.atan2(a, z)
    alpha = math.asin(r / math.sqrt(rho2))
    a0, a1 = theta - alpha, theta + alpha
    if a1 <= -half_pi or a0 >= half_pi:
        return None
    lo_f = -1.0 if a0 <= -half_pi else math.floor(c0 + f * math.tan(a0)) - 1.0
    hi_f = float(n) if a1 >= half_pi else math.ceil(c0 + f * math.tan(a1)) + 1.0
    lo, hi = int(max(0.0, lo_f)), int(min(float(n - 1), hi_f))
    return (lo, hi) if lo <= hi else None


def find_depth_collision(
    samples_world: FloatArray,
    radius_m: float,
    min_pixels: int,
    depth_m: NDArray[np.float32],
    camera: CameraModel,
) -> DepthCollision:
    """The first sample (index into samples_world, (S, 3)) with at least min_pixels occupied pixels."""
    depth = np.asarray(depth_m)
    if depth.shape != (camera.height, camera.width):
        raise ValueError(
            f"depth image {depth.shape} and camera model ({camera.height}, {camera.width}) differ"
        )
    if not (camera.fx > 0.0 and camera.fy > 0.0):
        raise ValueError("camera focal lengths must be > 0")
    T = np.asarray(camera.T_world_camera, dtype=np.float64)
    R, t = T[:3, :3], T[:3, 3]
    cams = (np.asarray(samples_world, dtype=np.float64) - t) @ R  # rows: R^T (p - t)
    dx = (np.arange(camera.width, dtype=np.float64) - camera.cx) / camera.fx
    dy = (np.arange(camera.height, dtype=np.float64) - camera.cy) / camera.fy
    r2 = radius_m * radius_m
    for j, c in enumerate(cams):
        cx, cy, cz = float(c[0]), float(c[1]), float(c[2])
        c2 = cx * cx + cy * cy + cz * cz
        if c2 <= r2:
            continue  # the sphere holds the camera: the vehicle's own place, not judged
        ur = _axis_range(cx, cz, radius_m, camera.fx, camera.cx, camera.width)
        vr = _axis_range(cy, cz, radius_m, camera.fy, camera.cy, camera.height)
        if ur is None or vr is None:
            continue
        (u0, u1), (v0, v1) = ur, vr
        d = depth[v0 : v1 + 1, u0 : u1 + 1].astype(np.float64)
        ddx = dx[u0 : u1 + 1][None, :]
        ddy = dy[v0 : v1 + 1][:, None]
        aa = ddx * ddx + ddy * ddy + 1.0
        bb = ddx * cx + ddy * cy + cz
        disc = bb * bb - aa * (c2 - r2)
        hit = disc >= 0.0
        t_far = (bb + np.sqrt(np.where(hit, disc, 0.0))) / aa
        known = ~np.isnan(d) & (d != np.inf)
        d_eff = np.where(d < 0.0, 0.0, d)  # -inf: nearer than the camera's minimum range
        occupied = hit & known & (t_far > np.where(known, d_eff, 0.0))
        count = int(np.count_nonzero(occupied))
        if count >= min_pixels:
            first = int(np.argmax(occupied))  # row-major, as the C++ loops
            fv, fu = divmod(first, occupied.shape[1])
            return DepthCollision(
                True, j, count, u0 + fu, v0 + fv, float(d_eff[fv, fu]), float(t_far[fv, fu])
            )
    return DepthCollision(False)


def nearest_depth(depth_m: NDArray[np.float32]) -> float:
    """The smallest depth (along the optical axis, m) among the pixels that show a surface: -inf (nearer than
    the camera's minimum range) counts as 0, NaN and +inf show none; +inf when no pixel shows one (C++
    NearestDepth)."""
    d = np.asarray(depth_m, dtype=np.float64)
    d = d[~np.isnan(d)]
    return float(max(np.min(d), 0.0)) if d.size else math.inf


def safety_sample_times(traj: UniformBspline, cfg: SafetyConfig) -> FloatArray:
    duration = traj.duration_s
    horizon = min(cfg.check_horizon_s, duration) if cfg.check_horizon_s > 0.0 else duration
    n = math.floor(horizon / cfg.sample_dt_s + 1e-9)
    times = [j * cfg.sample_dt_s for j in range(n + 1)]
    if times[-1] < horizon - 1e-9:
        times.append(horizon)
    return np.asarray(times, dtype=np.float64)


def trajectory_in_view(traj: UniformBspline, camera: CameraModel, cfg: SafetyConfig) -> bool:
    """Whether every sample up to the check horizon whose sphere does not hold the camera centre has its
    centre in front of the camera and projecting inside the image (the recovery's plans must pass this
    besides check_trajectory: a plan turned away from the goal may leave the view, where depth cannot judge
    it)."""
    T = np.asarray(camera.T_world_camera, dtype=np.float64)
    cams = (traj.position(safety_sample_times(traj, cfg)) - T[:3, 3]) @ T[:3, :3]
    r2 = cfg.vehicle_radius_m * cfg.vehicle_radius_m
    for cx, cy, cz in cams:
        if cx * cx + cy * cy + cz * cz <= r2:
            continue  # the vehicle's own place, as in find_depth_collision
        if not cz > 0.0:
            return False
        u = camera.cx + camera.fx * cx / cz
        v = camera.cy + camera.fy * cy / cz
        if not (0.0 <= u <= camera.width - 1.0 and 0.0 <= v <= camera.height - 1.0):
            return False
    return True


def check_trajectory(
    traj: UniformBspline,
    p_world_vehicle: FloatArray,
    depth_m: NDArray[np.float32] | None,
    camera: CameraModel | None,
    cfg: SafetyConfig,
) -> SafetyResult:
    """All checks in order; the first failure is the verdict (depth None: no collision check)."""
    ctrl = traj.ctrl_world
    bad = ~np.all(np.isfinite(ctrl), axis=1)
    if np.any(bad):
        i = int(np.argmax(bad))
        return SafetyResult(
            SafetyVerdict.NON_FINITE_OUTPUT,
            f"non_finite_output: control point {i} of {ctrl.shape[0]} is NaN/Inf",
            float(i),
        )
    if not (math.isfinite(traj.knot_dt_s) and traj.knot_dt_s > 0.0 and math.isfinite(traj.start_time_s)):
        return SafetyResult(
            SafetyVerdict.NON_FINITE_OUTPUT,
            "non_finite_output: knot interval or start time not finite and positive",
        )
    if not cfg.enabled:
        return SafetyResult(SafetyVerdict.ACCEPTED, "accepted (safety checks disabled)")
    speeds = np.linalg.norm(traj.velocity_ctrl_pts(), axis=1)
    i = int(np.argmax(speeds))
    if speeds[i] > cfg.max_vel_mps:
        return SafetyResult(
            SafetyVerdict.VELOCITY_LIMIT,
            f"velocity_limit: control-point speed {speeds[i]:.3f} m/s > {cfg.max_vel_mps:.3f} m/s "
            f"(velocity control point {i})",
            float(speeds[i]),
        )
    accs = np.linalg.norm(traj.acceleration_ctrl_pts(), axis=1)
    i = int(np.argmax(accs))
    if accs[i] > cfg.max_acc_mps2:
        return SafetyResult(
            SafetyVerdict.ACCELERATION_LIMIT,
            f"acceleration_limit: control-point acceleration {accs[i]:.3f} m/s^2 > "
            f"{cfg.max_acc_mps2:.3f} m/s^2 (acceleration control point {i})",
            float(accs[i]),
        )
    start_error = float(np.linalg.norm(traj.position(0.0)[0] - np.asarray(p_world_vehicle, dtype=np.float64)))
    if not start_error <= cfg.max_start_error_m:
        return SafetyResult(
            SafetyVerdict.START_FAR_FROM_VEHICLE,
            f"start_far_from_vehicle: the trajectory starts {start_error:.3f} m from the vehicle "
            f"(limit {cfg.max_start_error_m:.3f} m)",
            start_error,
        )
    if depth_m is not None:
        if camera is None:
            raise ValueError("a depth image needs its camera model")
        times = safety_sample_times(traj, cfg)
        hit = find_depth_collision(
            traj.position(times), cfg.vehicle_radius_m, cfg.collision_min_pixels, depth_m, camera
        )
        if hit.collides:
            t = float(times[hit.sample_index])
            return SafetyResult(
                SafetyVerdict.COLLISION_IN_DEPTH,
                f"collision_in_depth: at t = {t:.3f} s the vehicle sphere (r = {cfg.vehicle_radius_m:.2f} m) "
                f"reaches {hit.sphere_depth_m:.3f} m deep along pixel ({hit.u}, {hit.v}) whose measured "
                f"depth is {hit.measured_depth_m:.3f} m ({hit.occupied_pixels} occupied pixels)",
                t,
            )
    return SafetyResult(SafetyVerdict.ACCEPTED, "accepted")


@dataclass
class VerdictCounts:
    counts: dict[SafetyVerdict, int] = field(default_factory=lambda: {v: 0 for v in SafetyVerdict})

    def add(self, verdict: SafetyVerdict) -> None:
        self.counts[verdict] += 1

    @property
    def refused(self) -> int:
        return sum(n for v, n in self.counts.items() if v != SafetyVerdict.ACCEPTED)
