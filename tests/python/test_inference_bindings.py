"""The bindings of the C++ inference core (quad_policy_py, through quad_il.inference.core and .config): bad
input is a Python exception naming the problem, the config loader is the C++ one with the overlay rule of
quad_il.tools.config_overlay, and the decider's Python entry calls back into Python for turned goals. The
decisions themselves are compared with policy_replay's in test_inference_parity.py."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from quad_il.inference.config import PolicyConfigError, config_from_tree, load_policy_config
from quad_il.inference.core import (
    VERDICT_LABELS,
    CameraModel,
    PolicyDecider,
    UniformBspline,
    braking_trajectory,
    check_trajectory,
    parse_policy_meta,
    safety_sample_times,
)
from quad_il.tools.config_overlay import OverlayError, load_tree

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "config" / "policy.yaml"
T_WORLD_CAMERA = np.array([[0, 0, 1, 0.1], [-1, 0, 0, 0], [0, -1, 0, 1.5], [0, 0, 0, 1]], dtype=np.float64)
META = {
    "format": "quad_il_policy/1",
    "output": {"bspline_order": 3, "horizon_s": 2.0, "network_frame": "world", "num_ctrl_pts": 10,
               "network_representation": "bspline"},
    "preprocessing": {"input_height": 8, "input_width": 8, "max_depth_m": 10.0, "position_scale_m": 10.0,
                      "state_frame": "world", "velocity_scale_mps": 3.0},
}  # fmt: skip


def camera() -> CameraModel:
    return CameraModel(80, 60, 48.4, 48.4, 39.5, 29.5, T_WORLD_CAMERA)


HOVER = np.array([0.0, 0.0, 1.5])  # where the vehicle is, facing +x


def line_output(goal: np.ndarray) -> np.ndarray:
    """A world-frame B-spline output flying straight from HOVER at `goal` at 1.5 m/s (K = 10 over 2 s)."""
    p = HOVER
    direction = (goal - p) / np.linalg.norm(goal - p)
    tau = (np.arange(10) - 1.0) * 2.0 / 7.0
    return (p + 1.5 * tau[:, None] * direction).astype(np.float32).reshape(-1)


@pytest.fixture
def decider() -> PolicyDecider:
    cfg = load_policy_config(CONFIG)  # the recovery's turns 20, -20, 40, ...
    safety = cfg.safety
    safety.vehicle_radius_m = 0.25  # from hover a 20 deg turn stays in view with 0.25 m (docs/inference.md)
    return PolicyDecider(parse_policy_meta(json.dumps(META), "m.json"), safety, cfg.refusal, cfg.recovery)


def decide(decider: PolicyDecider, depth: np.ndarray, ask=line_output, **changes):
    args = dict(stamp_s=1.0, depth_m=depth, camera=camera(), p_world_body=HOVER, v_world=np.zeros(3))
    args.update(q_world_body=np.array([0.0, 0.0, 0.0, 1.0]), goal_world=np.array([10.0, 0, 1.5]))
    y = changes.pop("y") if "y" in changes else None
    args.update(changes)
    y = line_output(args["goal_world"]) if y is None else y
    return decider.decide(**args, y=y, ask=ask)


def test_a_plan_into_a_wall_is_recovered_through_the_python_callback(decider: PolicyDecider) -> None:
    free = np.full((60, 80), np.inf, np.float32)
    d = decide(decider, free)
    assert d.sent_kind == 1 and d.accepted and d.summary(1, 1.0).action == "policy"
    wall = free.copy()
    wall[:, 35:45] = 1.2
    asked: list[np.ndarray] = []
    d = decide(decider, wall, ask=lambda goal: asked.append(goal) or line_output(goal))
    assert d.safety.label == "collision_in_depth" and not d.accepted
    assert d.sent_kind == 3 and d.recovery_yaw_deg == 20.0 and d.recovery_tries == 1
    np.testing.assert_allclose(asked[0], [10 * np.cos(np.radians(20)), 10 * np.sin(np.radians(20)), 1.5])
    summary = d.summary(1, 1.0)
    assert summary.action == "recovery" and summary.events == ["recovered"]
    assert summary.reason.endswith("; recovered with the goal turned 20 deg")
    np.testing.assert_array_equal(d.to_send.ctrl_world, d.recovery.ctrl_world)


def test_bad_inputs_are_value_errors_naming_the_problem(decider: PolicyDecider) -> None:
    free = np.full((60, 80), np.inf, np.float32)
    with pytest.raises(ValueError, match=r"depth image must be a non-empty \(H, W\) array"):
        decide(decider, free.reshape(-1))
    with pytest.raises(ValueError, match="network output has 29 values, the policy declares 30"):
        decide(decider, free, y=np.zeros(29, np.float32))
    with pytest.raises(ValueError, match="p_world_body has a NaN/Inf element"):
        decide(decider, free, p_world_body=np.array([0.0, np.nan, 1.5]))
    with pytest.raises(ValueError, match="goal_world must have 3 values, got 2"):
        decide(decider, free, goal_world=np.zeros(2), y=line_output(np.array([10.0, 0.0, 1.5])))
    with pytest.raises(ValueError, match="q_world_body is zero"):
        decide(decider, free, q_world_body=np.zeros(4))
    with pytest.raises(ValueError, match="depth image and camera model sizes differ"):
        decide(decider, np.full((30, 40), np.inf, np.float32))
    wall = free.copy()
    wall[:] = 1.0
    with pytest.raises(ValueError, match="network output has 3 values"):
        decide(decider, wall, ask=lambda goal: np.zeros(3, np.float32))  # a wrong answer of the callback
    with pytest.raises(ValueError, match="camera intrinsics"):
        CameraModel(80, 60, -1.0, 48.4, 39.5, 29.5, T_WORLD_CAMERA)
    with pytest.raises(ValueError, match="non-finite"):
        braking_trajectory(np.array([np.inf, 0, 0]), np.zeros(3), 3.0, 0.5, 0.0)
    with pytest.raises(ValueError, match="p_world_vehicle must have 3 values"):
        check_trajectory(
            UniformBspline(0.0, 0.2, np.zeros((4, 3))), np.zeros(4), free, camera(), decider_cfg()
        )


def decider_cfg():
    return load_policy_config(CONFIG).safety


def test_the_safety_layer_and_trajectories_are_usable_from_python() -> None:
    cfg = decider_cfg()
    stop = braking_trajectory(np.zeros(3), np.array([1.5, 0.0, 0.0]), 3.0, 0.5, 2.0)
    assert stop.start_time_s == 2.0 and stop.duration_s == pytest.approx(1.0)
    np.testing.assert_allclose(stop.position([stop.duration_s])[0], [0.5, 0.0, 0.0], atol=1e-12)
    times = safety_sample_times(stop, cfg)
    assert times[0] == 0.0 and times[-1] == pytest.approx(1.0)
    free = np.full((60, 80), np.inf, np.float32)
    assert check_trajectory(stop, np.zeros(3), free, camera(), cfg).label == "accepted"
    assert VERDICT_LABELS[0] == "accepted" and "collision_in_depth" in VERDICT_LABELS


@pytest.mark.parametrize("name", sorted(p.name for p in (ROOT / "config").glob("policy*.yaml")))
def test_the_cpp_loader_merges_overlays_as_the_python_overlay_rule_does(name: str) -> None:
    path = ROOT / "config" / name
    assert load_policy_config(path) == config_from_tree(load_tree(path), name)


def test_overlay_and_config_errors_name_the_file_and_the_key(tmp_path: Path) -> None:
    typo = tmp_path / "typo.yaml"
    typo.write_text(f"overlay_of: {CONFIG}\nsafety:\n  max_vel_mp: 2.0\n")
    with pytest.raises(
        PolicyConfigError, match=r"typo.yaml \(overlay of .*\): key 'safety.max_vel_mp' does not"
    ):
        load_policy_config(typo)
    with pytest.raises(OverlayError, match="key 'safety.max_vel_mp' does not exist in the base config"):
        load_tree(typo)  # the same rule in Python
    removed = tmp_path / "steer.yaml"
    removed.write_text(f"overlay_of: {CONFIG}\nrecovery:\n  steer_clearance_m: 1.0\n")
    with pytest.raises(PolicyConfigError, match="'recovery.steer_clearance_m' does not exist"):
        load_policy_config(removed)  # a removed knob is named
    bad = tmp_path / "bad.yaml"
    bad.write_text(f"overlay_of: {CONFIG}\nsafety:\n  max_vel_mps: -1.0\n")
    with pytest.raises(PolicyConfigError, match="'safety.max_vel_mps' has value -1"):
        load_policy_config(bad)
    with pytest.raises(PolicyConfigError, match="missing required key 'goal_tolerance_m'"):
        config_from_tree({k: v for k, v in load_tree(CONFIG).items() if k != "goal_tolerance_m"}, "t")
    with pytest.raises(ValueError, match="cannot open config file"):
        load_policy_config(tmp_path / "none.yaml")
