"""The clearance check against the simulator's exact boxes (quad_il.evaluation.clearance_check, issue 30).

Synthetic cases show each check can fail (a collision, a clearance <= 0, a world file that disagrees with the
flight, a safety layer fed a frame that hides a wall); the closed-loop case flies the expert over a few seeded
worlds with fast_planner's expert_clearance_flights and requires no violation.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from quad_il.evaluation import clearance_check as cc
from quad_il.evaluation.metrics import Box
from quad_il.inference.config import SafetyConfig, load_policy_config
from quad_il.inference.core import CameraModel

ROOT = Path(__file__).resolve().parents[2]

VEHICLE_BOX = np.array([0.25, 0.25, 0.25])
IDENTITY_Q = np.array([0.0, 0.0, 0.0, 1.0])


def wall(x_face: float) -> Box:
    """A 1 m thick wall whose near face is the plane x = x_face, 10 m wide (y) and 5 m high (z from 0)."""
    return Box(np.array([x_face + 0.5, 0.0, 2.5]), IDENTITY_Q, np.array([1.0, 10.0, 5.0]))


def flown_towards(x_face: float, xs: np.ndarray, exact_offset: float = 0.0) -> np.ndarray:
    """Rows [t, p, q, exact clearance] of an axis-aligned vehicle flying along x at height 1 m: its exact
    clearance to wall(x_face) is the face-to-face gap x_face - x - 0.125."""
    rows = np.zeros((len(xs), cc.FLOWN_COLUMNS))
    rows[:, 0] = np.arange(len(xs)) * 0.005
    rows[:, 1] = xs
    rows[:, 3] = 1.0
    rows[:, 4:8] = IDENTITY_Q
    rows[:, 8] = x_face - xs - 0.125 + exact_offset
    return rows


def test_a_clear_flight_passes_and_its_minimum_is_the_exact_gap() -> None:
    xs = np.linspace(0.0, 4.0, 50)
    c = cc.check_flight(1, flown_towards(5.0, xs), [wall(5.0)], VEHICLE_BOX, collided=False)
    assert c.violations == ()
    assert c.exact_min_m == pytest.approx(5.0 - 4.0 - 0.125)
    assert c.centre_min_m == pytest.approx(1.0)


def test_a_clearance_at_or_below_zero_is_a_violation() -> None:
    xs = np.linspace(0.0, 4.9, 50)  # the vehicle's front face passes x = 5.0
    c = cc.check_flight(2, flown_towards(5.0, xs), [wall(5.0)], VEHICLE_BOX, collided=False)
    assert any("exact clearance" in v and "<= 0" in v for v in c.violations), c.violations


def test_a_reported_collision_is_a_violation() -> None:
    c = cc.check_flight(
        3, flown_towards(5.0, np.linspace(0, 1, 5)), [wall(5.0)], VEHICLE_BOX, True, False, "hit"
    )
    assert any("collision (hit)" in v for v in c.violations)


def test_a_world_file_that_disagrees_with_the_flight_is_a_violation() -> None:
    # The simulator measured the wall at x = 5, the world file puts it 0.3 m farther: the exact clearance is
    # below the centre's bound.
    c = cc.check_flight(
        4, flown_towards(5.0, np.linspace(0, 3, 20)), [wall(5.3)], VEHICLE_BOX, collided=False
    )
    assert any("disagree" in v and "below the centre bound" in v for v in c.violations), c.violations
    c = cc.check_flight(
        5, flown_towards(5.0, np.linspace(0, 3, 20)), [wall(4.7)], VEHICLE_BOX, collided=False
    )
    assert any("above the centre bound" in v for v in c.violations), c.violations


# A camera at (0, 0, 1) looking along world +x (optical x right = world -y, y down = world -z), 160 x 120.
R_WORLD_CAMERA = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def camera() -> CameraModel:
    T = np.eye(4)
    T[:3, :3] = R_WORLD_CAMERA
    T[:3, 3] = [0.0, 0.0, 1.0]
    return CameraModel(160, 120, 96.8, 96.8, 79.5, 59.5, T)


def render_wall(cam: CameraModel, x_face: float, max_depth: float = 10.0) -> np.ndarray:
    """The exact depth image of wall(x_face) (depth along the optical axis = world x distance)."""
    u, v = np.meshgrid(np.arange(cam.width), np.arange(cam.height))
    rays_cam = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u, dtype=float)], -1)
    rays_world = rays_cam @ R_WORLD_CAMERA.T  # per unit optical depth
    depth = x_face - cam.T_world_camera[0, 3]
    hit = rays_world * depth + cam.T_world_camera[:3, 3]
    inside = (np.abs(hit[..., 1]) <= 5.0) & (hit[..., 2] >= 0.0) & (hit[..., 2] <= 5.0) & (depth <= max_depth)
    return np.where(inside, depth, np.inf).astype(np.float32)


def safety_cfg() -> SafetyConfig:
    return load_policy_config(ROOT / "config" / "policy_keep.yaml").safety


def frame_before(depth: np.ndarray, speed: float = 1.0) -> cc.FrameData:
    return cc.FrameData(0.0, depth, camera(), np.array([0.0, 0.0, 1.0]), np.array([speed, 0.0, 0.0]))


def test_the_safety_layer_on_an_exact_frame_keeps_its_guarantee() -> None:
    frame = frame_before(render_wall(camera(), 3.0), speed=2.0)
    plans = cc.candidate_plans(frame, np.random.default_rng(0), 64)
    t = cc.check_plans_on_frame(frame, plans, [wall(3.0)], safety_cfg(), 10.0, VEHICLE_BOX, "synthetic")
    assert t.violations == []
    assert t.accepted > 0 and t.accepted < t.plans  # some plans fly into the wall and are refused
    assert t.refusals.get("collision_in_depth", 0) > 0
    assert t.samples_guaranteed > 0
    assert t.min_guarantee_margin_m > 0.0


def test_a_frame_that_hides_the_wall_makes_accepted_plans_violate() -> None:
    # The safety layer judges what the frame shows: with an empty frame it accepts plans through the wall,
    # and the check against the exact boxes must catch them.
    frame = frame_before(np.full((120, 160), np.inf, dtype=np.float32))
    plans = cc.candidate_plans(frame, np.random.default_rng(0), 64)
    t = cc.check_plans_on_frame(frame, plans, [wall(2.0)], safety_cfg(), 10.0, VEHICLE_BOX, "hidden wall")
    assert t.accepted == t.plans
    assert t.violations and "hidden wall" in t.violations[0]
    assert t.min_guarantee_margin_m < 0.0


def test_a_sphere_partly_outside_the_view_or_range_is_not_guaranteed() -> None:
    cam = camera()
    r = 0.4
    centred = np.array([[0.0, 0.0, 3.0]])
    assert cc.sphere_in_view(centred, r, cam, 10.0).tolist() == [True]
    edge_x = (cam.width - 1 - cam.cx) / cam.fx * 3.0  # the rightmost pixel centre's ray at 3 m
    assert cc.sphere_in_view(np.array([[edge_x - 0.1, 0.0, 3.0]]), r, cam, 10.0).tolist() == [False]
    assert cc.sphere_in_view(np.array([[0.0, 0.0, 9.7]]), r, cam, 10.0).tolist() == [False]  # past 10 m
    assert cc.sphere_in_view(np.array([[0.0, 0.0, -3.0]]), r, cam, 10.0).tolist() == [False]  # behind


def test_the_tolerance_is_the_pixel_discretisation() -> None:
    # One pixel at 96.8 px/m-at-1-m: pitch 1/96.8 m per metre of depth.
    tol = cc.guarantee_tolerance_m(np.array([1.0, 5.0]), 96.8, 96.8, 1)
    expected = 2 * math.sqrt(3) / 96.8 * (math.sqrt(1 / math.pi) + math.sqrt(0.5))
    assert tol[0] == pytest.approx(expected)
    assert tol[1] == pytest.approx(5 * expected)
    assert cc.guarantee_tolerance_m(np.array([1.0]), 96.8, 96.8, 4)[0] > tol[0]


def test_the_expert_over_three_seeded_worlds_keeps_clearance(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    # Closed loop in the simulator core (expert_clearance_flights); 15 m flights keep it quick.
    code = cc.main(
        [
            "--out",
            str(tmp_path),
            "--worlds",
            "3",
            "--seed0",
            "1",
            "--distance-m",
            "15",
            "--frames-every",
            "4",
            "--candidates",
            "8",
            "--planner-config",
            str(ROOT / "config/planner.yaml"),
            "--sim-config",
            str(ROOT / "config/sim.yaml"),
            "--tracker-config",
            str(ROOT / "config/tracker.yaml"),
            "--policy-config",
            str(ROOT / "config/policy_keep.yaml"),
        ]
    )
    out = capsys.readouterr().out
    assert code == 0, out
    bench = dict(re.findall(r"^BENCH (\S+) (\S+) ", out, flags=re.M))
    assert float(bench["clearance_worlds"]) == 3
    assert float(bench["clearance_expert_collisions"]) == 0
    assert float(bench["clearance_expert_min_m"]) > 0.0
    assert float(bench["clearance_expert_violations"]) == 0
    assert float(bench["clearance_safety_accepted"]) > 0
    assert float(bench["clearance_safety_samples_guaranteed"]) > 0
    assert float(bench["clearance_safety_violations"]) == 0
    # Judging the kept flights again gives the same lines (seeded candidates, no flight).
    again = cc.main(
        [
            "--flights-from",
            str(tmp_path),
            "--candidates",
            "8",
            "--policy-config",
            str(ROOT / "config/policy_keep.yaml"),
        ]
    )
    assert again == 0
    assert re.findall(r"^BENCH .*$", capsys.readouterr().out, flags=re.M) == re.findall(
        r"^BENCH .*$", out, flags=re.M
    )
