"""Parity of the C++ and the Python inference pipelines (issue 8): the same recorded inputs go through the C++
decider (`policy_replay`, what policy_node runs) and the Python decider (what policy_node.py runs); every
intermediate result and the output must agree, and both must agree with the exported file's own methods.

The recorded inputs are a small fixture written here: synthetic depth frames (quad_il.learning.synthetic)
with REP 118 specials, odometry and goal, in the on-disk layout both languages read. Skipped when quad_policy
is not built and sourced.
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

from quad_il.inference.config import load_policy_config
from quad_il.inference.decider import PolicyDecider, fixture_inputs
from quad_il.inference.fixture import DecisionFixture, write_fixture
from quad_il.inference.policy import LoadedPolicy
from quad_il.inference.random_policy import (
    export_goal_fan_policy,
    export_goal_line_policy,
    export_random_policy,
)
from quad_il.inference.safety import SafetyVerdict, check_trajectory, trajectory_in_view
from quad_il.learning.config import ModelConfig
from quad_il.learning.synthetic import make_synthetic_arrays

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "config" / "policy.yaml"
TOL = 1e-4  # the parity tolerance on the output
RECOVERY_TURNS = [30.0, -30.0, 60.0, -60.0]
STEER_CLEARANCE_M = 1.0


def _find_tool(name: str) -> Path | None:
    for prefix in os.environ.get("CMAKE_PREFIX_PATH", "").split(os.pathsep):
        candidate = Path(prefix) / "lib" / "quad_policy" / name
        if prefix and candidate.is_file():
            return candidate
    return None


REPLAY = _find_tool("policy_replay")
pytestmark = pytest.mark.skipif(REPLAY is None, reason="policy_replay is not built (source devel/setup.bash)")

H, W = 60, 80
# Fast-Planner's field of view at 80 x 60; optical frame looking along base_link +x, 0.1 m ahead.
CAMERA_K = np.array([387.2 * W / 640, 387.2 * H / 480, (W - 1) / 2, (H - 1) / 2])
T_BODY_CAMERA = np.array([[0, 0, 1, 0.1], [-1, 0, 0, 0], [0, -1, 0, 0], [0, 0, 0, 1]], dtype=np.float64)


def _replay(
    policy: Path, fixture_dir: Path, config: Path, out: Path, trajectories: Path | None = None
) -> dict[str, np.ndarray]:
    """policy_replay (the C++ decider) over a fixture; its .npy outputs by name."""
    cmd = [str(REPLAY), "--policy", str(policy), "--fixture", str(fixture_dir), "--config", str(config)]
    cmd += ["--out", str(out)] + (["--trajectories", str(trajectories)] if trajectories else [])
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    outputs = {p.stem: np.load(p) for p in out.glob("*.npy")}
    prefix = "[policy_replay] frame "
    reasons = [line.split(": ", 1)[1] for line in proc.stderr.splitlines() if line.startswith(prefix)]
    outputs["reason"] = np.array(reasons, dtype=object)  # the safety verdict's words, per frame
    return outputs


def _decide_all(decider: PolicyDecider, fx: DecisionFixture) -> list:
    return [decider.decide(fixture_inputs(fx, i)) for i in range(len(fx))]


def _sent_kinds(py: list) -> list[int]:
    """policy_replay's sent_kind of each Python decision."""
    return [
        ((7 if d.committed else 6) if d.kept is not None else 0)
        if d.to_send() is None
        else (
            5
            if d.final is not None
            else ((4 if d.steered else 3) if d.recovery is not None else (1 if d.accepted else 2))
        )
        for d in py
    ]


def _recorded_inputs(directory: Path) -> DecisionFixture:
    a = make_synthetic_arrays(num_episodes=2, samples_per_episode=4, height=H, width=W, seed=7)
    depth = a["depth_m"].astype(np.float32)
    rng = np.random.default_rng(3)
    # REP 118 specials scattered over every frame: too near, invalid, no return.
    for value in (-np.inf, np.nan, np.inf):
        mask = rng.random(depth.shape) < 0.02
        depth[mask] = value
    # Frame 0 sees nothing (every trajectory is collision-free there), frame 5 a wall at 2 m.
    depth[0] = np.inf
    depth[5] = 2.0
    fx = DecisionFixture(
        depth_m=depth,
        stamp_s=1.0 + a["depth_stamp_s"],
        p_world_body=a["p_world_body"].astype(np.float64),
        v_world=a["v_world"].astype(np.float64),
        q_world_body=a["q_world_body"].astype(np.float64),
        goal_world=a["goal_world"].astype(np.float64),
        camera_k=CAMERA_K,
        T_body_camera=T_BODY_CAMERA,
    )
    write_fixture(directory, fx)
    return fx


