"""The Python inference components without ROS or the C++ build: preprocessing against the exported file,
both network entries, metadata and config errors, trajectories, the decider, fixtures."""

from __future__ import annotations

import copy
import dataclasses
import json
import re
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from quad_il.inference.config import (
    PolicyConfigError,
    RecoveryConfig,
    RefusalConfig,
    SafetyConfig,
    config_from_tree,
    load_policy_config,
)
from quad_il.inference.decider import Decision, DecisionInputs, PolicyDecider, turned_goal
from quad_il.inference.fixture import DecisionFixture, FixtureError, read_fixture, write_fixture
from quad_il.inference.geometry import yaw_of
from quad_il.inference.meta import PolicyFormatError, parse_policy_meta
from quad_il.inference.policy import LoadedPolicy, ordered_plans
from quad_il.inference.preprocessing import PolicyPreprocessing, as_row
from quad_il.inference.random_policy import export_random_policy
from quad_il.inference.safety import (
    CameraModel,
    SafetyResult,
    SafetyVerdict,
    nearest_depth,
    trajectory_in_view,
)
from quad_il.inference.trajectory import (
    UniformBspline,
    braking_trajectory,
    final_approach,
    turning_stop,
    with_constant_yaw_rate,
)
from quad_il.learning.config import ModelConfig
from quad_il.learning.export import META_FILE, load_exported

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "config" / "policy.yaml"


@pytest.fixture(scope="module")
def policies(tmp_path_factory: pytest.TempPathFactory) -> dict[str, LoadedPolicy]:
    d = tmp_path_factory.mktemp("policies")
    small = dict(input_height=32, input_width=32)
    return {
        "world": LoadedPolicy(export_random_policy(d / "w.ts", ModelConfig(**small), seed=1)),
        "world_h3": LoadedPolicy(
            export_random_policy(d / "h3.ts", ModelConfig(**small, hypotheses=3), seed=3)
        ),
        "local_poly_net": LoadedPolicy(
            export_random_policy(
                d / "l.ts",
                ModelConfig(**small, state_frame="local", output_frame="local", output="polynomial"),
                seed=2,
                forward_net=True,
            )
        ),
    }


def _inputs(seed: int, h: int = 50, w: int = 70) -> tuple[np.ndarray, list[torch.Tensor]]:
    rng = np.random.default_rng(seed)
    depth = rng.uniform(0.2, 14.0, (h, w)).astype(np.float32)
    depth[rng.random((h, w)) < 0.05] = np.inf
    depth[rng.random((h, w)) < 0.05] = -np.inf
    depth[rng.random((h, w)) < 0.05] = np.nan
    q = rng.normal(size=4)
    rows = [
        as_row(rng.uniform(-10, 10, 3), 3, "p"),
        as_row(rng.uniform(-2, 2, 3), 3, "v"),
        as_row(q / np.linalg.norm(q), 4, "q"),
        as_row(rng.uniform(-20, 20, 3), 3, "goal"),
    ]
    return depth, rows


@pytest.mark.parametrize("name", ["world", "local_poly_net"])
def test_python_preprocessing_and_decoding_equal_the_files_own(policies, name: str) -> None:
    policy = policies[name]
    pre = PolicyPreprocessing(policy.meta)
    for seed in range(3):
        depth, (p, v, q, g) = _inputs(seed)
        x = pre.depth(depth)
        np.testing.assert_array_equal(x[0, 0].numpy(), policy.file_preprocess_depth(depth))
        y = policy.run(x, pre.state(p, v, q, g), p, v, q, g)
        np.testing.assert_allclose(pre.decode(y, p, q), policy.file_decode(y, p, q), rtol=0, atol=1e-5)
        np.testing.assert_allclose(
            pre.decode(y, p, q), policy.file_forward(depth, p, v, q, g), rtol=0, atol=1e-4
        )


def test_the_network_entry_and_the_files_state_encoding_give_the_same_output(policies) -> None:
    policy = policies["local_poly_net"]
    assert policy.has_forward_net and not policies["world"].has_forward_net
    pre = PolicyPreprocessing(policy.meta)
    depth, (p, v, q, g) = _inputs(5)
    x = pre.depth(depth)
    with torch.inference_mode():
        via_net = policy.module.forward_net(x, pre.state(p, v, q, g))
        via_file = policy.module.forward_prepared(x, p, v, q, g)
    torch.testing.assert_close(via_net, via_file, rtol=0, atol=1e-6)


def test_metadata_errors_name_the_key(policies) -> None:
    meta = copy.deepcopy(policies["world"].raw_meta)
    parse_policy_meta(meta, "p.ts")
    bad = copy.deepcopy(meta)
    bad["output"]["network_representation"] = "spline"
    with pytest.raises(PolicyFormatError, match="'output.network_representation' must be"):
        parse_policy_meta(bad, "p.ts")
    bad = copy.deepcopy(meta)
    del bad["preprocessing"]["max_depth_m"]
    with pytest.raises(
        PolicyFormatError, match="p.ts: policy metadata key 'preprocessing.max_depth_m' is missing"
    ):
        parse_policy_meta(bad, "p.ts")
    bad = copy.deepcopy(meta)
    bad["format"] = "quad_il_policy/9"
    with pytest.raises(PolicyFormatError, match="unsupported policy format 'quad_il_policy/9'"):
        parse_policy_meta(bad, "p.ts")
    bad = copy.deepcopy(meta)
    bad["output"]["bspline_order"] = 4
    with pytest.raises(PolicyFormatError, match="'output.bspline_order' must be 3"):
        parse_policy_meta(bad, "p.ts")
    assert parse_policy_meta(meta, "p.ts").velocity_input  # absent in older files: true
    blind = copy.deepcopy(meta)
    blind["preprocessing"]["velocity_input"] = False
    assert not parse_policy_meta(blind, "p.ts").velocity_input
    blind["preprocessing"]["velocity_input"] = "no"
    with pytest.raises(
        PolicyFormatError, match="'preprocessing.velocity_input' must be true or false, got 'no'"
    ):
        parse_policy_meta(blind, "p.ts")


