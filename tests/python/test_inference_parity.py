"""Parity of the two forward passes, and the bound decider's decisions (issue 31: inference exists once, in
C++; the network's preprocessing and forward pass exist twice, LibTorch in the C++ node and torch in the
Python node, so that their latencies can be compared).

The same recorded inputs go through `policy_replay` (the C++ node's pipeline: PreprocessDepth, EncodeState,
TorchPolicy, PolicyDecider) and through the Python node's (LoadedPolicy's preprocessing and forward pass, then
the bound C++ decider, quad_policy_py). The depth input must be bit-identical (and equal the file's own
preprocessing), the state vector within 1e-6, the network output within 1e-4, and the decisions the same:
what is sent, the verdict, the recovery, the control points (within 1e-4) and the words. The recorded inputs
are synthetic depth frames (quad_il.learning.synthetic) with REP 118 specials, odometry and goals, in the
on-disk layout both languages read. Skipped when quad_policy is not built and sourced."""

from __future__ import annotations

import dataclasses
import subprocess
from pathlib import Path

import numpy as np
import pytest

from quad_il.inference.config import load_policy_config
from quad_il.inference.core import (
    VERDICT_LABELS,
    PolicyDecider,
    UniformBspline,
    check_trajectory,
    trajectory_in_view,
)
from quad_il.inference.fixture import DecisionFixture, write_fixture
from quad_il.inference.policy import LoadedPolicy
from quad_il.inference.random_policy import (
    export_goal_fan_policy,
    export_goal_line_policy,
    export_random_policy,
)
from quad_il.learning.config import ModelConfig
from quad_il.learning.synthetic import make_synthetic_arrays
from quad_il.tools.binaries import find_binary

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "config" / "policy.yaml"
TOL = 1e-4  # the parity tolerance on the output
try:
    REPLAY: Path | None = Path(find_binary("quad_policy", "policy_replay"))
except Exception:  # noqa: BLE001 - not built: skipped below
    REPLAY = None
pytestmark = pytest.mark.skipif(REPLAY is None, reason="policy_replay is not built (source scripts/env.sh)")

H, W = 60, 80
# Fast-Planner's field of view at 80 x 60; optical frame looking along base_link +x, 0.1 m ahead.
CAMERA_K = np.array([387.2 * W / 640, 387.2 * H / 480, (W - 1) / 2, (H - 1) / 2])
T_BODY_CAMERA = np.array([[0, 0, 1, 0.1], [-1, 0, 0, 0], [0, -1, 0, 0], [0, 0, 0, 1]], dtype=np.float64)


def replay(
    policy: Path, fixture_dir: Path, config: Path, out: Path, trajectories: Path | None = None
) -> dict:
    """policy_replay (the C++ pipeline) over a fixture; its .npy outputs by name and `reason` (per frame)."""
    cmd = [str(REPLAY), "--policy", str(policy), "--fixture", str(fixture_dir), "--config", str(config)]
    cmd += ["--out", str(out)] + (["--trajectories", str(trajectories)] if trajectories else [])
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    outputs = {p.stem: np.load(p) for p in out.glob("*.npy")}
    outputs["reason"] = (out / "reason.txt").read_text().splitlines()
    return outputs


@dataclasses.dataclass
class PyRun:
    """The Python node's pipeline over a fixture: its inputs to the network, outputs and decisions."""

    depth_x: np.ndarray
    state_x: np.ndarray
    y: np.ndarray
    decisions: list


def decide_in_python(policy: LoadedPolicy, fx: DecisionFixture, config: Path) -> PyRun:
    cfg = load_policy_config(config)
    decider = PolicyDecider(policy.meta, cfg.safety, cfg.refusal, cfg.recovery, cfg.keeping)
    depth_x, state_x, y, decisions = [], [], [], []
    for i in range(len(fx)):
        p, v, q, g = fx.p_world_body[i], fx.v_world[i], fx.q_world_body[i], fx.goal_world[i]
        x = policy.preprocess_depth(fx.depth_m[i])
        s, out = policy.network_output(x, p, v, q, g)
        depth_x.append(x[0, 0].numpy())
        state_x.append(s)
        y.append(out)
        d, _, _ = policy.decide(decider, float(fx.stamp_s[i]), fx.depth_m[i], fx.camera(i), p, v, q, g)
        decisions.append(d)
    return PyRun(np.stack(depth_x), np.stack(state_x), np.stack(y), decisions)


