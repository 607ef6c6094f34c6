"""Clearance against the simulator's exact boxes, for the expert's flights and the safety layer's accepted
plans (issue 30; docs/fast_planner.md, "Clearance against the simulator's boxes").

    python -m quad_il.evaluation.clearance_check --worlds 100 --seed0 1 [--out DIR] [--jobs 2]

1. The expert: fast_planner's `expert_clearance_flights` flies the expert in the simulator core (simulator +
   tracker + planner in one deterministic process, no ROS; the worlds and 30 m start/goal pairs of
   planner_bench) and writes, per world, the world flown and every control period's pose with the
   simulator's exact clearance (ClearanceToObstacles: the oriented vehicle box to the nearest oriented world
   box). A flight violates when the simulator reports a collision or its exact clearance is ever <= 0. As an
   independent cross-check the pose is measured here against the world file's boxes
   (metrics.point_box_distances): the exact clearance must lie between the centre's distance minus the
   vehicle box's circumscribed radius and minus its inscribed radius; otherwise the world file and the flight
   disagree, which is a violation too.

2. The safety layer (quad_policy's, bound as inference.core.check_trajectory, with the `safety`
   section of --policy-config): at every K-th expert plan the depth frame the plan used is judged with seeded
   candidate plans from the vehicle's odometry (straight and turning ones in and beside the view, and ones
   stopping short of a surface the frame shows). What the layer guarantees for a plan it accepts, and what is
   checked, exactly: at each sample time it tests (safety_sample_times: every sample_dt_s up to
   check_horizon_s), whose sphere of radius r = vehicle_radius_m lies wholly inside the pyramid of the
   image's outermost pixel centres and within the camera's range (|c| + r <= max depth), the sphere holds no
   box surface the frame's pixel rays could see, so the sample's centre is farther than r - tol from every
   exact box. tol is the pixel discretisation: a box entering the sphere by tol = 2 sqrt(3) s (sqrt(k / pi) +
   sqrt(2) / 2), with s the pixel pitch at the sphere's far depth and k = collision_min_pixels, holds a cube
   that k pixel rays pass through. A sample closer than that is a violation. Nothing is promised between
   samples, beyond the horizon, or for a sphere partly outside the view or range (the depth frame does not
   show that space): such samples are counted, and those whose centre comes within the vehicle box's
   circumscribed radius of a box are reported as unguarded contacts (not violations).

Prints a summary and `BENCH clearance_<name> <value> <unit>` lines; exits 1 on any violation, 2 on bad input.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO

import numpy as np
import yaml
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quad_il.evaluation.metrics import Box, point_box_distances
from quad_il.inference.config import SafetyConfig, load_policy_config
from quad_il.inference.core import CameraModel, UniformBspline, check_trajectory, safety_sample_times
from quad_il.tools.binaries import find_binary
from quad_il.tools.cli import HelpFormatter

FloatArray = NDArray[np.float64]

FLOWN_COLUMNS = 9  # t_s, p xyz, q xyzw, exact clearance_m (expert_clearance_flights' flown_<seed>.bin)
CONSISTENCY_TOL_M = 1e-6
CANDIDATE_CTRL_PTS = 10  # as the network's output (config/train.yaml shards.num_ctrl_pts)


class ClearanceCheckError(RuntimeError):
    """Bad input or a failed tool run; the message names the file or the command."""


# ---------------------------------------------------------------------------------------------------- worlds


def load_world_boxes(path: Path) -> list[Box]:
    """The oriented boxes of a quad_sim world file (quaternions x, y, z, w)."""
    try:
        tree = yaml.load(path.read_text(), Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))
        return [
            Box(
                np.asarray(b["center_m"], dtype=np.float64),
                np.asarray(b["q_xyzw"], dtype=np.float64),
                np.asarray(b["size_m"], dtype=np.float64),
            )
            for b in tree["boxes"]
        ]
    except (OSError, KeyError, TypeError, yaml.YAMLError) as e:
        raise ClearanceCheckError(f"{path}: not a readable quad_sim world file: {e}") from None


# ---------------------------------------------------------------------------------------------------- expert


@dataclass(frozen=True)
class FlightCheck:
    seed: int
    reached_goal: bool
    collided: bool
    end_reason: str
    samples: int
    exact_min_m: float  # the simulator's exact box-to-box clearance, minimum over the flight
    centre_min_m: float  # the vehicle centre's distance to the nearest box, minimum over the flight
    violations: tuple[str, ...]


def check_flight(
    seed: int,
    flown: FloatArray,
    boxes: Sequence[Box],
    vehicle_box_m: FloatArray,
    collided: bool,
    reached_goal: bool = False,
    end_reason: str = "",
) -> FlightCheck:
    """Judges one flight: flown is (N, 9) rows of expert_clearance_flights' flown_<seed>.bin."""
    rows = np.asarray(flown, dtype=np.float64).reshape(-1, FLOWN_COLUMNS)
    violations: list[str] = []
    if len(rows) == 0:
        violations.append(f"world {seed}: no flown samples")
        return FlightCheck(seed, reached_goal, collided, end_reason, 0, math.nan, math.nan, tuple(violations))
    t, p, exact = rows[:, 0], rows[:, 1:4], rows[:, 8]
    centre = point_box_distances(p, boxes)
    half = 0.5 * np.asarray(vehicle_box_m, dtype=np.float64)
    r_out, r_in = float(np.linalg.norm(half)), float(np.min(half))
    if collided:
        violations.append(f"world {seed}: the simulator reported a collision ({end_reason})")
    bad = np.flatnonzero(~(exact > 0.0))
    if len(bad):
        i = int(bad[0])
        violations.append(
            f"world {seed}: exact clearance {exact[i]:.4f} m <= 0 at t = {t[i]:.3f} s, "
            f"p = {np.round(p[i], 3)} ({len(bad)} control periods)"
        )
    # exact must lie in [centre - r_out, centre - r_in] (where finite: +inf without boxes near).
    finite = np.isfinite(centre) & np.isfinite(exact)
    low = finite & (exact < centre - r_out - CONSISTENCY_TOL_M)
    high = finite & (exact > centre - r_in + CONSISTENCY_TOL_M)
    for name, mask in (("below the centre bound", low), ("above the centre bound", high)):
        if np.any(mask):
            i = int(np.argmax(mask))
            violations.append(
                f"world {seed}: the world file and the flight disagree at t = {t[i]:.3f} s: exact clearance "
                f"{exact[i]:.4f} m {name} (centre distance {centre[i]:.4f} m, vehicle radii {r_in:.4f} / "
                f"{r_out:.4f} m)"
            )
    return FlightCheck(
        seed,
        reached_goal,
        collided,
        end_reason,
        len(rows),
        float(np.min(exact)),
        float(np.min(centre)),
        tuple(violations),
    )