def test_hypotheses_metadata_is_read_checked_and_defaults_to_one(policies) -> None:
    h3 = policies["world_h3"].meta
    assert h3.hypotheses == 3 and h3.output_dim == 30 and h3.network_output_dim == 93
    meta = copy.deepcopy(policies["world"].raw_meta)
    del meta["output"]["hypotheses"]  # files exported before multiple hypotheses
    old = parse_policy_meta(meta, "p.ts")
    assert old.hypotheses == 1 and old.network_output_dim == old.output_dim == 30
    for bad in (0, 9, 2.5, True, "3"):
        meta["output"]["hypotheses"] = bad
        with pytest.raises(PolicyFormatError, match=r"'output.hypotheses' must be an integer in \[1, 8\]"):
            parse_policy_meta(meta, "p.ts")
    meta["output"]["hypotheses"] = 3
    assert not parse_policy_meta(meta, "p.ts").mean_first  # no hypotheses_first: confidence
    meta["output"]["hypotheses_first"] = "mean"
    assert parse_policy_meta(meta, "p.ts").mean_first
    meta["output"]["hypotheses_first"] = "best"
    with pytest.raises(PolicyFormatError, match="'output.hypotheses_first' must be 'confidence' or 'mean'"):
        parse_policy_meta(meta, "p.ts")


def test_ordered_plans_put_the_most_confident_first_ties_by_index_nan_last(policies) -> None:
    meta = policies["world_h3"].meta
    plans = torch.arange(90, dtype=torch.float32)

    def order(logits: list[float]) -> list[int]:
        y = torch.cat([plans, torch.tensor(logits)]).reshape(1, -1)
        out = ordered_plans(y, meta)
        for i, plan in out:
            assert torch.equal(plan[0], plans[30 * i : 30 * (i + 1)])
        return [i for i, _ in out]

    assert order([0.1, 2.0, -1.0]) == [1, 0, 2]
    assert order([1.0, 1.0, 1.0]) == [0, 1, 2]
    assert order([float("nan"), 0.0, 3.0]) == [2, 1, 0]
    mean_first = dataclasses.replace(meta, mean_first=True)
    y = torch.cat([plans, torch.tensor([9.0, 0.0, 3.0])]).reshape(1, -1)
    assert [i for i, _ in ordered_plans(y, mean_first)] == [0, 2, 1]  # plan 0 whatever its logit
    one = policies["world"].meta
    y = torch.rand(1, 30)
    [(i, plan)] = ordered_plans(y, one)
    assert i == 0 and torch.equal(plan, y)
    with pytest.raises(RuntimeError, match="network output has 92 values, the policy declares 93"):
        ordered_plans(torch.zeros(1, 92), meta)


@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_the_file_refuses_metadata_with_another_number_of_hypotheses(tmp_path: Path, policies) -> None:
    module, meta = load_exported(policies["world_h3"].path)
    meta["output"]["hypotheses"] = 2
    torch.jit.save(module, str(tmp_path / "lying.ts"), _extra_files={META_FILE: json.dumps(meta)})
    with pytest.raises(
        PolicyFormatError,
        match="attribute num_hypotheses = 3 disagrees with the metadata's output.hypotheses 2",
    ):
        LoadedPolicy(tmp_path / "lying.ts")
    meta["output"]["hypotheses"] = 3
    meta["output"]["hypotheses_first"] = "mean"
    torch.jit.save(module, str(tmp_path / "lying2.ts"), _extra_files={META_FILE: json.dumps(meta)})
    with pytest.raises(PolicyFormatError, match="attribute mean_first = False disagrees"):
        LoadedPolicy(tmp_path / "lying2.ts")


@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_files_that_are_not_policy_exports_are_refused(tmp_path: Path, policies) -> None:
    plain = torch.jit.script(torch.nn.Linear(2, 2))
    torch.jit.save(plain, str(tmp_path / "plain.ts"))
    with pytest.raises(PolicyFormatError, match="not a quad_il policy export"):
        LoadedPolicy(tmp_path / "plain.ts")
    with pytest.raises(FileNotFoundError):
        LoadedPolicy(tmp_path / "missing.ts")
    # Metadata that disagrees with the file's attributes.
    module, meta = load_exported(policies["world"].path)
    meta["output"]["num_ctrl_pts"] = 12
    torch.jit.save(module, str(tmp_path / "lying.ts"), _extra_files={META_FILE: json.dumps(meta)})
    with pytest.raises(
        PolicyFormatError, match="attribute num_ctrl_pts = 10 disagrees with the metadata's 12"
    ):
        LoadedPolicy(tmp_path / "lying.ts")


def test_the_repository_config_loads_and_errors_name_the_key(tmp_path: Path) -> None:
    cfg = load_policy_config(CONFIG)
    assert cfg.num_threads == 1 and cfg.refusal.action == "stop" and cfg.safety.enabled
    # The recovery variant differs only in the recovery turns and the safety margin.
    rec = load_policy_config(CONFIG.with_name("policy_recovery.yaml"))
    assert rec.recovery.goal_yaw_offsets_deg == [20.0, -20.0, 40.0, -40.0, 60.0, -60.0]
    assert rec.safety.vehicle_radius_m == 0.40
    assert (
        rec.model_copy(
            update={
                "recovery": cfg.recovery,
                "safety": rec.safety.model_copy(update={"vehicle_radius_m": 0.25}),
            }
        )
        == cfg
    )
    # The 10 Hz variant differs from the recovery config only in the decision rate.
    r10 = load_policy_config(CONFIG.with_name("policy_recovery_r10.yaml"))
    assert r10.replan_rate_hz == 10.0 and rec.replan_rate_hz == 0.0
    assert r10.model_copy(update={"replan_rate_hz": 0.0}) == rec
    # make eval's default differs from the 10 Hz variant only in the final approach and keeping the plan.
    keep = load_policy_config(CONFIG.with_name("policy_keep.yaml"))
    assert keep.recovery.final_approach_m == 1.5 and keep.keeping.commit_s == 0.3 and keep.keeping.on_refusal
    assert (
        keep.model_copy(
            update={
                "recovery": keep.recovery.model_copy(update={"final_approach_m": 0.0}),
                "keeping": r10.keeping,
            }
        )
        == r10
    )
    tree = yaml.safe_load(CONFIG.read_text())
    typo = copy.deepcopy(tree)
    typo["safety"]["max_vel_mp"] = 3.0
    with pytest.raises(PolicyConfigError, match="key 'safety.max_vel_mp': Extra inputs are not permitted"):
        config_from_tree(typo)
    missing = copy.deepcopy(tree)
    del missing["goal_tolerance_m"]
    with pytest.raises(PolicyConfigError, match="key 'goal_tolerance_m': Field required"):
        config_from_tree(missing)
    bad = copy.deepcopy(tree)
    bad["refusal"]["action"] = "land"
    with pytest.raises(PolicyConfigError, match="key 'refusal.action'.*got 'land'"):
        config_from_tree(bad)
    bad = copy.deepcopy(tree)
    bad["num_threads"] = 0
    with pytest.raises(PolicyConfigError, match="key 'num_threads'.*got 0"):
        config_from_tree(bad)
    with pytest.raises(PolicyConfigError, match="not found"):
        load_policy_config(tmp_path / "nope.yaml")