def _designed_trajectories(fx: DecisionFixture, k: int, dt: float) -> np.ndarray:
    """One trajectory per frame from its odometry, designed so that the frames cover every verdict: straight
    ahead at 1.5 m/s (accepted in frame 0), NaN, 9 m/s, a 0.3 m zigzag, 3 m off the vehicle, into the wall of
    frame 5, then two more straight lines."""
    out = np.empty((len(fx), k, 3))
    for i in range(len(fx)):
        x, y, z, w = fx.q_world_body[i]
        yaw = np.arctan2(2 * (w * z + x * y), w * w + x * x - y * y - z * z)
        ahead = np.array([np.cos(yaw), np.sin(yaw), 0.0])
        side = np.array([-np.sin(yaw), np.cos(yaw), 0.0])
        tau = (np.arange(k) - 1.0) * dt
        speed = 9.0 if i == 2 else 1.5
        c = fx.p_world_body[i] + speed * tau[:, None] * ahead
        if i == 1:
            c[4, 2] = np.nan
        if i == 3:
            c += 0.3 * ((-1.0) ** np.arange(k))[:, None] * side
        if i == 4:
            c += 3.0 * side
        out[i] = c
    return out


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, DecisionFixture]:
    d = tmp_path_factory.mktemp("recorded")
    return d, _recorded_inputs(d)


POLICIES = {
    # The thesis's frames (world state, world B-spline output); the file encodes the state (forward_prepared).
    "world_bspline": (ModelConfig(input_height=32, input_width=48), False),
    # Local state and output, polynomial output, and the network-only entry forward_net (the state vector of
    # each language is the network's input).
    "local_polynomial_forward_net": (
        ModelConfig(
            input_height=40,
            input_width=40,
            state_frame="local",
            output_frame="local",
            output="polynomial",
            poly_degree=5,
        ),
        True,
    ),
    # Three hypotheses: the decoded plan is the most confident one's; the others feed the recovery.
    "local_bspline_hypotheses": (
        ModelConfig(input_height=32, input_width=32, state_frame="local", output_frame="local", hypotheses=3),
        False,
    ),
    # The mean plan first, then the others by logit.
    "local_bspline_mean_first": (
        ModelConfig(
            input_height=32,
            input_width=32,
            state_frame="local",
            output_frame="local",
            hypotheses=3,
            hypotheses_first="mean",
        ),
        False,
    ),
    # Plans that continue the vehicle's motion (output prior): they reach surfaces, so the steering searches.
    "local_bspline_cv_prior": (
        ModelConfig(
            input_height=32,
            input_width=32,
            state_frame="local",
            output_frame="local",
            output_prior="constant_velocity",
        ),
        False,
    ),
}


@pytest.fixture(scope="module", params=sorted(POLICIES))
def run_both(request: pytest.FixtureRequest, recorded, tmp_path_factory):
    fixture_dir, fx = recorded
    model_cfg, forward_net = POLICIES[request.param]
    work = tmp_path_factory.mktemp(request.param)
    policy_path = export_random_policy(
        work / "policy.ts", model_cfg, 10, 2.0, seed=5, forward_net=forward_net
    )
    policy = LoadedPolicy(policy_path)
    trajs = _designed_trajectories(fx, 10, policy.meta.knot_dt_s)
    np.save(work / "trajectories.npy", trajs)
    # The repository's config with the recovery and the steering on, so both languages also run those loops.
    config = work / "policy.yaml"
    config.write_text(
        CONFIG.read_text()
        .replace("goal_yaw_offsets_deg: []", f"goal_yaw_offsets_deg: {RECOVERY_TURNS}")
        .replace("steer_clearance_m: 0.0", f"steer_clearance_m: {STEER_CLEARANCE_M}")
    )
    cpp = _replay(policy_path, fixture_dir, config, work / "cpp", work / "trajectories.npy")
    cfg = load_policy_config(config)
    assert cfg.recovery.goal_yaw_offsets_deg == RECOVERY_TURNS
    assert cfg.recovery.steer_clearance_m == STEER_CLEARANCE_M
    py = _decide_all(PolicyDecider(policy, cfg.safety, cfg.refusal, cfg.recovery), fx)
    return request.param, policy, fx, cpp, py, trajs, cfg


