"""The Python safety layer (quad_il.inference.safety): one test per refusal reason, a safe plan accepted, the
radius as margin, the depth test against a brute-force scan of every pixel, and the depth memory. The C++
twin has the same cases (src/quad_policy/test/test_safety.cpp); test_inference_parity.py holds the two to
each other."""

from __future__ import annotations

import numpy as np
import pytest

from quad_il.inference.config import SafetyConfig
from quad_il.inference.safety import (
    CameraModel,
    DepthFrame,
    DepthMemory,
    SafetyVerdict,
    VerdictCounts,
    check_trajectory,
    find_depth_collision,
    rest_is_clear,
    safety_sample_times,
    trajectory_in_view,
)
from quad_il.inference.trajectory import UniformBspline

W, H = 160, 120
VEHICLE = np.array([-0.1, 0.0, 0.0])  # 0.1 m behind the camera


def camera(T: np.ndarray | None = None) -> CameraModel:
    """160 x 120, Fast-Planner's field of view, at the world origin looking along world +x (by default)."""
    if T is None:
        T = np.eye(4)
        T[:3, :3] = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], dtype=np.float64)
    return CameraModel(W, H, 96.8, 96.8, 79.5, 59.5, T)


def uniform(depth_m: float) -> np.ndarray:
    return np.full((H, W), depth_m, dtype=np.float32)


def line(speed: float, y_offset: float = 0.0, zigzag: float = 0.0) -> UniformBspline:
    """Straight along +x from the vehicle, K = 10 over 2 s; zigzag: alternating lateral control points."""
    dt = 2.0 / 7.0
    tau = (np.arange(10) - 1.0) * dt
    ctrl = np.zeros((10, 3))
    ctrl[:, 0] = -0.1 + speed * tau
    ctrl[:, 1] = y_offset + zigzag * (-1.0) ** np.arange(10)
    return UniformBspline(5.0, dt, ctrl)


def cfg(**kw: object) -> SafetyConfig:
    base = dict(
        enabled=True,
        max_vel_mps=5.0,
        max_acc_mps2=10.0,
        max_start_error_m=1.0,
        vehicle_radius_m=0.25,
        sample_dt_s=0.05,
        check_horizon_s=0.0,
        collision_min_pixels=1,
        memory_frames=0,
        memory_spacing_s=0.2,
    )
    base.update(kw)
    return SafetyConfig(**base)


def check(traj: UniformBspline, depth: np.ndarray, c: SafetyConfig | None = None):
    return check_trajectory(traj, VEHICLE, depth, camera(), c or cfg())


def test_a_safe_plan_in_free_space_is_accepted() -> None:
    r = check(line(2.0), uniform(np.inf))
    assert r.verdict == SafetyVerdict.ACCEPTED and r.verdict.label == "accepted", r.reason
    assert check(line(2.0), uniform(6.0)).accepted  # a wall beyond reach


def test_non_finite_control_points_are_refused_even_when_disabled() -> None:
    t = line(2.0)
    t.ctrl_world[4, 1] = np.nan
    r = check(t, uniform(np.inf), cfg(enabled=False))
    assert r.verdict == SafetyVerdict.NON_FINITE_OUTPUT and r.verdict.label == "non_finite_output"
    assert "control point 4" in r.reason


def test_control_point_speed_above_the_limit_is_refused() -> None:
    r = check(line(6.0), uniform(np.inf))
    assert r.verdict == SafetyVerdict.VELOCITY_LIMIT and r.verdict.label == "velocity_limit"
    assert r.value == pytest.approx(6.0, abs=1e-9)
    assert check(line(6.0), uniform(np.inf), cfg(enabled=False)).accepted


def test_control_point_acceleration_above_the_limit_is_refused() -> None:
    r = check(line(2.0, zigzag=0.3), uniform(np.inf))
    assert r.verdict == SafetyVerdict.ACCELERATION_LIMIT and r.verdict.label == "acceleration_limit"
    assert r.value == pytest.approx(1.2 / (2.0 / 7.0) ** 2, abs=1e-9)  # |c_i - 2 c_i+1 + c_i+2| / dt^2


def test_a_trajectory_starting_far_from_the_vehicle_is_refused() -> None:
    r = check(line(2.0, y_offset=2.0), uniform(np.inf))
    assert r.verdict == SafetyVerdict.START_FAR_FROM_VEHICLE and r.verdict.label == "start_far_from_vehicle"
    assert r.value == pytest.approx(2.0, abs=1e-9)