def test_uniform_bspline_derivatives_match_finite_differences() -> None:
    rng = np.random.default_rng(2)
    s = UniformBspline(7.0, 0.25, rng.uniform(-3, 3, (10, 3)))
    t = np.linspace(0.01, s.duration_s - 0.01, 40)
    h = 1e-5
    np.testing.assert_allclose(s.velocity(t), (s.position(t + h) - s.position(t - h)) / (2 * h), atol=1e-6)
    np.testing.assert_allclose(
        s.acceleration(t), (s.velocity(t + h) - s.velocity(t - h)) / (2 * h), atol=1e-5
    )
    k = s.knots()
    assert len(k) == 14 and k[3] == 0.0 and k[10] == pytest.approx(s.duration_s)
    # The derivative control points bound speed and acceleration (convex hull).
    tt = np.linspace(0, s.duration_s, 400)
    assert np.linalg.norm(s.velocity(tt), axis=1).max() <= np.linalg.norm(s.velocity_ctrl_pts(), axis=1).max()


def test_the_stopping_trajectory_starts_at_the_state_and_stops_within_the_limit() -> None:
    p0, v0 = np.array([1.0, 2.0, 1.5]), np.array([3.0, -1.0, 0.5])
    s = braking_trajectory(p0, v0, 2.5, 0.5, 12.0)
    assert s.num_ctrl_pts == 4 and s.start_time_s == 12.0
    assert s.duration_s == pytest.approx(2 * np.linalg.norm(v0) / 2.5)
    np.testing.assert_allclose(s.position(0.0)[0], p0, atol=1e-12)
    np.testing.assert_allclose(s.velocity(0.0)[0], v0, atol=1e-12)
    np.testing.assert_allclose(s.velocity(s.duration_s)[0], 0.0, atol=1e-12)
    np.testing.assert_allclose(s.position(s.duration_s)[0], p0 + v0 * s.duration_s / 3, atol=1e-12)
    t = np.linspace(0, s.duration_s, 200)
    assert np.linalg.norm(s.acceleration(t), axis=1).max() <= 2.5 + 1e-9
    assert braking_trajectory(p0, np.zeros(3), 2.5, 0.5, 0.0).duration_s == 0.5
    with pytest.raises(ValueError, match="non-finite"):
        braking_trajectory(np.array([np.nan, 0, 0]), v0, 2.5, 0.5, 0.0)


def _camera() -> CameraModel:
    T = np.eye(4)
    T[:3, :3] = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], dtype=np.float64)
    return CameraModel(70, 50, 42.35, 40.3, 34.5, 24.5, T)


def test_the_decider_refuses_sends_the_stopping_trajectory_and_counts(policies) -> None:
    cfg = load_policy_config(CONFIG)
    decider = PolicyDecider(policies["world"], cfg.safety, cfg.refusal)
    depth = np.full((50, 70), np.inf, np.float32)
    q = np.array([0.0, 0.0, 0.0, 1.0])
    # A random world-frame policy proposes control points near the origin: 12 m away from this vehicle.
    inp = DecisionInputs(
        3.0, depth, _camera(), np.array([12.0, 0, 1.5]), np.array([2.0, 0, 0]), q, np.zeros(3)
    )
    d = decider.decide(inp)
    assert d.safety.verdict == SafetyVerdict.START_FAR_FROM_VEHICLE
    assert d.to_send() is d.stop and d.stop is not None and d.stop.start_time_s == 3.0
    np.testing.assert_allclose(d.stop.position(0.0)[0], [12.0, 0, 1.5], atol=1e-12)
    assert d.proposed.start_time_s == 3.0 and d.proposed.knot_dt_s == pytest.approx(2.0 / 7.0)
    assert decider.counts.counts[SafetyVerdict.START_FAR_FROM_VEHICLE] == 1
    assert min(d.timings.preprocess_ms, d.timings.forward_ms, d.timings.decode_ms, d.timings.safety_ms) >= 0
    hover = PolicyDecider(policies["world"], cfg.safety, cfg.refusal.model_copy(update={"action": "hover"}))
    assert hover.decide(inp).to_send() is None
    with pytest.raises(ValueError, match="v_world has a NaN/Inf element"):
        decider.decide(
            DecisionInputs(3.0, depth, _camera(), np.zeros(3), np.array([np.nan, 0, 0]), q, np.zeros(3))
        )
    with pytest.raises(ValueError, match="q_world_body is zero"):
        decider.decide(
            DecisionInputs(3.0, depth, _camera(), np.zeros(3), np.zeros(3), np.zeros(4), np.zeros(3))
        )


def test_fixtures_round_trip_and_errors_name_the_file(tmp_path: Path) -> None:
    rng = np.random.default_rng(4)
    q = rng.normal(size=(3, 4))
    fx = DecisionFixture(
        depth_m=rng.uniform(0, 5, (3, 6, 8)).astype(np.float32),
        stamp_s=np.array([1.0, 1.1, 1.2]),
        p_world_body=rng.normal(size=(3, 3)),
        v_world=rng.normal(size=(3, 3)),
        q_world_body=q / np.linalg.norm(q, axis=1, keepdims=True),
        goal_world=rng.normal(size=(3, 3)),
        camera_k=np.array([4.0, 4.0, 3.5, 2.5]),
        T_body_camera=np.eye(4),
    )
    write_fixture(tmp_path / "fx", fx)
    back = read_fixture(tmp_path / "fx")
    for name in ("depth_m", "stamp_s", "p_world_body", "v_world", "q_world_body", "goal_world", "camera_k"):
        np.testing.assert_array_equal(getattr(back, name), getattr(fx, name))
    assert back.camera(1).width == 8 and back.camera(1).height == 6
    np.save(tmp_path / "fx" / "goal_world.npy", np.zeros((2, 3)))
    with pytest.raises(FixtureError, match="goal_world.npy: shape"):
        read_fixture(tmp_path / "fx")
    (tmp_path / "fx" / "stamp_s.npy").unlink()
    with pytest.raises(FixtureError, match="stamp_s.npy: missing"):
        read_fixture(tmp_path / "fx")


