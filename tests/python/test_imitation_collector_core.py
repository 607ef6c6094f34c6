"""The ROS-agnostic parts of the rospy collector: message conversion and the pair -> learner -> dataset
glue."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from quad_il.imitation import EpisodeOutcome, ImitationError, Observation, RoundAlgorithmConfig, SplineAction
from quad_il.imitation.collector_core import (
    CollectorCore,
    CollectorCounters,
    EpisodeBook,
    collector_manifest,
    expert_noise_from_param,
    load_round_config,
    perturb_spline,
)
from quad_il.imitation.config import HGDAggerConfig
from quad_il.imitation.dataset import read_records, read_round
from quad_il.imitation.learners import make_learner
from quad_il.imitation.messages import depth_from_msg, spline_from_msg
from quad_il.imitation.pairing import StampPairer
from quad_il.imitation.wait_peers import missing_peers, parse_counts


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


def test_expert_noise_keeps_the_start_state_and_perturbs_the_rest() -> None:
    ctrl = np.stack([np.arange(8.0), np.zeros(8), np.ones(8)], axis=1)
    knots = np.arange(-0.3, 0.9, 0.1)[:12]
    a = SplineAction(ctrl, knots, 3, 1.5, 9)
    b = perturb_spline(a, 0.2, np.random.default_rng(0))
    np.testing.assert_array_equal(b.ctrl_pts_world[:3], ctrl[:3])  # position, velocity, acceleration at t0
    d = b.ctrl_pts_world[3:] - ctrl[3:]
    assert np.all(d != 0.0) and 0.05 < d.std() < 0.4
    np.testing.assert_array_equal(b.knots, a.knots)
    assert (b.start_time_s, b.traj_id, b.order) == (1.5, 9, 3)
    np.testing.assert_array_equal(perturb_spline(a, 0.0, np.random.default_rng(0)).ctrl_pts_world, ctrl)
    with pytest.raises(ImitationError, match="expert noise std must be a finite number >= 0 m, got -0.1"):
        perturb_spline(a, -0.1, np.random.default_rng(0))


def test_expert_noise_parameter_names_what_is_wrong() -> None:
    topics = {"expert_a": "/a", "expert_b": "/b"}
    assert expert_noise_from_param({}, topics) == {}
    assert expert_noise_from_param({"expert_b": 0.15}, topics) == {"expert_b": 0.15}
    with pytest.raises(
        ImitationError, match=r"names 'expert_c', which is not in ~expert_topics \['expert_a'"
    ):
        expert_noise_from_param({"expert_c": 0.1}, topics)
    with pytest.raises(ImitationError, match=r"\['expert_a'\] must be finite and >= 0 m, got -1"):
        expert_noise_from_param({"expert_a": -1}, topics)
    with pytest.raises(ImitationError, match=r"must be a number of metres, got 'lots'"):
        expert_noise_from_param({"expert_a": "lots"}, topics)
    with pytest.raises(ImitationError, match=r"must be a mapping \{expert: metres\}, got 0.1"):
        expert_noise_from_param(0.1, topics)


def test_depth_images_honour_the_row_stride_and_encoding() -> None:
    img = np.arange(12, dtype=np.float32).reshape(3, 4)
    padded = np.zeros((3, 6), dtype=np.float32)
    padded[:, :4] = img
    msg = SimpleNamespace(encoding="32FC1", is_bigendian=0, height=3, width=4, step=24, data=padded.tobytes())
    np.testing.assert_array_equal(depth_from_msg(msg), img)
    with pytest.raises(ImitationError, match="must be 32FC1, got '16UC1'"):
        depth_from_msg(SimpleNamespace(encoding="16UC1"))


def test_the_core_pairs_decides_and_appends_each_episode_to_the_rounds_dataset(tmp_path: Path) -> None:
    cfg_path = tmp_path / "algorithm.yaml"
    cfg_path.write_text(
        "algorithm: {name: hg_dagger, gate: {on_threshold_m: 1.0, off_threshold_m: 0.5}}\n"
        "round_index: 2\nseed: 5\n"
    )
    cfg = load_round_config(cfg_path)
    assert isinstance(cfg, RoundAlgorithmConfig) and isinstance(cfg.algorithm, HGDAggerConfig)
    learner = make_learner(cfg, np.random.default_rng(cfg.seed))
    core = CollectorCore(
        learner, ["expert", "learner"], "expert", tmp_path / "data", {"round_index": "2"}, fsync=False
    )
    base = np.column_stack([np.linspace(0, 3, 6), np.zeros(6), np.ones(6)])
    learner.start_episode(9)
    flown = []
    for i, offset in enumerate([0.0, 2.0, 0.1]):
        t = 0.1 * i
        depth = np.full((12, 16), 3.0, dtype=np.float32)
        obs = Observation(t, i, 9, [0, 0, 1], [0, 0, 0], [0, 0, 0, 1], [5, 0, 1], depth_m=depth)
        core.pairer.add_observation(obs)
        core.pairer.add_action("expert", t, SplineAction.uniform(base, 0.5, start_time_s=t))
        frames = core.pairer.add_action(
            "learner", t, SplineAction.uniform(base + [0, offset, 0], 0.5, start_time_s=t)
        )
        flown += [d.controller.value for _, d in core.frames(frames)]
    core.finish_episode(9, EpisodeOutcome(reached_goal=True), world_seed=77, camera_fx_px=9.5)
    assert core.finalize()
    assert flown == ["learner", "expert", "learner"]
    (rec,) = read_records(tmp_path / "data")
    assert rec.obs.stamp_s == 0.1 and rec.round_index == 2 and rec.partition.value == "intervention"
    assert rec.obs.episode_id == 9 and rec.source == "expert" and rec.controller.value == "expert"
    assert core.episodes_written == 1 and core.records_written == 1 and core.files_written == 1
    data = read_round(tmp_path / "data")
    assert data is not None and data.manifest is not None
    assert data.manifest["status"] == "complete" and data.manifest["config"]["camera"]["fx_px"] == 9.5
    assert data.records["world_seed"].tolist() == [77]
    # An episode without records writes nothing; the count of closed episodes still moves.
    learner.start_episode(10)
    core.finish_episode(10, EpisodeOutcome(), flown=False)
    assert core.episodes_written == 2 and core.episodes_flown == 1 and core.files_written == 1


def test_an_empty_bspline_message_means_no_plan() -> None:
    msg = SimpleNamespace(order=3, traj_id=0, start_time=_time(1.0), knots=[], pos_pts=[])
    assert spline_from_msg(msg) is None


def test_episode_book_follows_status_and_ignores_stale_goals() -> None:
    book = EpisodeBook()
    assert book.status(1, True, 0.0, world_seed=41) == [("start", 1, False)]
    assert book.world_seeds == {1: 41}
    assert not book.flying
    assert book.status(1, True, 1.0) == []  # the periodic repeat
    # The reset: episode 1 ends unflown, episode 2 starts at 3.0 s; the latched goal of 2.5 s is stale.
    assert book.status(2, True, 3.0) == [("end", 1, False), ("start", 2, False)]
    assert not book.set_goal(2.5, np.zeros(3)) and not book.flying
    assert book.set_goal(3.2, np.array([5.0, 0.0, 1.0])) and book.flying
    np.testing.assert_array_equal(book.goal, [5.0, 0.0, 1.0])
    # Goal reached: the episode ends (flown); its repeated final status does not reopen it.
    assert book.status(2, False, 9.0) == [("end", 2, True)]
    assert book.status(2, False, 10.0) == [] and book.episode_id is None
    assert not book.set_goal(10.5, np.zeros(3))
    assert book.status(3, True, 11.0) == [("start", 3, False)]


def test_pairer_reports_waiting_sources_and_flushes_everything() -> None:
    pairer = StampPairer(["expert", "learner"])
    obs = Observation(1.5, 3, 1, [0, 0, 1], [0, 0, 0], [0, 0, 0, 1], [5, 0, 1])
    assert not pairer.waiting_for("expert", 1.5)  # no observation yet
    pairer.add_observation(obs)
    assert pairer.waiting_for("expert", 1.5) and pairer.waiting_for("learner", 1.5)
    pairer.add_action("expert", 1.5, None)
    assert not pairer.waiting_for("expert", 1.5) and pairer.waiting_for("learner", 1.5)
    (frame,) = pairer.flush_all()
    assert frame.obs is obs and frame.actions == {"expert": None, "learner": None}
    assert pairer.pending == 0 and pairer.flush_all() == []


def test_wait_peers_names_what_is_missing() -> None:
    state = [[("/sim/frame_ack", ["/a", "/b"])], [("/camera/depth/image", ["/a"])], []]
    assert missing_peers(state, {"/sim/frame_ack": 2}, {"/camera/depth/image": 1}) == []
    assert missing_peers(state, {"/sim/frame_ack": 3}, {"/camera/depth/image": 2, "/odom": 1}) == [
        "1 publisher(s) of /sim/frame_ack",
        "1 subscriber(s) of /camera/depth/image",
        "1 subscriber(s) of /odom",
    ]
    with pytest.raises(ValueError, match="expected topic=COUNT"):
        parse_counts(["=2"], "--publishers")
    with pytest.raises(ValueError, match="expected topic=COUNT"):
        parse_counts(["~frame_ack=2"], "--publishers")
    # Relative names resolve in the command's namespace (ROS_NAMESPACE), global ones stay.
    assert parse_counts(["sim/frame_ack=2", "/clock=1"], "--publishers", "/a") == {
        "/a/sim/frame_ack": 2,
        "/clock": 1,
    }
    assert parse_counts(["sim/frame_ack=2"], "--publishers") == {"/sim/frame_ack": 2}
    with pytest.raises(ValueError, match="COUNT must be an integer"):
        parse_counts(["/sim/frame_ack=two"], "--publishers")


def test_a_writer_failure_is_kept_and_later_episodes_are_not_written(tmp_path: Path) -> None:
    cfg = RoundAlgorithmConfig.model_validate({"algorithm": {"name": "bc"}, "round_index": 0, "seed": 1})
    learner = make_learner(cfg, np.random.default_rng(1))
    core = CollectorCore(learner, ["expert"], "expert", tmp_path / "data", {"round_index": "0"}, fsync=False)
    calls = []

    def failing_write(world_seed: int, records: list, **kw: object) -> int:
        calls.append(len(records))
        raise ImitationError("dataset writer failed: cannot write X/shard_000000.qdr.partial: File too large")

    core.writer.write = failing_write  # type: ignore[method-assign]
    base = np.column_stack([np.linspace(0, 3, 6), np.zeros(6), np.ones(6)])
    for eid in (1, 2):
        learner.start_episode(eid)
        obs = Observation(0.1 * eid, eid, eid, [0, 0, 1], [0, 0, 0], [0, 0, 0, 1], [5, 0, 1])
        core.frames(core.pairer.add_observation(obs))
        core.frames(core.pairer.add_action("expert", 0.1 * eid, SplineAction.uniform(base, 0.5)))
        core.finish_episode(eid, EpisodeOutcome())
    assert calls == [1]  # the second episode is not offered to a failed writer
    assert core.write_error.endswith("File too large") and core.episodes_written == 2
    assert collector_manifest(cfg, core, False, CollectorCounters())["dataset_error"] == core.write_error
