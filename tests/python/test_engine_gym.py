"""The engine's Gymnasium environments (quad_il.engine.gym_env, docs/engine.md "Gymnasium"): check_env, the
spaces, keyed episodes (the same seed gives the same episode), labels and decisions in info, the vector env's
batch and autoreset, and the docs' example. Needs the built workspace (quad_engine_py)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("gymnasium")
engine = pytest.importorskip("quad_il.engine")
try:
    engine.native()
except engine.EngineNotBuiltError as exc:  # pragma: no cover - the workspace is built in CI
    pytest.skip(str(exc), allow_module_level=True)

from gymnasium.utils.env_checker import check_env  # noqa: E402

SHORT = {"episode_timeout_s": 2.0}


@pytest.fixture(scope="module")
def env():
    e = engine.make_env(seed=9000, labeller=True, **SHORT)
    yield e
    e.close()


def test_the_env_passes_gymnasiums_checker(env) -> None:
    check_env(env, skip_render_check=True)


def test_spaces_come_from_the_policy_metadata(env) -> None:
    obs, _ = env.reset(seed=9000)
    assert obs["depth"].shape == env.observation_space["depth"].shape
    assert obs["depth"].dtype == np.float32 and 0.0 <= obs["depth"].min() <= obs["depth"].max() <= 1.0
    assert obs["state"].shape == (13,)
    assert env.action_space.shape[0] == 30  # config/train.yaml: 10 control points x 3, one hypothesis
    assert env.observation_space.contains(obs)


def test_an_episode_is_keyed_by_seed_and_index(env) -> None:
    a, info_a = env.reset(seed=9001)
    b, info_b = env.reset(options={"index": 0, "world_seed": 9001})
    assert info_a["world_seed"] == info_b["world_seed"] == 9001 and info_a["index"] == info_b["index"] == 0
    for k in ("depth", "state", "goal"):
        np.testing.assert_array_equal(a[k], b[k])
    c, info_c = env.reset(options={"index": 1, "world_seed": 9001})
    assert not np.array_equal(a["goal"], c["goal"]), "another index must be another episode"


def test_steps_carry_the_decision_and_the_experts_label(env) -> None:
    env.reset(seed=9000)
    obs, reward, terminated, truncated, info = env.step(np.zeros(env.action_space.shape, np.float32))
    # All-zero control points start far from the vehicle: the decider refuses and stops.
    assert info["decision"]["accepted"] is False
    assert info["decision"]["verdict"] == "start_far_from_vehicle"
    assert "start" in info["decision"]["reason"]
    label = info["label"]
    assert label["ok"], label["reason"]
    assert label["ctrl_pts"].shape[1] == 3 and len(label["knots"]) == label["ctrl_pts"].shape[0] + 4
    done = terminated or truncated
    while not done:
        obs, reward, terminated, truncated, info = env.step(np.zeros(env.action_space.shape, np.float32))
        done = terminated or truncated
    assert info["outcome"] in ("timeout", "collision", "goal_reached")
    assert truncated == (info["outcome"] == "timeout")
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(env.action_space.shape, np.float32))


def test_unknown_options_are_refused_naming_them() -> None:
    with pytest.raises(TypeError, match="polciy"):
        engine.make_env(polciy="x.ts")


def test_the_vector_env_steps_a_batch_and_resets_ended_episodes() -> None:
    venv = engine.make_vec_env(3, seed=9000, labeller=False, **SHORT)
    obs, _ = venv.reset()
    assert obs["depth"].shape[0] == 3 and obs["state"].shape == (3, 13)
    one = engine.make_env(seed=9000, labeller=False, **SHORT)
    single, _ = one.reset(options={"index": 2, "world_seed": 9002})
    np.testing.assert_array_equal(obs["state"][2], single["state"])  # env k flies episode k, world seed+k
    ended = 0
    for _ in range(400):
        obs, reward, terminated, truncated, info = venv.step(np.zeros((3, 30), np.float32))
        ended += int(np.sum(terminated | truncated))
        if ended >= 3:
            break
    assert ended >= 3
    assert venv.observation_space.contains(obs)


def test_the_docs_example_runs() -> None:
    venv = engine.make_vec_env(2, seed=9000, labeller=False, **SHORT)
    obs, info = venv.reset()
    outcomes: list[str] = []
    steps = 0
    while len(outcomes) < 2 and steps < 500:
        obs, reward, terminated, truncated, info = venv.step(venv.action_space.sample())
        outcomes += [info["outcome"][k] for k in np.flatnonzero(terminated | truncated)]
        steps += 1
    assert len(outcomes) >= 2 and set(outcomes) <= {"goal_reached", "collision", "timeout"}