def assert_same_decisions(cpp: dict, py: PyRun, fx: DecisionFixture, hypotheses: int) -> None:
    """The bound decider on Python's forward pass decides as policy_replay on LibTorch's."""
    ds = py.decisions
    np.testing.assert_array_equal(cpp["sent_kind"], [d.sent_kind for d in ds])
    np.testing.assert_array_equal(cpp["verdict"], [d.safety.verdict for d in ds])
    np.testing.assert_array_equal(cpp["proposed_hypothesis"], [d.proposed_hypothesis for d in ds])
    np.testing.assert_array_equal(cpp["recovery_tries"], [d.recovery_tries for d in ds])
    np.testing.assert_array_equal(cpp["recovery_hypothesis"], [d.recovery_hypothesis for d in ds])
    yaws = [d.recovery_yaw_deg if d.recovery is not None else np.nan for d in ds]
    np.testing.assert_array_equal(cpp["recovery_yaw_deg"], yaws)
    np.testing.assert_allclose(
        cpp["ctrl_world"], np.stack([d.proposed.ctrl_world for d in ds]), rtol=0, atol=TOL
    )
    for i, d in enumerate(ds):
        for name, traj in [("recovery", d.recovery), ("stop", d.stop), ("final", d.final_approach)]:
            if traj is not None:
                np.testing.assert_allclose(cpp[f"{name}_ctrl"][i], traj.ctrl_world, rtol=0, atol=TOL)
        # The words: the verdict's name and everything after it (the numbers of a refusal may differ in their
        # last printed digit with outputs 1e-6 apart).
        words = d.summary(hypotheses, float(fx.stamp_s[i])).reason
        assert cpp["reason"][i].split(":")[0] == words.split(":")[0], (cpp["reason"][i], words)
        assert cpp["reason"][i].split(";")[1:] == words.split(";")[1:], (cpp["reason"][i], words)


def recorded_inputs(directory: Path) -> DecisionFixture:
    a = make_synthetic_arrays(num_episodes=2, samples_per_episode=4, height=H, width=W, seed=7)
    depth = a["depth_m"].astype(np.float32)
    rng = np.random.default_rng(3)
    for value in (-np.inf, np.nan, np.inf):  # REP 118 specials on every frame: too near, invalid, no return
        depth[rng.random(depth.shape) < 0.02] = value
    depth[0] = np.inf  # frame 0 sees nothing (every trajectory is collision-free there)
    depth[5] = 2.0  # frame 5 a wall at 2 m
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


def designed_trajectories(fx: DecisionFixture, k: int, dt: float) -> np.ndarray:
    """One trajectory per frame from its odometry, so that the frames cover every verdict: straight ahead at
    1.5 m/s (accepted in frame 0), NaN, 9 m/s, a 0.3 m zigzag, 3 m off the vehicle, into the wall of frame 5,
    then two more straight lines."""
    out = np.empty((len(fx), k, 3))
    for i in range(len(fx)):
        x, y, z, w = fx.q_world_body[i]
        yaw = np.arctan2(2 * (w * z + x * y), w * w + x * x - y * y - z * z)
        ahead, side = np.array([np.cos(yaw), np.sin(yaw), 0.0]), np.array([-np.sin(yaw), np.cos(yaw), 0.0])
        tau = (np.arange(k) - 1.0) * dt
        c = fx.p_world_body[i] + (9.0 if i == 2 else 1.5) * tau[:, None] * ahead
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
    return d, recorded_inputs(d)


POLICIES = {
    # The thesis's frames (world state, world B-spline output); the file encodes the state (forward_prepared).
    "world_bspline": (ModelConfig(input_height=32, input_width=48), False),
    # Local state and output, polynomial output, and the network-only entry forward_net.
    "local_polynomial_forward_net": (
        ModelConfig(
            input_height=40, input_width=40, state_frame="local", output_frame="local", output="polynomial",
            poly_degree=5,
        ),
        True,
    ),
    # Three hypotheses: the most confident is proposed, the others feed the recovery.
    "local_bspline_hypotheses": (
        ModelConfig(input_height=32, input_width=32, state_frame="local", output_frame="local", hypotheses=3),
        False,
    ),
    "local_bspline_mean_first": (
        ModelConfig(
            input_height=32, input_width=32, state_frame="local", output_frame="local", hypotheses=3,
            hypotheses_first="mean",
        ),
        False,
    ),
    # Plans that continue the vehicle's motion (output prior): they reach surfaces, so the recovery searches.
    "local_bspline_cv_prior": (
        ModelConfig(
            input_height=32, input_width=32, state_frame="local", output_frame="local",
            output_prior="constant_velocity",
        ),
        False,
    ),
}  # fmt: skip


