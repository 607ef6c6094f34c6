"""The Python side of inference: the preprocessing and forward pass against the exported file's own methods,
both network entries, the policy file's checks, the metadata parser's errors (the bound C++ parser) and the
fixture format. The decider itself is C++ (gtest test_quad_policy; bindings: test_inference_bindings.py)."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from quad_il.inference.core import PolicyFormatError, parse_policy_meta
from quad_il.inference.fixture import DecisionFixture, FixtureError, read_fixture, write_fixture
from quad_il.inference.policy import LoadedPolicy, as_row
from quad_il.inference.random_policy import export_random_policy
from quad_il.learning.config import ModelConfig
from quad_il.learning.export import META_FILE, load_exported


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


def _inputs(seed: int, h: int = 50, w: int = 70) -> tuple[np.ndarray, list[np.ndarray]]:
    rng = np.random.default_rng(seed)
    depth = rng.uniform(0.2, 14.0, (h, w)).astype(np.float32)
    depth[rng.random((h, w)) < 0.05] = np.inf
    depth[rng.random((h, w)) < 0.05] = -np.inf
    depth[rng.random((h, w)) < 0.05] = np.nan
    q = rng.normal(size=4)
    return depth, [
        rng.uniform(-10, 10, 3),
        rng.uniform(-2, 2, 3),
        q / np.linalg.norm(q),
        rng.uniform(-20, 20, 3),
    ]


@pytest.mark.parametrize("name", ["world", "local_poly_net"])
def test_python_preprocessing_equals_the_files_own(policies, name: str) -> None:
    policy = policies[name]
    for seed in range(3):
        depth, _ = _inputs(seed)
        x = policy.preprocess_depth(depth)
        assert x.shape == (1, 1, policy.meta.input_height, policy.meta.input_width)
        np.testing.assert_array_equal(x[0, 0].numpy(), policy.file_preprocess_depth(depth))


def test_the_network_entry_and_the_files_state_encoding_give_the_same_output(policies) -> None:
    policy = policies["local_poly_net"]
    assert policy.has_forward_net and not policies["world"].has_forward_net
    depth, (p, v, q, g) = _inputs(5)
    x = policy.preprocess_depth(depth)
    state_x, y = policy.network_output(x, p, v, q, g)
    assert state_x.shape == (13,) and y.shape == (policy.meta.network_output_dim,) and y.dtype == np.float32
    rows = [as_row(a, n, name) for a, n, name in [(p, 3, "p"), (v, 3, "v"), (q, 4, "q"), (g, 3, "g")]]
    with torch.inference_mode():
        via_file = policy.module.forward_prepared(x, *rows).reshape(-1).numpy()
    np.testing.assert_allclose(y, via_file, rtol=0, atol=1e-6)


def test_bad_odometry_is_refused_naming_the_input(policies) -> None:
    policy = policies["world"]
    depth, (p, v, q, g) = _inputs(6)
    x = policy.preprocess_depth(depth)
    with pytest.raises(ValueError, match="v_world has a NaN/Inf element"):
        policy.network_output(x, p, np.array([0.0, np.nan, 0.0]), q, g)
    with pytest.raises(ValueError, match="q_world_body is zero"):
        policy.network_output(x, p, v, np.zeros(4), g)
    with pytest.raises(ValueError, match=r"goal_world must have 3 values, got shape \(2,\)"):
        policy.network_output(x, p, v, q, g[:2])
    with pytest.raises(ValueError, match=r"non-empty \(H, W\) array"):
        policy.preprocess_depth(np.zeros((3, 0), np.float32))


def test_metadata_errors_name_the_key(policies) -> None:
    _, meta = load_exported(policies["world"].path)
    assert parse_policy_meta(json.dumps(meta), "p.ts").num_ctrl_pts == 10
    cases = [
        (("output", "network_representation", "spline"), "'output.network_representation' must be"),
        (
            ("preprocessing", "max_depth_m", None),
            "p.ts: policy metadata key 'preprocessing.max_depth_m' is missing",
        ),
        (("output", "bspline_order", 4), "'output.bspline_order' must be 3"),
        (("output", "hypotheses", 9), r"'output.hypotheses' must be an integer in \[1, 8\]"),
        (("output", "hypotheses_first", "best"), "'output.hypotheses_first' must be 'confidence' or 'mean'"),
    ]
    for (section, key, value), message in cases:
        bad = copy.deepcopy(meta)
        if value is None:
            del bad[section][key]
        else:
            bad[section][key] = value
        with pytest.raises(PolicyFormatError, match=message):
            parse_policy_meta(json.dumps(bad), "p.ts")
    bad = copy.deepcopy(meta)
    bad["format"] = "quad_il_policy/9"
    with pytest.raises(PolicyFormatError, match="unsupported policy format 'quad_il_policy/9'"):
        parse_policy_meta(json.dumps(bad), "p.ts")
    with pytest.raises(ValueError):  # PolicyFormatError is a ValueError
        parse_policy_meta("{not json", "p.ts")


def test_hypotheses_metadata_is_read_and_defaults_to_one(policies) -> None:
    h3 = policies["world_h3"].meta
    assert h3.hypotheses == 3 and h3.output_dim == 30 and h3.network_output_dim == 93
    _, meta = load_exported(policies["world"].path)
    del meta["output"]["hypotheses"]  # files exported before multiple hypotheses
    old = parse_policy_meta(json.dumps(meta), "p.ts")
    assert old.hypotheses == 1 and old.network_output_dim == old.output_dim == 30
    meta["output"]["hypotheses"] = 3
    meta["output"]["hypotheses_first"] = "mean"
    assert parse_policy_meta(json.dumps(meta), "p.ts").mean_first


@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_the_file_refuses_metadata_that_disagrees_with_it(tmp_path: Path, policies) -> None:
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
    module, meta = load_exported(policies["world"].path)
    meta["output"]["num_ctrl_pts"] = 12
    torch.jit.save(module, str(tmp_path / "lying3.ts"), _extra_files={META_FILE: json.dumps(meta)})
    with pytest.raises(
        PolicyFormatError, match="attribute num_ctrl_pts = 10 disagrees with the metadata's 12"
    ):
        LoadedPolicy(tmp_path / "lying3.ts")


@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_files_that_are_not_policy_exports_are_refused(tmp_path: Path) -> None:
    plain = torch.jit.script(torch.nn.Linear(2, 2))
    torch.jit.save(plain, str(tmp_path / "plain.ts"))
    with pytest.raises(PolicyFormatError, match="not a quad_il policy export"):
        LoadedPolicy(tmp_path / "plain.ts")
    with pytest.raises(FileNotFoundError):
        LoadedPolicy(tmp_path / "missing.ts")
    (tmp_path / "text.ts").write_text("not a zip")
    with pytest.raises(PolicyFormatError, match="text.ts"):
        LoadedPolicy(tmp_path / "text.ts")


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
    cam = back.camera(1)
    assert cam.width == 8 and cam.height == 6 and cam.fx == 4.0
    np.testing.assert_allclose(cam.T_world_camera[:3, 3], fx.p_world_body[1])
    np.save(tmp_path / "fx" / "goal_world.npy", np.zeros((2, 3)))
    with pytest.raises(FixtureError, match="goal_world.npy: shape"):
        read_fixture(tmp_path / "fx")
    (tmp_path / "fx" / "stamp_s.npy").unlink()
    with pytest.raises(FixtureError, match="stamp_s.npy: missing"):
        read_fixture(tmp_path / "fx")