class _GoalLine(LoadedPolicy):
    """Test double: the exported file's codec around a 'network' flying straight at the goal at 1.5 m/s."""

    def run(self, depth_x, state_x, p, v, q, goal):  # noqa: ANN001, ANN201 - LoadedPolicy.run's signature
        k, dt = self.meta.num_ctrl_pts, self.meta.knot_dt_s
        p64, g64 = p[0].double(), goal[0].double()
        direction = (g64 - p64) / torch.linalg.norm(g64 - p64)
        tau = (torch.arange(k, dtype=torch.float64) - 1.0) * dt
        ctrl = (p64 + 1.5 * tau[:, None] * direction).float().unsqueeze(0)
        with torch.inference_mode():
            return self.module.encode_target(ctrl, p, q).reshape(1, -1)


def _recovery(
    turns: list[float] | None = None,
    steer: float = 0.0,
    turn_after: int = 0,
    turn_rate: float = 45.0,
    turn_clearance: float = 0.0,
    final_m: float = 0.0,
    final_acc: float = 2.0,
) -> RecoveryConfig:
    return RecoveryConfig(
        goal_yaw_offsets_deg=turns or [],
        steer_clearance_m=steer,
        turn_after_stops=turn_after,
        turn_rate_dps=turn_rate,
        turn_clearance_m=turn_clearance,
        final_approach_m=final_m,
        final_approach_acc_mps2=final_acc,
    )


def _wall_ahead() -> np.ndarray:
    """_camera()'s view from the origin along +x: a wall 1.2 m ahead in the middle columns, free elsewhere."""
    depth = np.full((50, 70), np.inf, np.float32)
    depth[:, 25:45] = 1.2  # half-width 12.6 deg seen from the camera (fx 42.35, cx 34.5)
    return depth


def test_turned_goals_keep_distance_and_height() -> None:
    p = np.array([1.0, 2.0, 1.5])
    g = turned_goal(p, np.array([11.0, 2.0, 3.0]), 90.0)
    np.testing.assert_allclose(g, [1.0, 12.0, 3.0], atol=1e-12)  # + = counter-clockwise seen from above
    np.testing.assert_allclose(
        turned_goal(p, np.array([11.0, 2.0, 3.0]), -30.0),
        [1.0 + 10 * np.cos(np.pi / 6), 2.0 - 5.0, 3.0],
        atol=1e-12,
    )


def test_trajectory_in_view_on_constructed_plans() -> None:
    cfg = load_policy_config(CONFIG).safety
    tau = np.arange(10) * 0.25

    def line(direction: list[float]) -> UniformBspline:
        return UniformBspline(
            0.0, 0.25, np.asarray(direction) * tau[:, None] * 1.5 / np.linalg.norm(direction)
        )

    assert trajectory_in_view(line([1.0, 0.0, 0.0]), _camera(), cfg)  # straight ahead
    assert trajectory_in_view(line([1.0, 0.5, 0.0]), _camera(), cfg)  # 26.6 deg left: inside 39.1 deg
    assert not trajectory_in_view(line([1.0, 1.0, 0.0]), _camera(), cfg)  # 45 deg left: beyond the image
    assert not trajectory_in_view(line([-1.0, 0.0, 0.0]), _camera(), cfg)  # behind the camera
    # Samples that hold the camera (the vehicle's own place) are not judged: a plan that stays put is in view.
    assert trajectory_in_view(UniformBspline(0.0, 0.25, np.zeros((10, 3))), _camera(), cfg)


def test_the_recovery_turns_the_goal_until_a_plan_is_accepted_and_in_view(policies) -> None:
    cfg = load_policy_config(CONFIG)
    assert cfg.recovery.goal_yaw_offsets_deg == []  # off by default
    policy = _GoalLine(policies["world"].path)
    q = np.array([0.0, 0.0, 0.0, 1.0])
    inp = DecisionInputs(2.0, _wall_ahead(), _camera(), np.zeros(3), np.zeros(3), q, np.array([10.0, 0, 0]))

    off = PolicyDecider(policy, cfg.safety, cfg.refusal).decide(inp)
    assert off.safety.verdict == SafetyVerdict.COLLISION_IN_DEPTH
    assert off.recovery is None and off.recovery_tries == 0 and off.to_send() is off.stop

    # 60 deg: clear of the wall but out of the image (refused by the view test); 30 deg: accepted.
    on = _recovery([60.0, 30.0, -30.0])
    decider = PolicyDecider(policy, cfg.safety, cfg.refusal, on)
    d = decider.decide(inp)
    assert d.safety.verdict == SafetyVerdict.COLLISION_IN_DEPTH  # the verdict is the policy's own plan's
    assert d.recovery_yaw_deg == 30.0 and d.recovery_tries == 2
    assert d.to_send() is d.recovery and d.stop is None
    heading = d.recovery.position(np.array([1.0]))[0]
    assert np.degrees(np.arctan2(heading[1], heading[0])) == pytest.approx(30.0, abs=1e-3)
    assert decider.counts.counts[SafetyVerdict.COLLISION_IN_DEPTH] == 1

    # Only turns that stay blocked or leave the view: no recovery, the stopping trajectory as before.
    only_bad = _recovery([60.0, 10.0])
    none = PolicyDecider(policy, cfg.safety, cfg.refusal, only_bad)
    d = none.decide(inp)
    assert d.recovery is None and d.recovery_tries == 2 and d.to_send() is d.stop

    # An accepted plan asks no turned goal.
    free = DecisionInputs(
        2.0,
        np.full((50, 70), np.inf, np.float32),
        _camera(),
        np.zeros(3),
        np.zeros(3),
        q,
        np.array([10.0, 0, 0]),
    )
    d = decider.decide(free)
    assert d.accepted and d.recovery_tries == 0 and d.to_send() is d.proposed


