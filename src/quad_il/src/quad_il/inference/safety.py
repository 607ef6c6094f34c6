"""The safety layer between the network and the tracker (issue 8), the Python twin of quad_policy/safety.h.

A proposed trajectory is refused, first failure wins, when: a control point is NaN/Inf (always checked); a
velocity control point V_i = (c_{i+1} - c_i) / dt is faster than `max_vel_mps`; an acceleration control point
(V_{i+1} - V_i) / dt exceeds `max_acc_mps2` (convex-hull bounds of the spline's speed and acceleration); the
trajectory starts more than `max_start_error_m` from the vehicle; or a sample (every `sample_dt_s` up to the
check horizon, and its end) enters space the latest depth frame shows occupied: the sphere of radius
`vehicle_radius_m` around the sample reaches, along some pixel's ray, beyond the depth measured there (d =
+inf and NaN are free, -inf counts as 0). Samples whose sphere holds the camera centre (the vehicle's own
place) and samples that no ray of the image meets are not judged.

With a depth memory (`memory_frames` > 0), a sample whose centre the latest frame does not show (beside or
behind the camera) is judged instead by the newest remembered earlier frame that shows it: the world is
static, so a box seen while approaching still stands there when the vehicle has turned past it.
docs/inference.md."""

from __future__ import annotations

import math
from collections.abc import Sequence
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
class DepthFrame:
    """An earlier depth frame the safety layer remembers (its stamp, image and camera pose at the frame)."""

    stamp_s: float
    depth_m: NDArray[np.float32]  # (height, width) of the camera model
    camera: CameraModel


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
    # The frame that judged the sample: 0 the latest, k >= 1 the k-th remembered (newest first).
    frame: int = 0
    frame_stamp_s: float = math.nan  # that remembered frame's stamp (NaN for the latest)


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


def _check_frame(depth_m: NDArray[np.float32], camera: CameraModel, what: str) -> NDArray[np.float32]:
    depth = np.asarray(depth_m)
    if depth.shape != (camera.height, camera.width):
        raise ValueError(
            f"{what}: depth image {depth.shape} and camera model ({camera.height}, {camera.width}) differ"
        )
    if not (camera.fx > 0.0 and camera.fy > 0.0):
        raise ValueError(f"{what}: camera focal lengths must be > 0")
    return depth


def _to_camera(camera: CameraModel, points_world: FloatArray) -> FloatArray:
    T = np.asarray(camera.T_world_camera, dtype=np.float64)
    return (np.asarray(points_world, dtype=np.float64) - T[:3, 3]) @ T[:3, :3]  # rows: R^T (p - t)


def _centre_in_view(c: FloatArray, camera: CameraModel) -> bool:
    """Whether a point (camera frame) is in front of the camera and projects inside the image."""
    cx, cy, cz = float(c[0]), float(c[1]), float(c[2])
    if not cz > 0.0:
        return False
    u = camera.cx + camera.fx * cx / cz
    v = camera.cy + camera.fy * cy / cz
    return 0.0 <= u <= camera.width - 1.0 and 0.0 <= v <= camera.height - 1.0


def _showing_frame(j: int, cams: list[FloatArray], cameras: list[CameraModel]) -> int | None:
    """The first frame whose view holds sample j's centre: the latest (0), else the newest remembered; None:
    no frame shows it. cams[k]: the samples in frame k's camera frame."""
    for k, cam in enumerate(cameras):
        if _centre_in_view(cams[k][j], cam):
            return k
    return None