@pytest.fixture(scope="module", params=sorted(POLICIES))
def run_both(request: pytest.FixtureRequest, recorded, tmp_path_factory):
    fixture_dir, fx = recorded
    model_cfg, forward_net = POLICIES[request.param]
    work = tmp_path_factory.mktemp(request.param)
    path = export_random_policy(work / "policy.ts", model_cfg, 10, 2.0, seed=5, forward_net=forward_net)
    policy = LoadedPolicy(path)
    trajs = designed_trajectories(fx, 10, policy.meta.knot_dt_s)
    np.save(work / "trajectories.npy", trajs)
    # The repository's default config: recovery, final approach, keeping.
    cpp = replay(path, fixture_dir, CONFIG, work / "cpp", work / "trajectories.npy")
    return request.param, policy, fx, cpp, decide_in_python(policy, fx, CONFIG), trajs


def test_both_languages_use_the_same_network_entry(run_both) -> None:
    name, policy, _, cpp, _, _ = run_both
    assert bool(cpp["has_forward_net"][0]) == policy.has_forward_net == name.endswith("forward_net")


def test_depth_input_is_bit_identical_in_cpp_python_and_the_file(run_both) -> None:
    _, _, _, cpp, py, _ = run_both
    assert cpp["depth_x"].dtype == np.float32
    np.testing.assert_array_equal(cpp["depth_x"], cpp["file_depth_x"])
    np.testing.assert_array_equal(cpp["depth_x"], py.depth_x)
    assert np.all(py.depth_x[0] == 1.0)  # frame 0 (no return anywhere) maps to 1 everywhere
    assert py.depth_x[1:].min() < 0.5


def test_state_vectors_and_network_outputs_agree(run_both) -> None:
    _, _, _, cpp, py, _ = run_both
    np.testing.assert_allclose(cpp["state_x"], py.state_x, rtol=0, atol=1e-6)
    np.testing.assert_allclose(cpp["y"], py.y, rtol=0, atol=TOL)
    # C++'s decoding of its output equals the file's decode, and the whole pipeline the file's forward.
    np.testing.assert_allclose(cpp["ctrl_world"], cpp["file_decode"], rtol=0, atol=TOL)
    np.testing.assert_allclose(cpp["ctrl_world"], cpp["file_forward"], rtol=0, atol=TOL)


def test_the_bound_decider_on_pythons_forward_pass_decides_as_the_cpp_node(run_both) -> None:
    name, policy, fx, cpp, py, _ = run_both
    assert_same_decisions(cpp, py, fx, policy.meta.hypotheses)
    np.testing.assert_allclose(cpp["knots"], py.decisions[0].proposed.knots(), rtol=0, atol=1e-12)
    assert cpp["knots"][3] == 0.0 and len(cpp["knots"]) == policy.meta.num_ctrl_pts + 4
    if name == "local_bspline_cv_prior":
        assert any(d.recovery_tries > 0 for d in py.decisions)  # the recovery searched
    if name == "local_bspline_mean_first":
        assert not cpp["proposed_hypothesis"].any()


def test_the_bound_safety_layer_judges_as_policy_replay_for_every_refusal_reason(run_both) -> None:
    _, policy, fx, cpp, _, trajs = run_both
    cfg = load_policy_config(CONFIG).safety
    verdicts, values, in_view = [], [], []
    for i in range(len(fx)):
        traj = UniformBspline(float(fx.stamp_s[i]), policy.meta.knot_dt_s, trajs[i])
        r = check_trajectory(traj, fx.p_world_body[i], fx.depth_m[i], fx.camera(i), cfg)
        verdicts.append(r.verdict)
        values.append(r.value)
        in_view.append(int(trajectory_in_view(traj, fx.camera(i), cfg)))
    np.testing.assert_array_equal(cpp["traj_verdict"], verdicts)
    np.testing.assert_allclose(cpp["traj_value"], values, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(cpp["traj_in_view"], in_view)
    assert set(in_view) == {0, 1}, in_view
    assert set(verdicts) == set(range(len(VERDICT_LABELS))), verdicts


def hover_scene(tmp_path: Path, depth: np.ndarray, goals: np.ndarray, overlay: str, v=None) -> tuple:
    """Frames 0.1 s apart seen by a vehicle hovering at (0, 0, 1.5) facing +x, one goal per frame, and an
    overlay of config/policy.yaml with the given keys; both written under tmp_path."""
    n = len(depth)
    fx = DecisionFixture(
        depth_m=depth,
        stamp_s=1.0 + 0.1 * np.arange(n),
        p_world_body=np.tile([0.0, 0.0, 1.5], (n, 1)),
        v_world=np.zeros((n, 3)) if v is None else np.tile(v, (n, 1)),
        q_world_body=np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)),
        goal_world=np.asarray(goals, dtype=np.float64),
        camera_k=CAMERA_K,
        T_body_camera=T_BODY_CAMERA,
    )
    write_fixture(tmp_path / "fx", fx)
    config = tmp_path / "policy.yaml"
    config.write_text(f"overlay_of: {CONFIG}\n{overlay}")
    return fx, config