# ---------------------------------------------------------------------------------------------- safety layer


@dataclass(frozen=True)
class FrameData:
    """One depth frame as an expert plan used it, with the odometry of that plan."""

    stamp_s: float
    depth_m: NDArray[np.float32]  # (height, width), metres along the optical axis (REP 118)
    camera: CameraModel
    p_world_body: FloatArray
    v_world: FloatArray


def guarantee_tolerance_m(far_depth_m: FloatArray, fx: float, fy: float, min_pixels: int) -> FloatArray:
    """How deep (m) a box may enter the tested sphere unseen by the pixel rays (module docstring)."""
    pitch = np.asarray(far_depth_m, dtype=np.float64) / min(fx, fy)
    return 2.0 * math.sqrt(3.0) * pitch * (math.sqrt(min_pixels / math.pi) + math.sqrt(0.5))


def sphere_in_view(
    points_cam: FloatArray, radius_m: float, camera: CameraModel, max_depth_m: float
) -> FloatArray:
    """(S,) whether each sphere (centres in the camera optical frame) lies inside the pyramid of the image's
    outermost pixel centres (u in [0, width - 1], v in [0, height - 1]) and within the range."""
    c = np.asarray(points_cam, dtype=np.float64).reshape(-1, 3)
    x, y, z = c[:, 0], c[:, 1], c[:, 2]
    u_hi, v_hi = camera.width - 1.0 - camera.cx, camera.height - 1.0 - camera.cy
    planes = [  # signed distance to each side plane through the optical centre, positive inside
        (camera.fx * x + camera.cx * z) / math.hypot(camera.fx, camera.cx),
        (u_hi * z - camera.fx * x) / math.hypot(camera.fx, u_hi),
        (camera.fy * y + camera.cy * z) / math.hypot(camera.fy, camera.cy),
        (v_hi * z - camera.fy * y) / math.hypot(camera.fy, v_hi),
    ]
    inside = np.all(np.stack(planes) >= radius_m, axis=0)
    return inside & (np.linalg.norm(c, axis=1) + radius_m <= max_depth_m)