def test_both_languages_use_the_same_network_entry(run_both) -> None:
    name, policy, _, cpp, _, _, _ = run_both
    assert bool(cpp["has_forward_net"][0]) == policy.has_forward_net == name.endswith("forward_net")


def test_depth_input_is_bit_identical_in_cpp_python_and_the_file(run_both) -> None:
    _, _, fx, cpp, py, _, _ = run_both
    py_depth = np.stack([d.depth_x for d in py])
    assert cpp["depth_x"].dtype == np.float32
    np.testing.assert_array_equal(cpp["depth_x"], cpp["file_depth_x"])
    np.testing.assert_array_equal(cpp["depth_x"], py_depth)
    # Frame 0 (no return anywhere) maps to 1 everywhere; the others hold nearer values too.
    assert np.all(py_depth[0] == 1.0)
    assert py_depth[1:].min() < 0.5


def test_state_vectors_agree(run_both) -> None:
    _, _, _, cpp, py, _, _ = run_both
    np.testing.assert_allclose(cpp["state_x"], np.stack([d.state_x for d in py]), rtol=0, atol=1e-6)


def test_network_outputs_and_control_points_agree_within_the_tolerance(run_both) -> None:
    _, _, _, cpp, py, _, _ = run_both
    np.testing.assert_allclose(cpp["y"], np.stack([d.y for d in py]), rtol=0, atol=TOL)
    py_ctrl = np.stack([d.proposed.ctrl_world for d in py])
    np.testing.assert_allclose(cpp["ctrl_world"], py_ctrl, rtol=0, atol=TOL)
    # Each language's own decoding equals the file's decode of the same output, and the whole pipeline equals
    # the file's end-to-end forward on the raw inputs.
    np.testing.assert_allclose(cpp["ctrl_world"], cpp["file_decode"], rtol=0, atol=TOL)
    np.testing.assert_allclose(cpp["ctrl_world"], cpp["file_forward"], rtol=0, atol=TOL)
    np.testing.assert_allclose(py_ctrl, cpp["file_forward"], rtol=0, atol=TOL)


def test_trajectory_layout_and_decisions_agree(run_both) -> None:
    name, policy, _, cpp, py, _, _ = run_both
    np.testing.assert_allclose(cpp["knots"], py[0].proposed.knots(), rtol=0, atol=1e-12)
    assert cpp["knots"][3] == 0.0 and len(cpp["knots"]) == policy.meta.num_ctrl_pts + 4
    np.testing.assert_array_equal(cpp["verdict"], [int(d.safety.verdict) for d in py])
    np.testing.assert_array_equal(cpp["sent_kind"], _sent_kinds(py))
    # The recovery and the steering: as many turned goals asked, the same one taken, the same plan.
    np.testing.assert_array_equal(cpp["recovery_tries"], [d.recovery_tries for d in py])
    assert all(d.recovery_tries in (0, len(RECOVERY_TURNS)) or d.recovery for d in py)
    if name == "local_bspline_cv_prior":
        assert any(d.accepted and d.recovery_tries > 0 for d in py)  # the steering searched
    py_yaw = [np.nan if d.recovery_yaw_deg is None else d.recovery_yaw_deg for d in py]
    np.testing.assert_array_equal(cpp["recovery_yaw_deg"], py_yaw)
    np.testing.assert_array_equal(cpp["proposed_hypothesis"], [d.proposed_hypothesis for d in py])
    py_h = [-1 if d.recovery_hypothesis is None else d.recovery_hypothesis for d in py]
    np.testing.assert_array_equal(cpp["recovery_hypothesis"], py_h)
    if name in ("local_bspline_hypotheses", "local_bspline_mean_first"):
        assert cpp["y"].shape[1] == 3 * (30 + 1)  # every hypothesis and its logit
    if name == "local_bspline_mean_first":
        assert not cpp["proposed_hypothesis"].any()
    for i, d in enumerate(py):
        if d.recovery is not None:
            np.testing.assert_allclose(cpp["recovery_ctrl"][i], d.recovery.ctrl_world, rtol=0, atol=TOL)
    for i, d in enumerate(py):
        if d.stop is not None:
            np.testing.assert_allclose(cpp["stop_ctrl"][i], d.stop.ctrl_world, rtol=0, atol=1e-9)
            assert cpp["stop_knot_dt"][i] == pytest.approx(d.stop.knot_dt_s, abs=1e-12)