class _GoalFan(LoadedPolicy):
    """Test double with three hypotheses: lines at 1.5 m/s towards the goal turned by 0, +30 and -30 deg, with
    the given confidence logits."""

    logits = (1.0, 0.5, 0.0)

    def run(self, depth_x, state_x, p, v, q, goal):  # noqa: ANN001, ANN201 - LoadedPolicy.run's signature
        k, dt = self.meta.num_ctrl_pts, self.meta.knot_dt_s
        p64 = p[0].double()
        tau = (torch.arange(k, dtype=torch.float64) - 1.0) * dt
        parts = []
        for yaw in (0.0, 30.0, -30.0):
            g64 = torch.from_numpy(turned_goal(p64.numpy(), goal[0].double().numpy(), yaw))
            direction = (g64 - p64) / torch.linalg.norm(g64 - p64)
            ctrl = (p64 + 1.5 * tau[:, None] * direction).float().unsqueeze(0)
            with torch.inference_mode():
                parts.append(self.module.encode_target(ctrl, p, q).reshape(-1))
        return torch.cat([*parts, torch.tensor(self.logits)]).reshape(1, -1)


def test_a_refused_plan_is_replaced_by_the_next_hypothesis_before_any_turned_goal(policies) -> None:
    cfg = load_policy_config(CONFIG)
    policy = _GoalFan(policies["world_h3"].path)
    q = np.array([0.0, 0.0, 0.0, 1.0])
    inp = DecisionInputs(2.0, _wall_ahead(), _camera(), np.zeros(3), np.zeros(3), q, np.array([10.0, 0, 0]))
    decider = PolicyDecider(policy, cfg.safety, cfg.refusal, _recovery([20.0, -20.0]))
    d = decider.decide(inp)
    # The most confident plan (straight) runs into the wall: refused, and that is the verdict counted.
    assert d.proposed_hypothesis == 0 and d.safety.verdict == SafetyVerdict.COLLISION_IN_DEPTH
    # Hypothesis 1 (+30 deg) passes without asking the network about a turned goal.
    assert d.recovery_hypothesis == 1 and d.recovery_yaw_deg == 0.0 and d.recovery_tries == 0
    assert d.to_send() is d.recovery
    heading = d.recovery.position(np.array([1.0]))[0]
    assert np.degrees(np.arctan2(heading[1], heading[0])) == pytest.approx(30.0, abs=1e-3)
    assert d.recovery_text(3) == "; recovered with hypothesis 2 of 3"
    assert len(d.y) == 93
    # The confidences choose: with -30 deg more confident than +30 deg the recovery takes that one.
    policy.logits = (1.0, 0.0, 0.5)
    d = decider.decide(inp)
    assert d.recovery_hypothesis == 2 and d.recovery_text(3) == "; recovered with hypothesis 3 of 3"
    # The most confident plan flies when it is clear, whatever its index.
    policy.logits = (0.0, 2.0, 1.0)
    free = dataclasses.replace(inp, depth_m=np.full((50, 70), np.inf, np.float32))
    d = decider.decide(free)
    assert d.accepted and d.proposed_hypothesis == 1 and d.recovery is None and d.to_send() is d.proposed


def _stub_decision() -> Decision:
    line = UniformBspline(0.0, 0.25, np.zeros((4, 3)))
    return Decision(
        safety=SafetyResult(SafetyVerdict.ACCEPTED, "ok"),
        proposed=line,
        stop=None,
        depth_x=np.zeros((2, 2), np.float32),
        state_x=np.zeros(13, np.float32),
        y=np.zeros(12, np.float32),
    )


def test_recovery_text_names_turn_and_hypothesis() -> None:
    d = dataclasses.replace(
        _stub_decision(), recovery=_stub_decision().proposed, recovery_yaw_deg=20.0, recovery_hypothesis=0
    )
    assert d.recovery_text(1) == "; recovered with the goal turned 20 deg"
    assert d.recovery_text(3) == "; recovered with the goal turned 20 deg, hypothesis 1 of 3"
    assert dataclasses.replace(d, steered=True).recovery_text(1) == "; steered with the goal turned 20 deg"
    assert dataclasses.replace(d, recovery=None).recovery_text(3) == ""


def test_steering_turns_away_from_a_wall_that_an_accepted_plan_comes_near(policies) -> None:
    cfg = load_policy_config(CONFIG)
    assert cfg.recovery.steer_clearance_m == 0.0  # off by default
    policy = _GoalLine(policies["world"].path)
    q = np.array([0.0, 0.0, 0.0, 1.0])
    depth = np.full((50, 70), np.inf, np.float32)
    depth[:, 30:40] = 2.2  # a narrow wall 2.2 m ahead: the straight plan ends 0.7 m from it
    inp = DecisionInputs(2.0, depth, _camera(), np.zeros(3), np.zeros(3), q, np.array([10.0, 0, 0]))

    turns = [60.0, 10.0, 30.0, -30.0]
    plain = PolicyDecider(policy, cfg.safety, cfg.refusal, _recovery(turns))
    d = plain.decide(inp)
    assert d.accepted and d.recovery_tries == 0 and d.to_send() is d.proposed  # steering off: no search

    steer = _recovery(turns, steer=0.9)
    decider = PolicyDecider(policy, cfg.safety, cfg.refusal, steer)
    d = decider.decide(inp)
    # 60 deg leaves the image, 10 deg still passes within 0.9 m of the wall, 30 deg keeps 0.9 m.
    assert d.accepted and d.steered and d.recovery_yaw_deg == 30.0 and d.recovery_tries == 3
    assert d.to_send() is d.recovery and d.stop is None
    heading = d.recovery.position(np.array([1.0]))[0]
    assert np.degrees(np.arctan2(heading[1], heading[0])) == pytest.approx(30.0, abs=1e-3)

    # No turn keeps the clearance: the accepted plan is flown as it is.
    d = PolicyDecider(
        policy,
        cfg.safety,
        cfg.refusal,
        _recovery([60.0, 10.0], steer=0.9),
    ).decide(inp)
    assert d.accepted and not d.steered and d.recovery is None and d.recovery_tries == 2
    assert d.to_send() is d.proposed

    # A plan that keeps the clearance is not steered; a refused one is recovered (not steered) as before.
    d = decider.decide(dataclasses.replace(inp, depth_m=np.full((50, 70), 9.0, np.float32)))
    assert d.accepted and d.recovery_tries == 0 and d.to_send() is d.proposed
    d = decider.decide(dataclasses.replace(inp, depth_m=_wall_ahead()))
    assert not d.accepted and not d.steered and d.recovery_yaw_deg == 30.0