def scene(tmp_path: Path, policy_path: Path, depth: np.ndarray, goals, overlay: str, v=None) -> tuple:
    """Both pipelines over a hover scene; they must decide alike. (cpp outputs, Python decisions)."""
    fx, config = hover_scene(tmp_path, depth, goals, overlay, v)
    cpp = replay(policy_path, tmp_path / "fx", config, tmp_path / "cpp")
    policy = LoadedPolicy(policy_path)
    py = decide_in_python(policy, fx, config)
    assert_same_decisions(cpp, py, fx, policy.meta.hypotheses)
    return cpp, py.decisions


def plain(turns: str = "[]", final_m: float = 0.0, commit_s: float = 0.0, on_refusal: str = "false") -> str:
    """An overlay of config/policy.yaml as config/policy_plain.yaml (a decision per frame, no recovery, final
    approach or keeping, a 0.25 m sphere) with the behaviours a scene turns on."""
    return (
        f"replan_rate_hz: 0.0\nrecovery:\n  goal_yaw_offsets_deg: {turns}\n  final_approach_m: {final_m}\n"
        f"keeping:\n  commit_s: {commit_s}\n  on_refusal: {on_refusal}\nsafety:\n  vehicle_radius_m: 0.25\n"
    )


def test_the_recovery_asks_pythons_network_with_turned_goals(tmp_path: Path) -> None:
    """The goal-line double flies straight at the (turned) goal at 1.5 m/s. Frames: nothing seen (accepted);
    a wall 1.2 m ahead (refused, recovered with the goal turned 20 deg: 60 deg leaves the image, 10 deg still
    hits the wall); a wall across the view (every turn refused: the stopping trajectory)."""
    depth = np.full((3, H, W), np.inf, np.float32)
    depth[1][:, 35:45] = 1.2
    depth[2][:] = 1.2
    overlay = plain(turns="[60.0, 10.0, 20.0, -20.0]")
    policy = export_goal_line_policy(tmp_path / "goal_line.ts")
    cpp, py = scene(tmp_path, policy, depth, np.tile([10.0, 0.0, 1.5], (3, 1)), overlay)
    assert [d.sent_kind for d in py] == [1, 3, 2]
    assert [d.recovery_tries for d in py] == [0, 3, 4]
    np.testing.assert_array_equal(cpp["recovery_yaw_deg"], [np.nan, 20.0, np.nan])
    heading = py[1].recovery.position([1.0])[0] - np.array([0.0, 0.0, 1.5])
    assert np.degrees(np.arctan2(heading[1], heading[0])) == pytest.approx(20.0, abs=1e-3)