def test_safety_layer_verdicts_agree_for_every_refusal_reason(run_both) -> None:
    _, policy, fx, cpp, _, trajs, cfg = run_both
    from quad_il.inference.trajectory import UniformBspline

    py_verdicts, py_values = [], []
    for i in range(len(fx)):
        traj = UniformBspline(float(fx.stamp_s[i]), policy.meta.knot_dt_s, trajs[i])
        r = check_trajectory(traj, fx.p_world_body[i], fx.depth_m[i], fx.camera(i), cfg.safety)
        py_verdicts.append(int(r.verdict))
        py_values.append(r.value)
    np.testing.assert_array_equal(cpp["traj_verdict"], py_verdicts)
    py_in_view = [
        int(
            trajectory_in_view(
                UniformBspline(float(fx.stamp_s[i]), policy.meta.knot_dt_s, trajs[i]),
                fx.camera(i),
                cfg.safety,
            )
        )
        for i in range(len(fx))
    ]
    np.testing.assert_array_equal(cpp["traj_in_view"], py_in_view)
    # The designed set holds plans in view (straight ahead) and out of it (3 m to the side).
    assert set(py_in_view) == {0, 1}, py_in_view
    np.testing.assert_allclose(cpp["traj_value"], py_values, rtol=0, atol=1e-9)
    assert set(py_verdicts) == {int(v) for v in SafetyVerdict}, py_verdicts


def _hover_scene(
    tmp_path: Path,
    depth: np.ndarray,
    p: np.ndarray,
    q: np.ndarray,
    goals: np.ndarray,
    replace: dict[str, str],
) -> tuple[DecisionFixture, Path]:
    """A fixture of frames 0.1 s apart seen by a vehicle hovering at p with attitude q (x, y, z, w), one goal
    per frame, and config/policy.yaml with the given text replacements; both written under tmp_path."""
    n = len(depth)
    fx = DecisionFixture(
        depth_m=depth,
        stamp_s=1.0 + 0.1 * np.arange(n),
        p_world_body=np.tile(p, (n, 1)),
        v_world=np.zeros((n, 3)),
        q_world_body=np.tile(q, (n, 1)),
        goal_world=np.asarray(goals, dtype=np.float64),
        camera_k=CAMERA_K,
        T_body_camera=T_BODY_CAMERA,
    )
    write_fixture(tmp_path / "fx", fx)
    text = CONFIG.read_text()
    for old, new in replace.items():
        assert old in text, old
        text = text.replace(old, new)
    config = tmp_path / "policy.yaml"
    config.write_text(text)
    return fx, config


def test_recovery_and_steering_succeed_alike_with_a_goal_seeking_policy(tmp_path: Path) -> None:
    """Random networks never give a turned plan that passes; a goal-seeking test double does.

    The vehicle hovers at the origin facing +x, goal 10 m ahead; the double flies straight at the (turned)
    goal at 1.5 m/s. Frames: nothing seen (accepted); a wall 1.2 m ahead (refused, recovered with the goal
    turned 20 deg: 60 deg leaves the image, 10 deg still hits the wall); a narrow wall 2.2 m ahead (accepted
    but within the steering clearance: steered by 20 deg); the same wall at 2.0 m (no turn keeps it)."""
    policy_path = export_goal_line_policy(tmp_path / "goal_line.ts")
    n = 4
    depth = np.full((n, H, W), np.inf, np.float32)
    depth[1][:, 35:45] = 1.2
    depth[2][:, 35:45] = 2.2
    depth[3][:, 35:45] = 2.0
    fx, config = _hover_scene(
        tmp_path,
        depth,
        np.array([0.0, 0.0, 1.5]),
        np.array([0.0, 0.0, 0.0, 1.0]),
        np.tile([10.0, 0.0, 1.5], (n, 1)),
        {
            "goal_yaw_offsets_deg: []": "goal_yaw_offsets_deg: [60.0, 10.0, 20.0, -20.0]",
            "steer_clearance_m: 0.0": "steer_clearance_m: 0.9",
        },
    )
    cfg = load_policy_config(config)
    cpp = _replay(policy_path, tmp_path / "fx", config, tmp_path / "cpp")
    py = _decide_all(PolicyDecider(LoadedPolicy(policy_path), cfg.safety, cfg.refusal, cfg.recovery), fx)
    # The scenes do what they were built for (Python), and C++ decides the same.
    assert _sent_kinds(py) == [1, 3, 4, 1]
    assert [d.recovery_tries for d in py] == [0, 3, 3, 4]
    np.testing.assert_array_equal(cpp["sent_kind"], _sent_kinds(py))
    np.testing.assert_array_equal(cpp["recovery_tries"], [d.recovery_tries for d in py])
    np.testing.assert_array_equal(cpp["recovery_yaw_deg"], [np.nan, 20.0, 20.0, np.nan])
    for i in (1, 2):
        np.testing.assert_allclose(cpp["recovery_ctrl"][i], py[i].recovery.ctrl_world, rtol=0, atol=TOL)
        heading = py[i].recovery.position(np.array([1.0]))[0] - fx.p_world_body[i]
        assert np.degrees(np.arctan2(heading[1], heading[0])) == pytest.approx(20.0, abs=1e-3)