@pytest.mark.parametrize(
    ("steer", "radius", "angles", "message"),
    [
        ("0.3", "0.4", "[20.0]", r"steer_clearance_m \(0.3\) must be 0 \(off\) or greater than safety"),
        ("1.0", "0.4", "[]", "goal_yaw_offsets_deg is empty: no turns to steer by"),
        ("-1.0", "0.4", "[20.0]", "recovery.steer_clearance_m.*greater than or equal to 0"),
    ],
)
def test_steering_config_errors_name_the_key(
    tmp_path: Path, steer: str, radius: str, angles: str, message: str, policies
) -> None:
    text = (
        CONFIG.read_text()
        .replace("steer_clearance_m: 0.0", f"steer_clearance_m: {steer}")
        .replace("goal_yaw_offsets_deg: []", f"goal_yaw_offsets_deg: {angles}")
    )
    text = re.sub(r"vehicle_radius_m: [0-9.]+", f"vehicle_radius_m: {radius}", text)
    bad = tmp_path / "policy.yaml"
    bad.write_text(text)
    with pytest.raises(PolicyConfigError, match=message):
        load_policy_config(bad)
    if float(steer) >= 0.0:  # the decider checks the same when built from parts
        tree = yaml.safe_load(text)
        with pytest.raises(ValueError, match=message):
            PolicyDecider(
                LoadedPolicy(policies["world"].path),
                SafetyConfig.model_validate(tree["safety"]),
                RefusalConfig.model_validate(tree["refusal"]),
                RecoveryConfig.model_validate(tree["recovery"]),
            )


@pytest.mark.parametrize(
    ("angles", "message"),
    [
        ("[0.0]", "non-zero"),
        ("[200.0]", "within \\[-180, 180\\]"),
        ("[.nan]", "finite"),
        (str([10.0] * 17), "at most 16"),
        ("30", "valid list"),
    ],
)
def test_recovery_config_errors_name_the_key(tmp_path: Path, angles: str, message: str) -> None:
    bad = tmp_path / "policy.yaml"
    bad.write_text(CONFIG.read_text().replace("goal_yaw_offsets_deg: []", f"goal_yaw_offsets_deg: {angles}"))
    with pytest.raises(PolicyConfigError, match=rf"recovery\.goal_yaw_offsets_deg[\s\S]*{message}"):
        load_policy_config(bad)


def _heading(traj: UniformBspline, t: np.ndarray) -> np.ndarray:
    """The heading of a trajectory at times t, evaluated with the same basis as its positions."""
    assert traj.yaw_ctrl is not None
    yaw = np.zeros_like(traj.ctrl_world)
    yaw[:, 0] = traj.yaw_ctrl
    return UniformBspline(traj.start_time_s, traj.knot_dt_s, yaw).position(t)[:, 0]


def test_constant_yaw_rate_is_exactly_linear_and_keeps_the_positions() -> None:
    stop = braking_trajectory(np.array([1.0, 2, 3]), np.array([1.0, 0, 0]), 3.0, 0.5, 5.0)
    assert stop.yaw_ctrl is None  # no heading unless one is set
    turning = with_constant_yaw_rate(stop, 3.0, -0.8)
    np.testing.assert_array_equal(turning.ctrl_world, stop.ctrl_world)
    t = np.linspace(0.0, stop.duration_s, 17)
    np.testing.assert_allclose(_heading(turning, t), 3.0 - 0.8 * t, rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match="non-finite yaw or rate"):
        with_constant_yaw_rate(stop, 0.0, float("nan"))
    # The turning stop without a back-off: the same motion, with the heading.
    same = turning_stop(np.array([1.0, 2, 3]), np.array([1.0, 0, 0]), np.zeros(3), 3.0, -0.8, 3.0, 0.5, 5.0)
    np.testing.assert_allclose(same.ctrl_world, stop.ctrl_world, rtol=0, atol=1e-12)
    np.testing.assert_allclose(same.yaw_ctrl, turning.yaw_ctrl, rtol=0, atol=1e-12)
    # The heading of a quaternion (x, y, z, w), also when it is not normalised.
    a = 2.5
    assert yaw_of(np.array([0.0, 0.0, np.sin(a / 2), np.cos(a / 2)])) == pytest.approx(a, abs=1e-12)
    assert yaw_of(3.0 * np.array([0.0, 0.0, np.sin(-a / 2), np.cos(-a / 2)])) == pytest.approx(-a, abs=1e-12)


def test_turning_in_place_starts_after_n_stops_towards_the_goal_and_ends_with_a_plan(policies) -> None:
    cfg = load_policy_config(CONFIG)
    assert cfg.recovery.turn_after_stops == 0  # off by default
    policy = _GoalLine(policies["world"].path)
    q = np.array([0.0, 0.0, 0.0, 1.0])
    right = DecisionInputs(
        2.0, _wall_ahead(), _camera(), np.zeros(3), np.zeros(3), q, np.array([10.0, -2, 0])
    )
    left = dataclasses.replace(right, goal_world=np.array([10.0, 2, 0]))
    free = dataclasses.replace(right, depth_m=np.full((50, 70), np.inf, np.float32))
    decider = PolicyDecider(policy, cfg.safety, cfg.refusal, _recovery(turn_after=3, turn_rate=45.0))

    # Two stops as before, then the third turns towards the goal's side (right: negative) at 45 deg/s.
    for _ in range(2):
        d = decider.decide(right)
        assert d.to_send() is d.stop and d.turn_rate_radps == 0.0 and d.stop.yaw_ctrl is None
    d = decider.decide(right)
    assert d.to_send() is d.stop and d.turn_rate_radps == pytest.approx(-np.pi / 4)
    t = np.linspace(0.0, d.stop.duration_s, 9)
    np.testing.assert_allclose(_heading(d.stop, t), -np.pi / 4 * t, rtol=0, atol=1e-12)
    np.testing.assert_allclose(d.stop.position(t), 0.0, atol=1e-12)  # at rest: it turns on the spot
    # The direction is kept while the stops go on, even when the goal is now on the left.
    assert decider.decide(left).turn_rate_radps == pytest.approx(-np.pi / 4)
    # A plan ends the turning; the count starts again, and the next turning goes to the goal's side.
    d = decider.decide(free)
    assert d.accepted and d.to_send() is d.proposed and d.turn_rate_radps == 0.0
    assert [decider.decide(left).turn_rate_radps for _ in range(3)] == [0.0, 0.0, pytest.approx(np.pi / 4)]
    decider.reset()  # a new episode
    assert decider.decide(left).turn_rate_radps == 0.0
    # A recovered plan ends the stops as an accepted one does.
    both = PolicyDecider(policy, cfg.safety, cfg.refusal, _recovery([40.0], turn_after=1))
    assert both.decide(right).recovery is not None and both.stops_in_row == 0
    with pytest.raises(ValueError, match="turn_after_stops is set but refusal.action is not 'stop'"):
        PolicyDecider(
            policy, cfg.safety, cfg.refusal.model_copy(update={"action": "hover"}), _recovery(turn_after=3)
        )