def test_a_trajectory_into_a_wall_seen_in_the_depth_image_is_refused() -> None:
    r = check(line(2.0), uniform(3.0))
    assert r.verdict == SafetyVerdict.COLLISION_IN_DEPTH and r.verdict.label == "collision_in_depth"
    # First sample whose sphere reaches 3 m: x = 2 t - 0.1 > 3 - 0.25 at t = 1.45 (1.55 with r = 0.1).
    assert r.value == pytest.approx(1.45, abs=1e-9), r.reason
    assert check(line(2.0), uniform(3.0), cfg(vehicle_radius_m=0.1)).value == pytest.approx(1.55, abs=1e-9)
    assert check(line(2.0), uniform(3.0), cfg(check_horizon_s=1.0)).accepted


def test_too_near_pixels_are_occupied_and_invalid_pixels_are_free() -> None:
    assert check(line(2.0), uniform(-np.inf)).verdict == SafetyVerdict.COLLISION_IN_DEPTH
    assert check(line(2.0), uniform(np.nan)).accepted


def test_the_vehicle_radius_is_the_margin_beside_an_obstacle() -> None:
    d = uniform(np.inf)
    d[:, :40] = 3.0  # a pillar at 3 m on the left (world +y) of the image
    assert check(line(2.0), d).accepted
    assert check(line(2.0, 1.1), d, cfg(max_start_error_m=2.0)).verdict == SafetyVerdict.COLLISION_IN_DEPTH
    assert check(line(2.0, 1.1), d, cfg(max_start_error_m=2.0, vehicle_radius_m=0.1)).accepted


def test_samples_behind_the_camera_or_holding_it_are_not_judged() -> None:
    wall = uniform(0.5)
    samples = np.array([[-0.1, 0, 0], [-2.0, 0, 0]], dtype=np.float64)
    assert not find_depth_collision(samples, 0.25, 1, wall, camera()).collides
    hit = find_depth_collision(np.vstack([samples, [0.4, 0, 0]]), 0.25, 1, wall, camera())
    assert hit.collides and hit.sample_index == 2


def _brute_force(c: np.ndarray, r: float, depth: np.ndarray, cam: CameraModel) -> int:
    if c @ c <= r * r:
        return 0
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    dirs = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u, dtype=float)], -1)
    a = np.sum(dirs * dirs, -1)
    b = dirs @ c
    disc = b * b - a * (c @ c - r * r)
    t_far = (b + np.sqrt(np.maximum(disc, 0))) / a
    d = depth.astype(np.float64)
    known = ~np.isnan(d) & ~np.isposinf(d)
    return int(
        np.count_nonzero((disc >= 0) & known & (t_far > np.maximum(np.nan_to_num(d, neginf=0.0), 0.0)))
    )


def test_the_bounding_rectangle_finds_every_occupied_pixel_of_a_brute_force_scan() -> None:
    rng = np.random.default_rng(11)
    cam = camera(np.eye(4))  # samples in the camera frame
    collisions = 0
    for trial in range(150):
        d = uniform(np.inf)
        for _ in range(8):
            u0, v0 = rng.integers(0, W), rng.integers(0, H)
            d[v0 : v0 + 1 + rng.integers(0, 60), u0 : u0 + 1 + rng.integers(0, 60)] = rng.uniform(0.3, 6.0)
        c = np.array([rng.uniform(-3, 3), rng.uniform(-3, 3), rng.uniform(-1, 6)])
        r = rng.uniform(0.05, 0.8)
        expected = _brute_force(c, r, d, cam)
        hit = find_depth_collision(c[None], r, 1, d, cam)
        assert hit.collides == (expected > 0), trial
        if hit.collides:
            assert hit.occupied_pixels == expected, trial
            collisions += 1
    assert 20 < collisions < 130  # both outcomes exercised


def test_sample_times_are_integer_steps_ending_at_the_horizon() -> None:
    t = safety_sample_times(line(1.0), cfg(sample_dt_s=0.3))
    assert len(t) == 8 and t[6] == 6 * 0.3 and t[-1] == 2.0
    assert len(safety_sample_times(line(1.0), cfg(sample_dt_s=0.5))) == 5


