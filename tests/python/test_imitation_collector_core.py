"""The ROS-agnostic parts of the rospy collector: message conversion and the pair -> learner -> file glue."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from quad_il.imitation import EpisodeOutcome, ImitationError, Observation, RoundAlgorithmConfig, SplineAction
from quad_il.imitation.config import HGDAggerConfig
from quad_il.imitation.dataset import read_episode
from quad_il.imitation.learners import make_learner
from quad_il.imitation.ros_collector import CollectorCore, depth_from_msg, load_round_config, spline_from_msg


def _time(t: float) -> SimpleNamespace:
    return SimpleNamespace(to_sec=lambda: t)


def test_bspline_messages_convert_to_validated_actions() -> None:
    pts = [SimpleNamespace(x=float(i), y=0.0, z=1.0) for i in range(5)]
    knots = [-0.3, -0.2, -0.1, 0.0, 0.1, 0.2, 0.3, 0.4, 0.5]
    msg = SimpleNamespace(order=3, traj_id=4, start_time=_time(2.5), knots=knots, pos_pts=pts)
    a = spline_from_msg(msg)
    assert a.num_ctrl == 5 and a.start_time_s == 2.5 and a.traj_id == 4
    np.testing.assert_allclose(a.knots, knots)
    with pytest.raises(ValueError, match="knots must have"):
        spline_from_msg(
            SimpleNamespace(order=3, traj_id=0, start_time=_time(0.0), knots=knots[:-1], pos_pts=pts)
        )


def test_depth_images_honour_the_row_stride_and_encoding() -> None:
    img = np.arange(12, dtype=np.float32).reshape(3, 4)
    padded = np.zeros((3, 6), dtype=np.float32)
    padded[:, :4] = img
    msg = SimpleNamespace(encoding="32FC1", is_bigendian=0, height=3, width=4, step=24, data=padded.tobytes())
    np.testing.assert_array_equal(depth_from_msg(msg), img)
    with pytest.raises(ImitationError, match="must be 32FC1, got '16UC1'"):
        depth_from_msg(SimpleNamespace(encoding="16UC1"))


def test_the_core_pairs_decides_and_writes_one_file_per_episode(tmp_path: Path) -> None:
    cfg_path = tmp_path / "algorithm.yaml"
    cfg_path.write_text(
        "algorithm: {name: hg_dagger, gate: {on_threshold_m: 1.0, off_threshold_m: 0.5}}\n"
        "round_index: 2\nseed: 5\n"
    )
    cfg = load_round_config(cfg_path)
    assert isinstance(cfg, RoundAlgorithmConfig) and isinstance(cfg.algorithm, HGDAggerConfig)
    learner = make_learner(cfg, np.random.default_rng(cfg.seed))
    core = CollectorCore(learner, ["expert", "learner"], "expert", tmp_path / "data")
    base = np.column_stack([np.linspace(0, 3, 6), np.zeros(6), np.ones(6)])
    learner.start_episode(9)
    flown = []
    for i, offset in enumerate([0.0, 2.0, 0.1]):
        t = 0.1 * i
        obs = Observation(t, i, 9, [0, 0, 1], [0, 0, 0], [0, 0, 0, 1], [5, 0, 1])
        core.pairer.add_observation(obs)
        core.pairer.add_action("expert", t, SplineAction.uniform(base, 0.5, start_time_s=t))
        frames = core.pairer.add_action(
            "learner", t, SplineAction.uniform(base + [0, offset, 0], 0.5, start_time_s=t)
        )
        flown += [d.controller.value for _, d in core.frames(frames)]
    core.finish_episode(9, EpisodeOutcome(reached_goal=True))
    assert flown == ["learner", "expert", "learner"]
    (rec,) = read_episode(tmp_path / "data" / "episode_000009.npz")
    assert rec.obs.frame_seq == 1 and rec.round_index == 2 and rec.partition.value == "intervention"
    assert core.episodes_written == 1 and core.records_written == 1