def _pose_matrix(p: FloatArray, q_xyzw: FloatArray) -> FloatArray:
    """4 x 4 transform of a position and a rotation (x, y, z, w)."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(q_xyzw).as_matrix()
    T[:3, 3] = p
    return T


def _uniform(ctrl: FloatArray, knot_dt_s: float, start_time_s: float) -> UniformBspline:
    return UniformBspline(start_time_s=start_time_s, knot_dt_s=knot_dt_s, ctrl_world=np.asarray(ctrl))


def candidate_plans(frame: FrameData, rng: np.random.Generator, count: int) -> list[UniformBspline]:
    """Seeded plans from the frame's odometry, half turning towards a direction within +-50 deg of the
    camera's heading (its half field of view is about 40 deg) at up to 4 m/s, half flying at a surface point
    the frame shows (nearer than 4.5 m when there is one) and stopping 0.1-1.2 m short of it (the boundary the
    depth test must draw)."""
    R = frame.camera.T_world_camera[:3, :3]
    axis = R[:, 2]
    heading = math.atan2(axis[1], axis[0])
    p0, v0 = frame.p_world_body, frame.v_world
    depth = frame.depth_m
    # Surfaces within reach of a 1 s horizon at up to 4 m/s (else any the frame shows).
    shown = np.argwhere(np.isfinite(depth) & (depth > 0.0) & (depth < 4.5))
    if len(shown) == 0:
        shown = np.argwhere(np.isfinite(depth) & (depth > 0.0))
    plans: list[UniformBspline] = []
    segments = CANDIDATE_CTRL_PTS - 3
    for i in range(count):
        if i % 2 == 0 or len(shown) == 0:
            yaw = heading + math.radians(rng.uniform(-50.0, 50.0))
            pitch = math.radians(rng.uniform(-10.0, 10.0))
            target = rng.uniform(0.5, 4.0) * np.array(
                [math.cos(pitch) * math.cos(yaw), math.cos(pitch) * math.sin(yaw), math.sin(pitch)]
            )
            tau = max(rng.uniform(0.3, 1.2), float(np.linalg.norm(target - v0)) / 5.0)
            duration = 2.0
            dt = duration / segments
            ts = (np.arange(CANDIDATE_CTRL_PTS) - 1.0) * dt
            # v(t) = v0 + (target - v0) min(t / tau, 1) for t >= 0, v0 before; integrated from p0.
            ramp = np.where(ts < tau, ts * ts / (2.0 * tau), ts - 0.5 * tau)
            ramp = np.where(ts < 0.0, 0.0, ramp)
            ctrl = p0 + np.outer(ts, v0) + np.outer(ramp, target - v0)
        else:
            row, col = shown[int(rng.integers(len(shown)))]
            z = float(depth[row, col])
            cam = frame.camera
            ray = np.array([(col - cam.cx) / cam.fx, (row - cam.cy) / cam.fy, 1.0]) * z
            surface = R @ ray + cam.T_world_camera[:3, 3]
            to_surface = surface - p0
            dist = float(np.linalg.norm(to_surface))
            length = dist - rng.uniform(0.1, 1.2)
            if length < 0.3:
                continue
            direction = to_surface / dist
            # The quintic profile's peak speed 1.875 L / T and peak acceleration 5.77 L / T^2 within limits.
            duration = max(1.875 * length / rng.uniform(1.0, 4.0), math.sqrt(5.77 * length / 5.5), 0.5)
            dt = duration / segments
            ts = (np.arange(CANDIDATE_CTRL_PTS) - 1.0) * dt
            u = np.clip(ts / duration, 0.0, 1.0)
            s = length * (10 * u**3 - 15 * u**4 + 6 * u**5)
            drift = 0.3 * (1.0 - np.exp(-np.maximum(ts, 0.0) / 0.3))  # the start velocity fading out
            drift = np.where(ts < 0.0, ts, drift)
            ctrl = p0 + np.outer(s, direction) + np.outer(drift, v0)
        plans.append(_uniform(ctrl, dt, frame.stamp_s))
    return plans


@dataclass
class SafetyTally:
    frames: int = 0
    plans: int = 0
    accepted: int = 0
    samples_guaranteed: int = 0  # tested samples of accepted plans whose sphere the frame shows whole
    samples_unguarded: int = 0  # tested samples of accepted plans partly or wholly outside the view or range
    min_sphere_margin_m: float = math.inf  # min over guaranteed samples of centre distance - r
    min_guarantee_margin_m: float = math.inf  # min over guaranteed samples of centre distance - (r - tol)
    unguarded_contacts: int = 0  # unguarded samples whose centre is within the vehicle's circumscribed radius
    refusals: dict[str, int] = field(default_factory=dict)
    violations: list[str] = field(default_factory=list)
    contacts: list[str] = field(default_factory=list)  # where the unguarded contacts were (not violations)

    def merge(self, other: SafetyTally) -> None:
        self.frames += other.frames
        self.plans += other.plans
        self.accepted += other.accepted
        self.samples_guaranteed += other.samples_guaranteed
        self.samples_unguarded += other.samples_unguarded
        self.min_sphere_margin_m = min(self.min_sphere_margin_m, other.min_sphere_margin_m)
        self.min_guarantee_margin_m = min(self.min_guarantee_margin_m, other.min_guarantee_margin_m)
        self.unguarded_contacts += other.unguarded_contacts
        for k, v in other.refusals.items():
            self.refusals[k] = self.refusals.get(k, 0) + v
        self.violations.extend(other.violations)
        self.contacts.extend(other.contacts)


def check_plans_on_frame(
    frame: FrameData,
    plans: Sequence[UniformBspline],
    boxes: Sequence[Box],
    cfg: SafetyConfig,
    max_depth_m: float,
    vehicle_box_m: FloatArray,
    where: str,
) -> SafetyTally:
    """Runs the safety layer on each plan with this frame and checks every accepted one's guarantee."""
    tally = SafetyTally(frames=1)
    r = cfg.vehicle_radius_m
    r_vehicle = 0.5 * float(np.linalg.norm(vehicle_box_m))
    cam = frame.camera
    T = np.asarray(cam.T_world_camera, dtype=np.float64)
    for n, plan in enumerate(plans):
        tally.plans += 1
        result = check_trajectory(plan, frame.p_world_body, frame.depth_m, cam, cfg)
        if not result.accepted:
            label = result.label
            tally.refusals[label] = tally.refusals.get(label, 0) + 1
            continue
        tally.accepted += 1
        times = safety_sample_times(plan, cfg)
        pts = plan.position(times)
        pts_cam = (pts - T[:3, 3]) @ T[:3, :3]
        dist = point_box_distances(pts, boxes)
        whole = sphere_in_view(pts_cam, r, cam, max_depth_m)
        tol = guarantee_tolerance_m(pts_cam[:, 2] + r, cam.fx, cam.fy, cfg.collision_min_pixels)
        tally.samples_guaranteed += int(np.count_nonzero(whole))
        tally.samples_unguarded += int(np.count_nonzero(~whole))
        if np.any(whole):
            tally.min_sphere_margin_m = min(tally.min_sphere_margin_m, float(np.min(dist[whole] - r)))
            margin = dist - (r - tol)
            tally.min_guarantee_margin_m = min(tally.min_guarantee_margin_m, float(np.min(margin[whole])))
            bad = np.flatnonzero(whole & ~(margin > 0.0))
            if len(bad):
                j = int(bad[0])
                tally.violations.append(
                    f"{where}, candidate {n}: the safety layer accepted a plan whose sample at "
                    f"t = {times[j]:.3f} s (shown whole by the frame) is {dist[j]:.4f} m from a box, "
                    f"within r - tol = {r:.3f} - {tol[j]:.4f} m"
                )
        near = np.flatnonzero(~whole & (dist <= r_vehicle))
        tally.unguarded_contacts += len(near)
        for j in near:
            c = pts_cam[j]
            view = "in front of" if c[2] > 0.0 else "behind"
            tally.contacts.append(
                f"{where}, candidate {n}: sample at t = {times[j]:.3f} s, {dist[j]:.4f} m from a box, its "
                f"centre at {np.linalg.norm(c):.2f} m {view} the camera (optical frame {np.round(c, 2)}), "
                "its sphere not wholly in the view"
            )
    return tally