def test_the_turning_stop_backs_off_within_the_deceleration_limit_and_ends_at_rest() -> None:
    p0, v0, b = np.array([1.0, 2, 3]), np.array([0.6, -0.3, 0.0]), np.array([-0.5, 0.2, 0.0])
    s = turning_stop(p0, v0, b, 0.2, 0.5, 3.0, 0.5, 7.0)
    T = s.knot_dt_s
    assert T == pytest.approx(np.sqrt(6 * np.linalg.norm(b) / 3.0))  # the back-off sets the duration here
    np.testing.assert_allclose(s.position(0.0)[0], p0, atol=1e-12)
    np.testing.assert_allclose(s.velocity(0.0)[0], v0, atol=1e-12)
    np.testing.assert_allclose(s.position(T)[0], p0 + v0 * T / 3 + b, atol=1e-12)
    np.testing.assert_allclose(s.velocity(T)[0], 0.0, atol=1e-12)
    # The back-off alone (no start velocity) accelerates at most max_decel, at its ends.
    only = turning_stop(p0, np.zeros(3), b, 0.0, 0.5, 3.0, 0.5, 7.0)
    acc = np.linalg.norm(only.acceleration(np.linspace(0, T, 41)), axis=1)
    assert acc.max() == pytest.approx(3.0, rel=1e-9) and acc[0] == pytest.approx(3.0, rel=1e-9)
    np.testing.assert_allclose(_heading(s, np.array([0.0, T])), [0.2, 0.2 + 0.5 * T], atol=1e-12)
    with pytest.raises(ValueError, match="non-finite back-off"):
        turning_stop(p0, v0, np.array([np.nan, 0, 0]), 0.0, 0.5, 3.0, 0.5, 7.0)


def test_nearest_depth_treats_the_rep118_specials_as_the_safety_layer_does() -> None:
    d = np.full((4, 5), np.inf, np.float32)
    assert nearest_depth(d) == np.inf  # nothing seen
    d[1, 2], d[3, 3], d[0, 0] = 2.5, 1.75, np.nan
    assert nearest_depth(d) == 1.75
    d[2, 4] = -np.inf  # too near: 0
    assert nearest_depth(d) == 0.0


def test_turning_backs_away_from_a_surface_nearer_than_the_clearance(policies) -> None:
    cfg = load_policy_config(CONFIG)
    policy = _GoalLine(policies["world"].path)
    yaw = 0.3
    q = np.array([0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2)])
    p0 = np.zeros(3)
    # The wall is 1.2 m ahead of _camera() (at the origin, looking along +x), which the depth test uses: the
    # plan at the goal is refused whatever the vehicle's heading, which sets the back-off's direction.
    inp = DecisionInputs(2.0, _wall_ahead(), _camera(), p0, np.zeros(3), q, p0 + np.array([10.0, 0, 0]))
    decider = PolicyDecider(policy, cfg.safety, cfg.refusal, _recovery(turn_after=1, turn_clearance=2.0))
    d = decider.decide(inp)
    assert d.turn_backoff_m == pytest.approx(0.8)
    heading = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    np.testing.assert_allclose(d.stop.position(d.stop.duration_s)[0], p0 - 0.8 * heading, atol=1e-12)
    # A surface beyond the clearance: no back-off, the vehicle turns where it is.
    far = PolicyDecider(policy, cfg.safety, cfg.refusal, _recovery(turn_after=1, turn_clearance=1.0))
    d = far.decide(inp)
    assert d.turn_rate_radps != 0.0 and d.turn_backoff_m == 0.0
    np.testing.assert_allclose(d.stop.position(d.stop.duration_s)[0], p0, atol=1e-12)


@pytest.mark.parametrize(
    ("after", "rate", "action", "message"),
    [
        ("-1", "45.0", "stop", r"recovery\.turn_after_stops[\s\S]*greater than or equal to 0"),
        ("15", "0.0", "stop", r"recovery\.turn_rate_dps[\s\S]*greater than 0"),
        ("15", "200.0", "stop", r"recovery\.turn_rate_dps[\s\S]*less than or equal to 180"),
        ("15", "45.0", "hover", "turn_after_stops is set but refusal.action is not 'stop'"),
        ("15", "45.0", "stop -1", r"recovery\.turn_clearance_m[\s\S]*greater than or equal to 0"),
    ],
)
def test_turning_config_errors_name_the_key(
    tmp_path: Path, after: str, rate: str, action: str, message: str
) -> None:
    bad = tmp_path / "policy.yaml"
    bad.write_text(
        CONFIG.read_text()
        .replace("turn_after_stops: 0", f"turn_after_stops: {after}")
        .replace("turn_rate_dps: 45.0", f"turn_rate_dps: {rate}")
        .replace("action: stop", f"action: {action.split()[0]}")
        .replace("turn_clearance_m: 0.8", f"turn_clearance_m: {action.split()[-1] if ' ' in action else 0.8}")
    )
    with pytest.raises(PolicyConfigError, match=message):
        load_policy_config(bad)