def test_a_refused_plan_is_replaced_by_another_hypothesis(tmp_path: Path) -> None:
    """The goal-fan double: lines towards the goal turned by 0, +20 and -20 deg with logits 0.5, 1.0, 0.0.
    A wall on the left half of the view refuses +20 deg and the straight line; -20 deg is sent."""
    depth = np.full((3, H, W), np.inf, np.float32)
    depth[1][:, : W // 2 + 8] = 1.2
    depth[2][:] = 1.2
    overlay = plain(turns="[40.0, -40.0]")
    policy = export_goal_fan_policy(tmp_path / "goal_fan.ts", [0.0, 20.0, -20.0], [0.5, 1.0, 0.0])
    cpp, py = scene(tmp_path, policy, depth, np.tile([10.0, 0.0, 1.5], (3, 1)), overlay)
    assert [d.sent_kind for d in py] == [1, 3, 2]
    assert [d.proposed_hypothesis for d in py] == [1, 1, 1]
    assert [d.recovery_hypothesis for d in py] == [-1, 2, -1]
    assert [d.recovery_tries for d in py] == [0, 0, 2]


def test_the_final_approach_is_flown_only_near_the_goal_and_when_clear(tmp_path: Path) -> None:
    """final_approach_m 1.5, moving at (1, 0.2, -0.1) m/s. Frames: the goal 1.2 m ahead (the final approach);
    behind a wall 0.9 m ahead (refused: the stopping trajectory); 1.8 m ahead (the network's plan)."""
    depth = np.full((3, H, W), np.inf, np.float32)
    depth[1][:, 30:50] = 0.9
    goals = np.array([[1.2, 0.0, 1.5], [1.2, 0.0, 1.5], [1.8, 0.0, 1.5]])
    overlay = plain(final_m=1.5)
    policy = export_goal_line_policy(tmp_path / "goal_line.ts")
    _, py = scene(tmp_path, policy, depth, goals, overlay, v=[1.0, 0.2, -0.1])
    assert [d.sent_kind for d in py] == [5, 2, 1]
    end = py[0].final_approach
    np.testing.assert_allclose(end.position([end.duration_s])[0], goals[0], atol=1e-9)


def test_keeping_flies_the_plan_sent_before_on_a_refusal_and_while_committed(tmp_path: Path) -> None:
    """on_refusal: frames 1-2 see a wall on the left with the goal turned into it: the proposal is refused and
    frame 0's plan still passes, so it is kept; frame 3's wider wall blocks it too: stop. commit_s 0.25: frame
    0's plan is committed to in frames 1-2, replaced in frame 3."""
    n = 5
    depth = np.full((n, H, W), np.inf, np.float32)
    depth[1][:, :25] = depth[2][:, :25] = 1.0
    depth[3][:, :30] = 1.0
    turned = [10.0 * np.cos(np.radians(25.0)), 10.0 * np.sin(np.radians(25.0)), 1.5]
    goals = np.array([[10.0, 0.0, 1.5], turned, turned, turned, turned])
    policy = export_goal_line_policy(tmp_path / "goal_line.ts")
    _, py = scene(tmp_path / "on", policy, depth, goals, plain(on_refusal="true"))
    assert [d.sent_kind for d in py] == [1, 6, 6, 2, 1]
    _, py = scene(tmp_path / "off", policy, depth, goals, plain())
    assert [d.sent_kind for d in py] == [1, 2, 2, 2, 1]
    free = np.full((4, H, W), np.inf, np.float32)
    _, py = scene(tmp_path / "commit", policy, free, np.tile([10.0, 0.0, 1.5], (4, 1)), plain(commit_s=0.25))
    assert [d.sent_kind for d in py] == [1, 7, 7, 1]
    assert "committed to the plan sent 0.10 s before" in py[1].summary(1, 1.1).reason


def test_given_the_cpp_network_output_the_bound_decider_is_bit_identical_to_policy_replay(run_both) -> None:
    """The same decider behind both entries: fed LibTorch's output, the bound decider reproduces
    policy_replay's decisions exactly (the recovery's turned goals still ask Python's network)."""
    _, policy, fx, cpp, _, _ = run_both
    cfg = load_policy_config(CONFIG)
    decider = PolicyDecider(policy.meta, cfg.safety, cfg.refusal, cfg.recovery, cfg.keeping)
    for i in range(len(fx)):
        p, v, q, g = fx.p_world_body[i], fx.v_world[i], fx.q_world_body[i], fx.goal_world[i]
        x = policy.preprocess_depth(fx.depth_m[i])
        d = decider.decide(
            float(fx.stamp_s[i]), fx.depth_m[i], fx.camera(i), p, v, q, g, cpp["y"][i],
            lambda turned, x=x, p=p, v=v, q=q: policy.network_output(x, p, v, q, turned)[1],
        )  # fmt: skip
        assert d.sent_kind == cpp["sent_kind"][i] and d.safety.verdict == cpp["verdict"][i]
        np.testing.assert_array_equal(d.proposed.ctrl_world, cpp["ctrl_world"][i])
        assert d.summary(policy.meta.hypotheses, float(fx.stamp_s[i])).reason == cpp["reason"][i]
        if d.stop is not None:
            np.testing.assert_array_equal(d.stop.ctrl_world, cpp["stop_ctrl"][i])