def find_depth_collision(
    samples_world: FloatArray,
    radius_m: float,
    min_pixels: int,
    depth_m: NDArray[np.float32],
    camera: CameraModel,
    memory: Sequence[DepthFrame] = (),
) -> DepthCollision:
    """The first sample (index into samples_world, (S, 3)) with at least min_pixels occupied pixels in the
    frame that judges it (the latest, or with a memory (newest first) the newest frame showing it)."""
    depths = [_check_frame(depth_m, camera, "latest frame")]
    depths += [_check_frame(f.depth_m, f.camera, f"remembered frame {k + 1}") for k, f in enumerate(memory)]
    cameras = [camera] + [f.camera for f in memory]
    cams = [_to_camera(c, samples_world) for c in cameras]
    axes: dict[int, tuple[FloatArray, FloatArray]] = {}
    r2 = radius_m * radius_m
    for j in range(len(cams[0])):
        if float(cams[0][j] @ cams[0][j]) <= r2:
            continue  # the sphere holds the (latest) camera: the vehicle's own place, not judged
        # The judging frame: the first that shows the sample's centre, else the latest (which judges the part
        # of the sphere it sees).
        k = (_showing_frame(j, cams, cameras) or 0) if memory else 0
        cam, depth, c = cameras[k], depths[k], cams[k][j]
        if k not in axes:
            axes[k] = (
                (np.arange(cam.width, dtype=np.float64) - cam.cx) / cam.fx,
                (np.arange(cam.height, dtype=np.float64) - cam.cy) / cam.fy,
            )
        dx, dy = axes[k]
        cx, cy, cz = float(c[0]), float(c[1]), float(c[2])
        c2 = cx * cx + cy * cy + cz * cz
        if c2 <= r2:
            continue  # the sphere holds that frame's camera: where the vehicle was, free
        ur = _axis_range(cx, cz, radius_m, cam.fx, cam.cx, cam.width)
        vr = _axis_range(cy, cz, radius_m, cam.fy, cam.cy, cam.height)
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
                True,
                j,
                count,
                u0 + fu,
                v0 + fv,
                float(d_eff[fv, fu]),
                float(t_far[fv, fu]),
                k,
                float(memory[k - 1].stamp_s) if k > 0 else math.nan,
            )
    return DepthCollision(False)


def nearest_depth(depth_m: NDArray[np.float32]) -> float:
    """The smallest depth (along the optical axis, m) among the pixels that show a surface: -inf (nearer than
    the camera's minimum range) counts as 0, NaN and +inf show none; +inf when no pixel shows one (C++
    NearestDepth)."""
    d = np.asarray(depth_m, dtype=np.float64)
    d = d[~np.isnan(d)]
    return float(max(np.min(d), 0.0)) if d.size else math.inf


def safety_sample_times(traj: UniformBspline, cfg: SafetyConfig, from_s: float = 0.0) -> FloatArray:
    """Trajectory times from_s + j * sample_dt_s (j = 0, 1, ...) up to the check horizon after from_s (or the
    trajectory's end), and that last time itself (C++ SafetySampleTimes). from_s > 0 judges the rest of a
    trajectory from that time on (PolicyDecider's kept plan)."""
    duration = traj.duration_s - from_s
    horizon = min(cfg.check_horizon_s, duration) if cfg.check_horizon_s > 0.0 else duration
    n = math.floor(horizon / cfg.sample_dt_s + 1e-9)
    times = [from_s + j * cfg.sample_dt_s for j in range(n + 1)]
    if times[-1] < from_s + horizon - 1e-9:
        times.append(from_s + horizon)
    return np.asarray(times, dtype=np.float64)


def trajectory_in_view(
    traj: UniformBspline,
    camera: CameraModel,
    cfg: SafetyConfig,
    memory: Sequence[DepthFrame] = (),
    from_s: float = 0.0,
) -> bool:
    """Whether every sample up to the check horizon whose sphere does not hold the camera centre has its
    centre in front of the camera and projecting inside the image (the recovery's plans must pass this
    besides check_trajectory: a plan turned away from the goal may leave the view, where depth cannot judge
    it). With a memory, a sample shown by a remembered frame instead counts as in view (that frame judges
    it). from_s: judge the samples from that trajectory time on (safety_sample_times)."""
    points = traj.position(safety_sample_times(traj, cfg, from_s))
    cameras = [camera] + [f.camera for f in memory]
    cams = [_to_camera(c, points) for c in cameras]
    r2 = cfg.vehicle_radius_m * cfg.vehicle_radius_m
    for j, c in enumerate(cams[0]):
        if float(c @ c) <= r2:
            continue  # the vehicle's own place, as in find_depth_collision
        if _showing_frame(j, cams, cameras) is None:
            return False
    return True