def load_frames(meta_path: Path, pixels_path: Path) -> list[FrameData]:
    frames: list[FrameData] = []
    if not meta_path.is_file():
        return frames
    pixels = np.fromfile(pixels_path, dtype=np.float32) if pixels_path.is_file() else np.zeros(0, np.float32)
    for line_no, line in enumerate(meta_path.read_text().splitlines(), 1):
        try:
            m = json.loads(line)
            w, h, off = int(m["width"]), int(m["height"]), int(m["offset"])
            first = off // 4
            if off % 4 or first + w * h > len(pixels):
                raise ValueError(f"pixels at byte {off} run past the end of {pixels_path}")
            camera = CameraModel(
                w,
                h,
                m["fx"],
                m["fy"],
                m["cx"],
                m["cy"],
                _pose_matrix(m["p_world_camera"], m["q_world_camera"]),
            )
            frames.append(
                FrameData(
                    float(m["stamp_s"]),
                    pixels[first : first + w * h].reshape(h, w),
                    camera,
                    np.asarray(m["p_world_body"], dtype=np.float64),
                    np.asarray(m["v_world"], dtype=np.float64),
                )
            )
        except (KeyError, ValueError, TypeError) as e:
            raise ClearanceCheckError(f"{meta_path}:{line_no}: bad frame record: {e}") from None
    return frames


