"""Resuming a collection run (quad_il.collection.resume, collect.launch resume:=true): the launch-time checks
that need no ROS. The whole fault (master killed, then the same command again) is
tests/rostest/collect_master_kill.test; appending and truncating in the C++ writer are DatasetWriter.Append*
in cpp_data_collector's gtest."""

from __future__ import annotations

from pathlib import Path

import pytest
from test_data_writer import config, sample

from quad_il.collection.episodes import EpisodeLog, EpisodeOutcome, manager_config, plan_episode
from quad_il.collection.prepare import PrepareError, prepare_output_dir
from quad_il.collection.resume import RUN_FILE, ResumeError, plan_resume, run_identity
from quad_il.data.writer import DatasetWriter

ROOT = Path(__file__).resolve().parents[2]


def run_args(tmp_path: Path, **changes: str) -> dict[str, str]:
    args = {
        "seeds": "4,5",
        "episodes": "2",
        "max_samples": "0",
        "episode_timeout_s": "0",
        "time_mode": "lockstep",
        "time_factor": "1.0",
        "collect_config": str(ROOT / "tests" / "rostest" / "collect_test.yaml"),
        "collector_config": str(ROOT / "config" / "collector.yaml"),
        "sim_config": str(ROOT / "config" / "sim.yaml"),
        "planner_config": str(ROOT / "config" / "planner.yaml"),
        "tracker_config": str(ROOT / "config" / "tracker.yaml"),
        "vehicle_config": str(ROOT / "config" / "vehicle.yaml"),
    }
    args.update(changes)
    return args


def test_a_fresh_run_records_its_identity_and_resuming_it_with_other_arguments_is_refused(
    tmp_path: Path,
) -> None:
    out = tmp_path / "ds"
    prepare_output_dir(str(out), run_args=run_args(tmp_path))
    identity = (out / RUN_FILE).read_text()
    assert "seeds: 4,5" in identity and "collect_config: sha256:" in identity
    EpisodeLog(out / "episodes.csv").append(EpisodeOutcome(0, 4, "goal_reached", "", 7.0, 0))
    # Seeds written as a range are the same run; other seeds are not.
    prepare_output_dir(str(out), resume=True, run_args=run_args(tmp_path, seeds="4-5"))
    with pytest.raises(PrepareError, match=r"was collected with seeds '4,5', this launch has '4,6'"):
        prepare_output_dir(str(out), resume=True, run_args=run_args(tmp_path, seeds="4,6"))
    # A config file is compared by content, whatever its path.
    edited = tmp_path / "collect.yaml"
    edited.write_text((ROOT / "tests" / "rostest" / "collect_test.yaml").read_text() + "\n# same keys\n")
    with pytest.raises(PrepareError, match=r"the content of collect_config differs"):
        prepare_output_dir(str(out), resume=True, run_args=run_args(tmp_path, collect_config=str(edited)))
    assert (out / RUN_FILE).read_text() == identity  # a refused resume changes nothing


def test_without_resume_a_started_run_is_refused_naming_resume(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    prepare_output_dir(str(out), run_args=run_args(tmp_path))
    EpisodeLog(out / "episodes.csv").append(EpisodeOutcome(0, 4, "goal_reached", "", 7.0, 0))
    with pytest.raises(PrepareError, match=r"already holds a dataset \(episodes.csv\).*resume:=true"):
        prepare_output_dir(str(out), run_args=run_args(tmp_path))


def test_a_collection_without_its_identity_cannot_be_resumed(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    out.mkdir()
    EpisodeLog(out / "episodes.csv").append(EpisodeOutcome(0, 4, "goal_reached", "", 7.0, 0))
    with pytest.raises(ResumeError, match=r"holds a collection without collect_run.yaml"):
        plan_resume(out, run_identity(run_args(tmp_path)), {})


def test_rows_without_records_on_disk_are_flown_again(tmp_path: Path) -> None:
    """Episodes that recorded nothing (a refused goal) stay finished; a row claiming samples without any
    dataset (the planner died before its writer started) is an error, not silently dropped."""
    out = tmp_path / "ds"
    args = run_args(tmp_path)
    prepare_output_dir(str(out), run_args=args)
    log = EpisodeLog(out / "episodes.csv")
    log.append(EpisodeOutcome(0, 4, "goal_rejected", "goal rejected: occupied", 0.0, 0))
    log.close()
    plan = plan_resume(out, run_identity(args), {})
    assert [r.index for r in plan.finished] == [0] and plan.actions == []
    log = EpisodeLog(out / "episodes.csv")
    log.append(EpisodeOutcome(1, 5, "goal_reached", "", 7.0, 12))
    log.close()
    with pytest.raises(
        ResumeError, match=r"episodes.csv lists recorded samples but there is no manifest.yaml"
    ):
        plan_resume(out, run_identity(args), {})


def test_a_row_cut_short_by_a_crash_is_ignored_and_a_bad_row_is_an_error(tmp_path: Path) -> None:
    path = tmp_path / "episodes.csv"
    log = EpisodeLog(path)
    log.append(EpisodeOutcome(0, 4, "goal_reached", "goal reached, at t=8 s", 7.0, 16))
    log.close()
    with open(path, "a") as f:
        f.write("1,5,goal_rea")  # killed inside write(2)
    assert [r.index for r in EpisodeLog.read(path)] == [0]
    path.write_text(path.read_text() + "ched,,7.0,14\nx,5,goal_reached,,1.0,3\n")
    with pytest.raises(ValueError, match=r"episodes.csv: line 4 is not an episode row"):
        EpisodeLog.read(path)


def _dataset_of_episode_zero(out: Path, args: dict[str, str], episode_id: int) -> int:
    """A finalised dataset holding 3 records of episode 0 (its goal, the given episode id) and its
    episodes.csv row; returns the record count."""
    goal = plan_episode(manager_config(args["collect_config"], {"seeds": "4,5"}), 0).goal_world
    w = DatasetWriter(config(out))
    for i in range(3):
        assert w.record(sample(i, episode_id=episode_id, goal_world=list(goal)))[0] == "queued"
    assert w.finalize()
    log = EpisodeLog(out / "episodes.csv")
    log.append(EpisodeOutcome(0, 4, "goal_reached", "", 7.0, 3))
    log.close()
    return 3


def test_a_dataset_of_keyed_episodes_resumes_and_one_collected_before_keys_is_refused(tmp_path: Path) -> None:
    """Resumed episodes are keyed (issue 32): they get the ids a straight run gives them (index + 1), which
    only continue a dataset whose finished episodes carry theirs; an older dataset (ids counted by the
    simulator process) is refused naming the record, the id and the fix."""
    args = run_args(tmp_path)
    params = {"config": args["collect_config"], "seeds": "4,5"}
    keyed = tmp_path / "keyed"
    prepare_output_dir(str(keyed), run_args=args)
    n = _dataset_of_episode_zero(keyed, args, episode_id=1)
    plan = plan_resume(keyed, run_identity(args), params)
    assert [r.index for r in plan.finished] == [0] and plan.records_kept == n and plan.records_cut == 0
    legacy = tmp_path / "legacy"
    prepare_output_dir(str(legacy), run_args=args)
    _dataset_of_episode_zero(legacy, args, episode_id=2)  # the unkeyed simulator's second episode
    with pytest.raises(
        ResumeError,
        match=r"record 0 of finished episode 0 has episode id 2, not its keyed id 1: the dataset was "
        r"collected before episodes were keyed \(issue 32\) and cannot be resumed; pass another output_dir",
    ):
        plan_resume(legacy, run_identity(args), params)