def check_trajectory(
    traj: UniformBspline,
    p_world_vehicle: FloatArray,
    depth_m: NDArray[np.float32] | None,
    camera: CameraModel | None,
    cfg: SafetyConfig,
    memory: Sequence[DepthFrame] = (),
) -> SafetyResult:
    """All checks in order; the first failure is the verdict (depth None: no collision check). memory: the
    remembered earlier frames, newest first (DepthMemory.frames)."""
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
            traj.position(times), cfg.vehicle_radius_m, cfg.collision_min_pixels, depth_m, camera, memory
        )
        if hit.collides:
            t = float(times[hit.sample_index])
            where = (
                ""
                if hit.frame == 0
                else f" of the remembered frame {hit.frame} (t = {hit.frame_stamp_s:.3f} s)"
            )
            return SafetyResult(
                SafetyVerdict.COLLISION_IN_DEPTH,
                f"collision_in_depth: at t = {t:.3f} s the vehicle sphere (r = {cfg.vehicle_radius_m:.2f} m) "
                f"reaches {hit.sphere_depth_m:.3f} m deep along pixel ({hit.u}, {hit.v}){where} whose "
                f"measured depth is {hit.measured_depth_m:.3f} m ({hit.occupied_pixels} occupied pixels)",
                t,
            )
    return SafetyResult(SafetyVerdict.ACCEPTED, "accepted")


def rest_is_clear(
    traj: UniformBspline,
    now_s: float,
    min_rest_s: float,
    p_world_vehicle: FloatArray,
    depth_m: NDArray[np.float32],
    camera: CameraModel,
    cfg: SafetyConfig,
    memory: Sequence[DepthFrame] = (),
) -> bool:
    """Whether the rest of a trajectory sent before (from the time now_s on) may still be flown: at least
    min_rest_s of it is left, the vehicle is within max_start_error_m of where it should be now, and from now
    up to the check horizon no sample enters what the depth frames show occupied or leaves their view (the
    test a recovery plan passes). Its velocity and acceleration were judged when it was sent (C++
    RestIsClear)."""
    elapsed = now_s - traj.start_time_s
    if not (math.isfinite(elapsed) and elapsed >= 0.0 and traj.duration_s - elapsed >= min_rest_s):
        return False
    p = np.asarray(p_world_vehicle, dtype=np.float64).reshape(3)
    if not float(np.linalg.norm(traj.position(elapsed)[0] - p)) <= cfg.max_start_error_m:
        return False
    if not cfg.enabled:
        return True
    times = safety_sample_times(traj, cfg, elapsed)
    hit = find_depth_collision(
        traj.position(times), cfg.vehicle_radius_m, cfg.collision_min_pixels, depth_m, camera, memory
    )
    return not hit.collides and trajectory_in_view(traj, camera, cfg, memory, elapsed)


@dataclass
class VerdictCounts:
    counts: dict[SafetyVerdict, int] = field(default_factory=lambda: {v: 0 for v in SafetyVerdict})

    def add(self, verdict: SafetyVerdict) -> None:
        self.counts[verdict] += 1

    @property
    def refused(self) -> int:
        return sum(n for v, n in self.counts.items() if v != SafetyVerdict.ACCEPTED)


class DepthMemory:
    """The earlier decision frames the safety layer judges out-of-view samples with (SafetyConfig
    memory_frames, memory_spacing_s): after each decision its frame is kept when the newest kept one is at
    least memory_spacing_s older; at most memory_frames are kept, the oldest dropped. A frame older than the
    newest kept (time went back: a new episode, a replayed bag) empties it first. The C++ DepthMemory."""

    def __init__(self, max_frames: int, spacing_s: float) -> None:
        if max_frames < 0 or not (math.isfinite(spacing_s) and spacing_s >= 0.0):
            raise ValueError(
                f"depth memory: memory_frames must be >= 0 and memory_spacing_s finite and >= 0, got "
                f"{max_frames} and {spacing_s}"
            )
        self.max_frames = max_frames
        self.spacing_s = spacing_s
        self.frames: list[DepthFrame] = []  # newest first

    def clear(self) -> None:
        self.frames = []

    def add(self, stamp_s: float, depth_m: NDArray[np.float32], camera: CameraModel) -> bool:
        """Keeps a copy of the frame if it is due; whether it was kept."""
        if self.max_frames == 0:
            return False
        if self.frames and stamp_s < self.frames[0].stamp_s:
            self.clear()
        if self.frames and stamp_s - self.frames[0].stamp_s < self.spacing_s - 1e-9:
            return False
        frame = DepthFrame(float(stamp_s), np.array(depth_m, dtype=np.float32, copy=True), camera)
        self.frames = [frame, *self.frames[: self.max_frames - 1]]
        return True