# ---------------------------------------------------------------------------------------------------- the run


@dataclass
class Summary:
    flights: list[FlightCheck]
    safety: SafetyTally
    policy_config: Path

    @property
    def violations(self) -> list[str]:
        return [v for f in self.flights for v in f.violations] + self.safety.violations

    def bench_lines(self) -> list[str]:
        fl = self.flights
        exact = min((f.exact_min_m for f in fl), default=math.nan)
        s = self.safety
        rows = [
            ("clearance_worlds", len(fl), "worlds"),
            ("clearance_expert_goals_reached", sum(f.reached_goal for f in fl), "goals"),
            ("clearance_expert_collisions", sum(f.collided for f in fl), "collisions"),
            ("clearance_expert_min_m", exact, "m"),
            ("clearance_expert_violations", sum(bool(f.violations) for f in fl), "worlds"),
            ("clearance_safety_frames", s.frames, "frames"),
            ("clearance_safety_plans", s.plans, "plans"),
            ("clearance_safety_accepted", s.accepted, "plans"),
            ("clearance_safety_samples_guaranteed", s.samples_guaranteed, "samples"),
            ("clearance_safety_samples_unguarded", s.samples_unguarded, "samples"),
            ("clearance_safety_min_sphere_margin_m", s.min_sphere_margin_m, "m"),
            ("clearance_safety_min_guarantee_margin_m", s.min_guarantee_margin_m, "m"),
            ("clearance_safety_unguarded_contacts", s.unguarded_contacts, "samples"),
            ("clearance_safety_violations", len(s.violations), "samples"),
        ]
        return [f"BENCH {name} {float(value):.4f} {unit}" for name, value, unit in rows]