def test_a_refused_plan_is_replaced_by_another_hypothesis_alike_in_both_deciders(tmp_path: Path) -> None:
    """The goal-fan double: three hypotheses, lines towards the goal turned by 0, +20 and -20 deg, with logits
    0.5, 1.0, 0.0 (the +20 deg line is the most confident). The vehicle hovers at the origin facing +x, goal
    10 m ahead. Frames: nothing seen (the +20 deg plan is flown); a wall 1.2 m ahead on the left half of the
    view (+20 deg refused, the straight line too, -20 deg accepted: hypothesis 3 without a turned goal); the
    wall across the whole view (every hypothesis and every turned goal refused: the stopping trajectory)."""
    policy_path = export_goal_fan_policy(tmp_path / "goal_fan.ts", [0.0, 20.0, -20.0], [0.5, 1.0, 0.0])
    n = 3
    depth = np.full((n, H, W), np.inf, np.float32)
    depth[1][:, : W // 2 + 8] = 1.2  # the image's left half is the vehicle's left (+y)
    depth[2][:] = 1.2
    fx, config = _hover_scene(
        tmp_path,
        depth,
        np.array([0.0, 0.0, 1.5]),
        np.array([0.0, 0.0, 0.0, 1.0]),
        np.tile([10.0, 0.0, 1.5], (n, 1)),
        {"goal_yaw_offsets_deg: []": "goal_yaw_offsets_deg: [40.0, -40.0]"},
    )
    cfg = load_policy_config(config)
    cpp = _replay(policy_path, tmp_path / "fx", config, tmp_path / "cpp")
    py = _decide_all(PolicyDecider(LoadedPolicy(policy_path), cfg.safety, cfg.refusal, cfg.recovery), fx)
    assert _sent_kinds(py) == [1, 3, 2]
    assert [d.proposed_hypothesis for d in py] == [1, 1, 1]
    assert [d.recovery_hypothesis for d in py] == [None, 2, None]
    assert [d.recovery_tries for d in py] == [0, 0, 2]
    np.testing.assert_array_equal(cpp["sent_kind"], _sent_kinds(py))
    np.testing.assert_array_equal(cpp["proposed_hypothesis"], [1, 1, 1])
    np.testing.assert_array_equal(cpp["recovery_hypothesis"], [-1, 2, -1])
    np.testing.assert_array_equal(cpp["recovery_tries"], [0, 0, 2])
    np.testing.assert_array_equal(cpp["recovery_yaw_deg"], [np.nan, 0.0, np.nan])
    np.testing.assert_allclose(cpp["recovery_ctrl"][1], py[1].recovery.ctrl_world, rtol=0, atol=TOL)
    heading = py[1].recovery.position(np.array([1.0]))[0] - fx.p_world_body[1]
    assert np.degrees(np.arctan2(heading[1], heading[0])) == pytest.approx(-20.0, abs=1e-3)
    np.testing.assert_allclose(cpp["ctrl_world"], cpp["file_decode"], rtol=0, atol=TOL)


def test_the_final_approach_is_flown_alike_in_both_deciders(tmp_path: Path) -> None:
    """recovery.final_approach_m 1.5, the vehicle at the origin facing +x, moving at (1, 0.2, -0.1) m/s.
    Frames: the goal 1.2 m ahead, nothing seen (the final approach); the same goal behind a wall 0.9 m ahead
    (the approach refused: the goal-seeking double's plan is refused too, so the stopping trajectory); the
    goal 1.8 m ahead (beyond the distance: the network's plan); the goal 1.0 m ahead, 0.3 m left and 0.4 m up
    (the final approach)."""
    policy_path = export_goal_line_policy(tmp_path / "goal_line.ts")
    n = 4
    depth = np.full((n, H, W), np.inf, np.float32)
    depth[1][:, 30:50] = 0.9
    goals = np.array([[1.2, 0.0, 1.5], [1.2, 0.0, 1.5], [1.8, 0.0, 1.5], [1.0, 0.3, 1.9]])
    fx, config = _hover_scene(
        tmp_path,
        depth,
        np.array([0.0, 0.0, 1.5]),
        np.array([0.0, 0.0, 0.0, 1.0]),
        goals,
        {"final_approach_m: 0.0": "final_approach_m: 1.5"},
    )
    fx = dataclasses.replace(fx, v_world=np.tile([1.0, 0.2, -0.1], (n, 1)))
    write_fixture(tmp_path / "fx", fx)
    cfg = load_policy_config(config)
    cpp = _replay(policy_path, tmp_path / "fx", config, tmp_path / "cpp")
    py = _decide_all(PolicyDecider(LoadedPolicy(policy_path), cfg.safety, cfg.refusal, cfg.recovery), fx)
    assert _sent_kinds(py) == [5, 2, 1, 5]
    np.testing.assert_array_equal(cpp["sent_kind"], _sent_kinds(py))
    for i, d in enumerate(py):
        if d.final is None:
            np.testing.assert_array_equal(cpp["final_ctrl"][i], np.zeros((4, 3)))
            assert cpp["final_knot_dt"][i] == 0.0
            continue
        np.testing.assert_allclose(cpp["final_ctrl"][i], d.final.ctrl_world, rtol=0, atol=1e-9)
        assert cpp["final_knot_dt"][i] == pytest.approx(d.final.knot_dt_s, abs=1e-12)
        np.testing.assert_allclose(d.final.position(d.final.duration_s)[0], goals[i], atol=1e-9)


def test_turning_in_place_turns_alike_in_both_deciders(tmp_path: Path) -> None:
    """Turning in place depends on the decisions before (the stops in a row): both deciders, given the same
    frames in order, must turn on the same frames, the same way, with the same heading.

    Frames: a wall 1.2 m ahead with the goal a little to the right (four stops: the third and fourth turn
    right), nothing seen (accepted: the turning ends), the wall with the goal a little to the left (three
    stops: the third turns left), at a heading of 0.5 rad. The turning stops back away from the wall (turn
    clearance 2 m: 0.8 m)."""
    policy_path = export_goal_line_policy(tmp_path / "goal_line.ts")
    n = 8
    yaw = 0.5
    ahead = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    side = np.array([-np.sin(yaw), np.cos(yaw), 0.0])
    depth = np.full((n, H, W), np.inf, np.float32)
    for i in (0, 1, 2, 3, 5, 6, 7):
        depth[i][:, 30:50] = 1.2
    p = np.array([1.0, 2.0, 1.5])
    goal_side = [-1.5] * 5 + [1.5] * 3
    fx, config = _hover_scene(
        tmp_path,
        depth,
        p,
        np.array([0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2)]),
        np.array([p + 10.0 * ahead + s * side for s in goal_side]),
        {
            "turn_after_stops: 0": "turn_after_stops: 3",
            "turn_rate_dps: 45.0": "turn_rate_dps: 30.0",
            "turn_clearance_m: 0.8": "turn_clearance_m: 2.0",
        },
    )
    cfg = load_policy_config(config)
    cpp = _replay(policy_path, tmp_path / "fx", config, tmp_path / "cpp")
    py = _decide_all(PolicyDecider(LoadedPolicy(policy_path), cfg.safety, cfg.refusal, cfg.recovery), fx)
    rate = np.radians(30.0)
    assert _sent_kinds(py) == [2, 2, 2, 2, 1, 2, 2, 2]
    np.testing.assert_allclose([d.turn_rate_radps for d in py], [0, 0, -rate, -rate, 0, 0, 0, rate])
    np.testing.assert_array_equal(cpp["sent_kind"], _sent_kinds(py))
    np.testing.assert_allclose(cpp["turn_rate_radps"], [d.turn_rate_radps for d in py], rtol=0, atol=1e-12)
    for i, d in enumerate(py):
        expected = np.zeros(4) if d.stop is None or d.stop.yaw_ctrl is None else d.stop.yaw_ctrl
        np.testing.assert_allclose(cpp["stop_yaw"][i], expected, rtol=0, atol=1e-12)
        if d.stop is not None:
            np.testing.assert_allclose(cpp["stop_ctrl"][i], d.stop.ctrl_world, rtol=0, atol=1e-9)
            assert cpp["stop_knot_dt"][i] == pytest.approx(d.stop.knot_dt_s, abs=1e-12)
    # The turning stops back away from the wall 1.2 m ahead by 0.8 m, along the heading.
    np.testing.assert_allclose([d.turn_backoff_m for d in py], [0, 0, 0.8, 0.8, 0, 0, 0, 0.8], atol=1e-6)
    end = py[2].stop.position(py[2].stop.duration_s)[0]
    np.testing.assert_allclose(end, p - 0.8 * ahead, atol=1e-6)  # the depth frame is float32
    # The heading starts at the vehicle's.
    assert py[2].stop.yaw_ctrl[1] == pytest.approx(yaw, abs=1e-12)