@pytest.mark.parametrize(
    "v0",
    [np.zeros(3), np.array([2.0, 0.0, 0.0]), np.array([1.5, -0.5, 0.8]), np.array([-2.0, 1.0, 0.0])],
)
def test_the_final_approach_ends_at_rest_on_the_goal_within_the_acceleration_limit(v0: np.ndarray) -> None:
    p0, goal = np.array([1.0, 2.0, 1.5]), np.array([1.6, 2.8, 2.3])  # 1.28 m away, 0.8 m above
    t = final_approach(p0, v0, goal, 2.0, 0.5, 4.0)
    assert t is not None and t.num_ctrl_pts == 4 and t.start_time_s == 4.0
    assert t.duration_s >= 0.5 and t.yaw_ctrl is None
    np.testing.assert_allclose(t.position(0.0)[0], p0, atol=1e-12)
    np.testing.assert_allclose(t.velocity(0.0)[0], v0, atol=1e-12)
    np.testing.assert_allclose(t.position(t.duration_s)[0], goal, atol=1e-12)
    np.testing.assert_allclose(t.velocity(t.duration_s)[0], 0.0, atol=1e-12)
    acc = np.linalg.norm(t.acceleration(np.linspace(0.0, t.duration_s, 101)), axis=1)
    assert acc.max() <= 2.0 + 1e-9
    # The first duration on the 0.02 s grid that keeps the limit: 0.02 s less would exceed it.
    if t.duration_s > 0.5 + 1e-9:
        shorter = t.duration_s - 0.02
        b = goal - p0 - v0 * shorter / 3.0
        ends = [-2.0 * v0 / shorter + 6.0 * b / shorter**2, -6.0 * b / shorter**2]
        assert max(np.linalg.norm(e) for e in ends) > 2.0


def test_the_final_approach_is_none_without_a_feasible_duration_and_rejects_bad_input() -> None:
    # 5 m/s away from a goal 1 m behind, with 1e-4 m/s^2: no duration up to 40 s turns it round.
    assert final_approach(np.zeros(3), np.array([5.0, 0, 0]), np.array([-1.0, 0, 0]), 1e-4, 0.5, 0.0) is None
    with pytest.raises(ValueError, match="final approach: non-finite goal"):
        final_approach(np.zeros(3), np.zeros(3), np.array([np.nan, 0, 0]), 2.0, 0.5, 0.0)
    with pytest.raises(ValueError, match="must be > 0"):
        final_approach(np.zeros(3), np.zeros(3), np.ones(3), 0.0, 0.5, 0.0)


def test_the_decider_flies_the_final_approach_near_the_goal_only_when_it_is_clear(policies) -> None:
    cfg = load_policy_config(CONFIG)
    q = np.array([0.0, 0.0, 0.0, 1.0])
    free = np.full((50, 70), np.inf, np.float32)
    # A random world-frame policy proposes control points near the origin: refused 12 m away (start far).
    p = np.array([12.0, 0.0, 1.5])
    near_goal = p + np.array([1.0, 0.0, 0.3])

    T = _camera().T_world_camera.copy()
    T[:3, 3] = p  # the camera at the vehicle, looking along +x
    camera = dataclasses.replace(_camera(), T_world_camera=T)

    def decide(recovery: RecoveryConfig, depth: np.ndarray, goal: np.ndarray):
        decider = PolicyDecider(policies["world"], cfg.safety, cfg.refusal, recovery)
        return decider, decider.decide(DecisionInputs(3.0, depth, camera, p, np.array([1.0, 0, 0]), q, goal))

    decider, d = decide(_recovery(final_m=1.5), free, near_goal)
    assert d.final is not None and d.to_send() is d.final and d.stop is None
    assert not d.accepted  # the network's own plan is still judged (and counted)
    assert decider.counts.counts[SafetyVerdict.START_FAR_FROM_VEHICLE] == 1 and decider.stops_in_row == 0
    np.testing.assert_allclose(d.final.position(d.final.duration_s)[0], near_goal, atol=1e-12)
    # Beyond the distance, or off: the decision is the one without it (here the stopping trajectory).
    for recovery, goal in ((_recovery(final_m=1.5), p + np.array([1.6, 0, 0])), (_recovery(), near_goal)):
        _, d = decide(recovery, free, goal)
        assert d.final is None and d.to_send() is d.stop
    # A wall 1.2 m ahead between the vehicle and a goal 1.4 m ahead: the safety layer refuses the approach.
    _, d = decide(_recovery(final_m=1.5), _wall_ahead(), p + np.array([1.4, 0, 0]))
    assert d.final is None and d.to_send() is d.stop


def _assert_edit_refused(tmp_path: Path, old: str, new: str, message: str) -> None:
    """The repository's policy config with `old` replaced by `new` is refused with a matching error."""
    bad = tmp_path / "policy.yaml"
    text = CONFIG.read_text()
    assert old in text
    bad.write_text(text.replace(old, new))
    with pytest.raises(PolicyConfigError, match=message):
        load_policy_config(bad)


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        (
            "final_approach_m: 0.0",
            "final_approach_m: -1.0",
            r"recovery\.final_approach_m[\s\S]*greater than or equal to 0",
        ),
        (
            "final_approach_acc_mps2: 2.0",
            "final_approach_acc_mps2: 0",
            r"recovery\.final_approach_acc_mps2[\s\S]*greater than 0",
        ),
        ("  final_approach_m: 0.0\n", "", r"key 'recovery\.final_approach_m': Field required"),
    ],
)
def test_final_approach_config_errors_name_the_key(tmp_path: Path, old: str, new: str, message: str) -> None:
    assert load_policy_config(CONFIG).recovery.final_approach_m == 0.0  # off in the repository's config
    _assert_edit_refused(tmp_path, old, new, message)


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ("commit_s: 0.0", "commit_s: -0.1", r"keeping\.commit_s[\s\S]*greater than or equal to 0"),
        ("commit_s: 0.0", "commit_s: .nan", r"keeping\.commit_s[\s\S]*finite number"),
        ("on_refusal: false", "on_refusal: maybe", r"keeping\.on_refusal[\s\S]*valid boolean"),
        ("  on_refusal: false", "  on_refusal_x: false", r"keeping\.on_refusal_x': Extra inputs"),
    ],
)
def test_keeping_config_errors_name_the_key(tmp_path: Path, old: str, new: str, message: str) -> None:
    keeping = load_policy_config(CONFIG).keeping
    assert keeping.commit_s == 0.0 and not keeping.on_refusal  # off in the repository's config
    _assert_edit_refused(tmp_path, old, new, message)