def run_flights(
    seeds: Sequence[int], out_dir: Path, args: argparse.Namespace, jobs: int
) -> list[tuple[dict, Path]]:
    """Runs expert_clearance_flights over the seeds in `jobs` parallel chunks; (flight record, chunk dir)."""
    tool = find_binary("quad_bench", "expert_clearance_flights")
    chunks = [list(seeds[i::jobs]) for i in range(jobs) if seeds[i::jobs]]

    def run(k: int, chunk: list[int]) -> Path:
        d = out_dir / f"chunk_{k}"
        cmd = [
            str(tool),
            "--planner-config",
            str(args.planner_config),
            "--sim-config",
            str(args.sim_config),
            "--tracker-config",
            str(args.tracker_config),
            "--seeds",
            ",".join(str(s) for s in chunk),
            "--out",
            str(d),
            "--frames-every",
            str(args.frames_every),
            "--timeout-s",
            str(args.timeout_s),
            "--distance-m",
            str(args.distance_m),
        ]
        if args.density:
            cmd += ["--density", str(args.density)]
        with open(out_dir / f"chunk_{k}.log", "w") as log:
            proc = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT)
        if proc.returncode != 0:
            tail = (out_dir / f"chunk_{k}.log").read_text()[-2000:]
            raise ClearanceCheckError(f"{' '.join(cmd)} exited {proc.returncode}:\n{tail}")
        return d

    with ThreadPoolExecutor(max_workers=jobs) as pool:
        dirs = list(pool.map(lambda kc: run(*kc), enumerate(chunks)))
    out: list[tuple[dict, Path]] = []
    for d in dirs:
        for line in (d / "flights.jsonl").read_text().splitlines():
            out.append((json.loads(line), d))
    return sorted(out, key=lambda fd: fd[0]["seed"])


def load_flights(out_dir: Path) -> list[tuple[dict, Path]]:
    """The flight records of an earlier run's --out directory (its chunk_<k> directories)."""
    flights = [
        (json.loads(line), d)
        for d in sorted(out_dir.glob("chunk_*/"))
        for line in (d / "flights.jsonl").read_text().splitlines()
    ]
    if not flights:
        raise ClearanceCheckError(f"{out_dir}: no chunk_*/flights.jsonl of an earlier run")
    return sorted(flights, key=lambda fd: fd[0]["seed"])


def analyse(
    flights: Sequence[tuple[dict, Path]], cfg: SafetyConfig, candidates: int, seed0: int, policy_config: Path
) -> Summary:
    checks: list[FlightCheck] = []
    tally = SafetyTally()
    for rec, d in flights:
        seed = int(rec["seed"])
        run = json.loads((d / "run.json").read_text())
        vehicle_box = np.asarray(run["vehicle_collision_box_m"], dtype=np.float64)
        boxes = load_world_boxes(d / f"world_{seed}.yaml")
        if len(boxes) != int(rec["boxes"]):
            raise ClearanceCheckError(
                f"{d}/world_{seed}.yaml has {len(boxes)} boxes, the flight {rec['boxes']}"
            )
        flown = np.fromfile(d / f"flown_{seed}.bin", dtype=np.float64)
        if flown.size != FLOWN_COLUMNS * int(rec["flown_samples"]):
            raise ClearanceCheckError(
                f"{d}/flown_{seed}.bin holds {flown.size} values, not {rec['flown_samples']} rows"
            )
        checks.append(
            check_flight(
                seed,
                flown,
                boxes,
                vehicle_box,
                bool(rec["collided"]),
                bool(rec["reached_goal"]),
                rec["end_reason"],
            )
        )
        frames = load_frames(d / f"frames_{seed}.jsonl", d / f"frames_{seed}.bin")
        for k, frame in enumerate(frames):
            rng = np.random.default_rng([seed0, seed, k])
            tally.merge(
                check_plans_on_frame(
                    frame,
                    candidate_plans(frame, rng, candidates),
                    boxes,
                    cfg,
                    float(run["camera_max_depth_m"]),
                    vehicle_box,
                    f"world {seed} frame {k} (t = {frame.stamp_s:.3f} s)",
                )
            )
    return Summary(checks, tally, policy_config)