def test_the_depth_memory_refuses_alike_in_both_deciders_what_only_an_earlier_frame_saw(
    tmp_path: Path,
) -> None:
    """The vehicle hovers at the origin; the goal is 10 m along +x, and the goal-seeking double flies straight
    at it. Frame 0 faces +x and sees a wall 1.2 m ahead (refused). Then the vehicle has turned to face +y
    and sees nothing: its plan along +x is out of view, so without memory it is accepted; with memory
    (spacing 0.2 s: frames 0 and 2 are kept) the frame that saw the wall refuses it, in both languages, with
    the same words (naming the remembered frame)."""
    policy_path = export_goal_line_policy(tmp_path / "goal_line.ts")
    n = 4
    depth = np.full((n, H, W), np.inf, np.float32)
    depth[0][:] = 1.2
    left = np.array([0.0, 0.0, np.sin(np.pi / 4), np.cos(np.pi / 4)])
    results = {}
    for frames in (0, 2):
        fx, config = _hover_scene(
            tmp_path / f"mem{frames}",
            depth,
            np.array([0.0, 0.0, 1.5]),
            np.array([0.0, 0.0, 0.0, 1.0]),
            np.tile([10.0, 0.0, 1.5], (n, 1)),
            {"memory_frames: 0": f"memory_frames: {frames}"},
        )
        fx = dataclasses.replace(
            fx, q_world_body=np.vstack([[0.0, 0.0, 0.0, 1.0], np.tile(left, (n - 1, 1))])
        )
        write_fixture(tmp_path / f"mem{frames}" / "fx", fx)
        cfg = load_policy_config(config)
        cpp = _replay(
            policy_path, tmp_path / f"mem{frames}" / "fx", config, tmp_path / f"mem{frames}" / "cpp"
        )
        decider = PolicyDecider(LoadedPolicy(policy_path), cfg.safety, cfg.refusal, cfg.recovery)
        py = _decide_all(decider, fx)
        np.testing.assert_array_equal(cpp["sent_kind"], _sent_kinds(py))
        np.testing.assert_array_equal(cpp["verdict"], [int(d.safety.verdict) for d in py])
        assert list(cpp["reason"]) == [d.safety.reason for d in py]
        assert [f.stamp_s for f in decider.memory.frames] == ([1.2, 1.0] if frames else [])
        decider.reset()  # a new episode forgets the frames
        assert decider.memory.frames == []
        results[frames] = py
    assert _sent_kinds(results[0]) == [2, 1, 1, 1]
    assert _sent_kinds(results[2]) == [2, 2, 2, 2]
    reasons = [d.safety.reason for d in results[2]]
    assert "remembered" not in reasons[0]
    assert all("of the remembered frame 1 (t = 1.000 s)" in r for r in reasons[1:3]), reasons
    assert "of the remembered frame 2 (t = 1.000 s)" in reasons[3], reasons