def test_verdict_counts_sum_the_refusals() -> None:
    c = VerdictCounts()
    for v in (SafetyVerdict.ACCEPTED, SafetyVerdict.VELOCITY_LIMIT, SafetyVerdict.COLLISION_IN_DEPTH):
        c.add(v)
    c.add(SafetyVerdict.COLLISION_IN_DEPTH)
    assert c.counts[SafetyVerdict.COLLISION_IN_DEPTH] == 2 and c.refused == 3


def test_depth_and_camera_sizes_must_agree() -> None:
    with pytest.raises(ValueError, match="depth image"):
        find_depth_collision(np.zeros((1, 3)), 0.25, 1, np.zeros((10, 10), np.float32), camera())


def test_depth_and_camera_sizes_must_agree_for_remembered_frames_too() -> None:
    bad = DepthFrame(1.0, np.zeros((10, 10), np.float32), camera())
    with pytest.raises(ValueError, match="remembered frame 1: depth image"):
        find_depth_collision(np.zeros((1, 3)), 0.25, 1, uniform(np.inf), camera(), [bad])
    with pytest.raises(ValueError, match="latest frame: depth image"):
        find_depth_collision(np.zeros((1, 3)), 0.25, 1, np.zeros((10, 10), np.float32), camera())


def yawed_camera(yaw_deg: float, position: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> CameraModel:
    """The default camera turned by yaw_deg about world z (left positive) and moved to position."""
    a = np.radians(yaw_deg)
    Rz = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    T = np.eye(4)
    T[:3, :3] = Rz @ np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], dtype=np.float64)
    T[:3, 3] = position
    return camera(T)


def test_a_remembered_frame_judges_samples_the_latest_frame_does_not_show() -> None:
    # Frame at t = 1 s looked along +x and saw a wall 3 m ahead; now the camera looks along +y (yawed 90 deg
    # left) into free space, so the plan along +x leaves the latest view at once.
    wall_ahead = DepthFrame(1.0, uniform(3.0), camera())
    latest = yawed_camera(90.0)
    free = uniform(np.inf)
    c = cfg()
    assert check_trajectory(line(2.0), VEHICLE, free, latest, c).accepted  # no memory: not judged
    r = check_trajectory(line(2.0), VEHICLE, free, latest, c, [wall_ahead])
    assert r.verdict == SafetyVerdict.COLLISION_IN_DEPTH, r.reason
    assert r.value == pytest.approx(1.45, abs=1e-9)  # the same sample as with the wall in the latest frame
    assert "of the remembered frame 1 (t = 1.000 s)" in r.reason
    hit = find_depth_collision(line(2.0).position(np.array([1.45])), 0.25, 1, free, latest, [wall_ahead])
    assert hit.collides and hit.frame == 1 and hit.frame_stamp_s == 1.0
    # The newest frame that shows the sample judges it: a newer frame looking along +x into free space wins.
    newer_free = DepthFrame(2.0, uniform(np.inf), camera())
    assert check_trajectory(line(2.0), VEHICLE, free, latest, c, [newer_free, wall_ahead]).accepted
    # A frame that does not show the samples (looking along -x) does not judge them.
    behind = DepthFrame(2.0, uniform(0.5), yawed_camera(180.0))
    r = check_trajectory(line(2.0), VEHICLE, free, latest, c, [behind, wall_ahead])
    assert "remembered frame 2 (t = 1.000 s)" in r.reason


def test_the_latest_frame_judges_what_it_shows_and_the_memory_leaves_it_alone() -> None:
    # The latest frame looks along +x and sees the wall: refused by it, with the same words as without memory.
    old_free = DepthFrame(1.0, uniform(np.inf), camera())
    without = check(line(2.0), uniform(3.0))
    with_mem = check_trajectory(line(2.0), VEHICLE, uniform(3.0), camera(), cfg(), [old_free])
    assert with_mem == without and "remembered" not in with_mem.reason
    # A sample inside the sphere around a remembered camera (where the vehicle was) is free in that frame.
    wall_at_old_camera = DepthFrame(1.0, uniform(0.01), yawed_camera(0.0, (2.9, 0.0, 0.0)))
    mem = [wall_at_old_camera]
    near, far = np.array([[3.0, 0.0, 0.0]]), np.array([[3.5, 0.0, 0.0]])  # 0.1 m and 0.6 m before it
    assert not find_depth_collision(near, 0.25, 1, uniform(np.inf), yawed_camera(90.0), mem).collides
    assert find_depth_collision(far, 0.25, 1, uniform(np.inf), yawed_camera(90.0), mem).frame == 1