def print_summary(summary: Summary, out: TextIO | None = None) -> None:
    out = out or sys.stdout
    fl, s = summary.flights, summary.safety
    print(
        f"clearance check: {len(fl)} worlds (seeds {fl[0].seed}..{fl[-1].seed})" if fl else "no worlds",
        file=out,
    )
    for f in fl:
        if f.violations or not f.reached_goal:
            outcome = "reached" if f.reached_goal else "NOT reached"
            print(
                f"  world {f.seed}: {outcome} ({f.end_reason}), exact min clearance {f.exact_min_m:.3f} m",
                file=out,
            )
    goals, collisions = sum(f.reached_goal for f in fl), sum(f.collided for f in fl)
    print(
        f"expert: {goals}/{len(fl)} goals, {collisions} collisions, "
        f"exact min clearance {min((f.exact_min_m for f in fl), default=math.nan):.4f} m over "
        f"{sum(f.samples for f in fl)} control periods",
        file=out,
    )
    print(
        f"safety layer ({summary.policy_config}): {s.frames} frames, {s.plans} candidate plans, {s.accepted} "
        f"accepted (refused: {', '.join(f'{k} {v}' for k, v in sorted(s.refusals.items())) or 'none'}); "
        f"{s.samples_guaranteed} tested samples shown whole by the frame: min centre distance - r "
        f"{s.min_sphere_margin_m:.4f} m, min margin to r - tol {s.min_guarantee_margin_m:.4f} m; "
        f"{s.samples_unguarded} samples outside the guarantee, {s.unguarded_contacts} of them within the "
        "vehicle's circumscribed radius of a box",
        file=out,
    )
    for note in s.contacts[:10]:
        print(f"unguarded contact: {note}", file=out)
    for v in summary.violations[:20]:
        print(f"VIOLATION {v}", file=out)
    if len(summary.violations) > 20:
        print(f"... and {len(summary.violations) - 20} more violations", file=out)
    for line in summary.bench_lines():
        print(line, file=out)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        formatter_class=HelpFormatter,
        prog="python -m quad_il.evaluation.clearance_check",
        description="Fly the expert over seeded worlds and check the flights and the safety layer's accepted "
        "plans against the simulator's exact boxes (docs/fast_planner.md).",
    )
    p.add_argument("--worlds", type=int, default=100, help="number of seeded worlds")
    p.add_argument(
        "--seed0", type=int, default=1, help="first world seed; worlds seed0 .. seed0 + worlds - 1"
    )
    p.add_argument("--density", type=float, default=0.0, help="boxes per 100 m^2 (0: the sim config's count)")
    p.add_argument("--planner-config", type=Path, default=Path("config/planner.yaml"), help="expert config")
    p.add_argument("--sim-config", type=Path, default=Path("config/sim.yaml"), help="simulator config")
    p.add_argument("--tracker-config", type=Path, default=Path("config/tracker.yaml"), help="tracker config")
    p.add_argument(
        "--policy-config", type=Path, default=Path("config/policy_keep.yaml"), help="its safety section"
    )
    p.add_argument(
        "--frames-every", type=int, default=5, help="judge every K-th expert plan's frame (0: none)"
    )
    p.add_argument("--candidates", type=int, default=16, help="candidate plans per judged frame")
    p.add_argument(
        "--distance-m", type=float, default=30.0, help="start-goal distance (planner_bench's 30 m)"
    )
    p.add_argument("--timeout-s", type=float, default=60.0, help="sim-time limit of one flight")
    p.add_argument("--jobs", type=int, default=1, help="parallel flight processes")
    p.add_argument("--out", type=Path, default=None, help="keep the flights here (default: a temporary dir)")
    p.add_argument(
        "--flights-from",
        type=Path,
        default=None,
        help="judge the flights an earlier run kept in this --out directory instead of flying",
    )
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.worlds < 1 or args.jobs < 1 or args.frames_every < 0 or args.candidates < 0 or args.seed0 < 0:
        print(
            "error: --worlds and --jobs must be >= 1; --frames-every, --candidates, --seed0 >= 0",
            file=sys.stderr,
        )
        return 2
    try:
        cfg = load_policy_config(args.policy_config).safety
        seeds = list(range(args.seed0, args.seed0 + args.worlds))
        with tempfile.TemporaryDirectory(prefix="clearance_check_") as tmp:
            out = args.out or Path(tmp)
            out.mkdir(parents=True, exist_ok=True)
            if args.flights_from:
                flights = load_flights(args.flights_from)
            else:
                flights = run_flights(seeds, out, args, min(args.jobs, len(seeds)))
            summary = analyse(flights, cfg, args.candidates, args.seed0, args.policy_config)
    except (ClearanceCheckError, FileNotFoundError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print_summary(summary)
    return 1 if summary.violations else 0


if __name__ == "__main__":
    sys.exit(main())