def _keeping_run(tmp_path: Path, name: str, depth: np.ndarray, goals: np.ndarray, replace: dict[str, str]):
    """The goal-line double over a hover scene (frames 0.1 s apart, vehicle at the origin facing +x) in both
    deciders with config/policy.yaml and the replacements; both sequences of sent kinds must agree, and the
    verdicts and their words. Returns the Python decisions."""
    policy_path = export_goal_line_policy(tmp_path / "goal_line.ts")
    fx, config = _hover_scene(
        tmp_path / name, depth, np.array([0.0, 0.0, 1.5]), np.array([0.0, 0.0, 0.0, 1.0]), goals, replace
    )
    cfg = load_policy_config(config)
    cpp = _replay(policy_path, tmp_path / name / "fx", config, tmp_path / name / "cpp")
    decider = PolicyDecider(LoadedPolicy(policy_path), cfg.safety, cfg.refusal, cfg.recovery, cfg.keeping)
    py = _decide_all(decider, fx)
    np.testing.assert_array_equal(cpp["sent_kind"], _sent_kinds(py))
    np.testing.assert_array_equal(cpp["verdict"], [int(d.safety.verdict) for d in py])
    assert list(cpp["reason"]) == [d.safety.reason for d in py]
    return py


def _left_wall(depth: np.ndarray, frame: int, columns: int) -> None:
    """A wall 1.0 m ahead filling the image's `columns` leftmost columns in `frame`."""
    depth[frame][:, :columns] = 1.0