def test_trajectory_in_view_counts_samples_a_remembered_frame_shows() -> None:
    c = cfg()
    latest = yawed_camera(90.0)
    assert not trajectory_in_view(line(2.0), latest, c)
    assert trajectory_in_view(line(2.0), latest, c, [DepthFrame(1.0, uniform(np.inf), camera())])
    assert not trajectory_in_view(
        line(2.0), latest, c, [DepthFrame(1.0, uniform(np.inf), yawed_camera(180.0))]
    )


def test_depth_memory_keeps_frames_spaced_newest_first_and_forgets_when_time_goes_back() -> None:
    m = DepthMemory(3, 0.2)
    d = uniform(5.0)
    assert m.add(1.0, d, camera())
    assert not m.add(1.1, d, camera())  # too soon after the newest kept
    assert m.add(1.2, d, camera()) and m.add(1.45, d, camera()) and m.add(1.7, d, camera())
    assert [f.stamp_s for f in m.frames] == [1.7, 1.45, 1.2]  # at most 3, the oldest dropped
    d[0, 0] = 1.0
    assert m.frames[0].depth_m[0, 0] == 5.0  # a copy, not the caller's buffer
    assert m.add(0.5, d, camera())  # time went back (a new episode): the memory starts again
    assert [f.stamp_s for f in m.frames] == [0.5]
    m.clear()
    assert m.frames == []
    off = DepthMemory(0, 0.2)
    assert not off.add(1.0, d, camera()) and off.frames == []


def test_bad_depth_memory_settings_are_refused_with_their_names() -> None:
    with pytest.raises(ValueError, match="memory_frames must be >= 0"):
        DepthMemory(-1, 0.2)
    with pytest.raises(ValueError, match="memory_spacing_s finite"):
        DepthMemory(2, float("nan"))
    with pytest.raises(ValueError, match="memory_frames"):
        cfg(memory_frames=65)
    with pytest.raises(ValueError, match="memory_spacing_s"):
        cfg(memory_spacing_s=-0.1)
    before_the_memory = cfg().model_dump(exclude={"memory_frames", "memory_spacing_s"})
    with pytest.raises(ValueError, match="memory_frames"):
        SafetyConfig(
            **before_the_memory
        )  # required: a config written before the memory names the missing key


def test_the_rest_of_a_plan_is_judged_from_now_on_with_the_recovery_test() -> None:
    """As the C++ RestIsClear test: the line flown from t = 5 s, judged at 5.3 s (0.45 m along)."""
    plan = line(1.5)
    c = cfg(check_horizon_s=1.0)
    there = np.array([-0.1 + 1.5 * 0.3, 0.0, 0.0])
    free = uniform(np.inf)
    assert rest_is_clear(plan, 5.3, 1.0, there, free, camera(), c)
    # too little left, not started yet, the vehicle far from the plan, a non-finite time
    assert not rest_is_clear(plan, 6.2, 1.0, there, free, camera(), c)
    assert not rest_is_clear(plan, 4.9, 1.0, there, free, camera(), c)
    assert not rest_is_clear(plan, 5.3, 1.0, there + [0.0, 1.1, 0.0], free, camera(), c)
    assert not rest_is_clear(plan, float("nan"), 1.0, there, free, camera(), c)
    # a wall 1.2 m ahead is in the next second's way; one 2.4 m ahead is not (the whole plan would reach it)
    assert not rest_is_clear(plan, 5.3, 1.0, there, uniform(1.2), camera(), c)
    assert rest_is_clear(plan, 5.3, 1.0, there, uniform(2.4), camera(), c)
    assert not check_trajectory(plan, VEHICLE, uniform(2.4), camera(), cfg()).accepted
    # leaving the view: the line turned 60 deg left of the camera's axis
    d = plan.ctrl_world[:, 0] + 0.1
    turned = UniformBspline(
        5.0, plan.knot_dt_s, np.column_stack([-0.1 + 0.5 * d, np.sqrt(3.0) / 2.0 * d, np.zeros(10)])
    )
    assert not rest_is_clear(turned, 5.3, 1.0, turned.position(0.3)[0], free, camera(), c)
    # with the safety layer off only time and place count
    assert rest_is_clear(
        plan, 5.3, 1.0, there, uniform(1.2), camera(), cfg(check_horizon_s=1.0, enabled=False)
    )