def test_a_refused_decision_keeps_the_plan_sent_before_alike_in_both_deciders(tmp_path: Path) -> None:
    """keeping.on_refusal: frame 0 sees nothing (the plan straight ahead is sent); frames 1-2 see a wall on
    the left and the goal is turned 25 deg into it: the proposal is refused, the plan of frame 0 still passes
    the wall, so it is kept (nothing sent); frame 3's wider wall is in the way of that plan too: stop; frame
    4 sees nothing (sent). Off, the refusals stop at once."""
    n = 5
    depth = np.full((n, H, W), np.inf, np.float32)
    for f in (1, 2):
        _left_wall(depth, f, 25)
    _left_wall(depth, 3, 30)
    turned = [10.0 * np.cos(np.radians(25.0)), 10.0 * np.sin(np.radians(25.0)), 1.5]
    goals = np.array([[10.0, 0.0, 1.5], turned, turned, turned, turned])
    on = _keeping_run(tmp_path, "on", depth, goals, {"on_refusal: false": "on_refusal: true"})
    assert _sent_kinds(on) == [1, 6, 6, 2, 1]
    assert all(d.kept is on[0].proposed and not d.committed for d in on[1:3])
    assert [d.safety.verdict.label for d in on[1:4]] == ["collision_in_depth"] * 3
    off = _keeping_run(tmp_path, "off", depth, goals, {})
    assert _sent_kinds(off) == [1, 2, 2, 2, 1]


def test_a_committed_plan_is_flown_on_until_it_ends_or_its_rest_is_blocked(tmp_path: Path) -> None:
    """keeping.commit_s 0.25: the plan of frame 0 is committed to in frames 1-2 (0.1 and 0.2 s old; nothing
    sent), replaced in frame 3 (0.3 s); in frame 4 a wall blocks the rest of frame 3's plan, so the commitment
    ends and the refused proposal stops the vehicle; frame 5 sends again."""
    n = 6
    depth = np.full((n, H, W), np.inf, np.float32)
    _left_wall(depth, 4, 30)
    goals = np.tile([10.0, 0.0, 1.5], (n, 1))
    py = _keeping_run(tmp_path, "commit", depth, goals, {"commit_s: 0.0": "commit_s: 0.25"})
    assert _sent_kinds(py) == [1, 7, 7, 1, 2, 1]
    assert py[1].committed and py[1].kept is py[0].proposed and py[2].kept is py[0].proposed
    # The network is still asked on committed frames: the same proposal as without the commitment.
    free = _keeping_run(tmp_path, "free", depth, goals, {})
    assert _sent_kinds(free) == [1, 1, 1, 1, 2, 1]
    np.testing.assert_allclose(py[1].proposed.ctrl_world, free[1].proposed.ctrl_world)


def test_bspline_messages_carry_the_heading_only_when_the_trajectory_has_one() -> None:
    """The turning stop's yaw points go to the tracker on the position's knots; other trajectories carry none
    (the tracker then turns the vehicle along its direction of travel). Needs the built messages."""
    from quad_il.inference.messages import bspline_message
    from quad_il.inference.trajectory import braking_trajectory, turning_stop

    stop = braking_trajectory(np.zeros(3), np.array([1.0, 0, 0]), 3.0, 0.5, 2.0)
    msg = bspline_message(stop, 7)
    assert msg.yaw_pts == [] and msg.yaw_dt == 0.0 and len(msg.knots) == 8
    turn = turning_stop(np.zeros(3), np.zeros(3), np.array([-0.3, 0, 0]), 1.0, 0.5, 3.0, 0.5, 2.0)
    msg = bspline_message(turn, 8)
    np.testing.assert_array_equal(msg.yaw_pts, turn.yaw_ctrl)
    assert msg.yaw_dt == turn.knot_dt_s and msg.knots[3] == 0.0 and msg.traj_id == 8
