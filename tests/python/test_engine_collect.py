"""The engine's command-line tools without ROS (docs/engine.md): engine collection (key order, resume, bad
arguments), a DAgger round whose dataset the training's loader reads, and the evaluation's engine backend.
Parity with collect.launch is tests/python/test_engine_parity.py. Needs the built workspace."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

engine = pytest.importorskip("quad_il.engine")
try:
    engine.native()
except engine.EngineNotBuiltError as exc:  # pragma: no cover - the workspace is built in CI
    pytest.skip(str(exc), allow_module_level=True)

from quad_il.collection.episodes import EpisodeLog  # noqa: E402
from quad_il.collection.prepare import PrepareError  # noqa: E402
from quad_il.engine import collect, dagger  # noqa: E402
from quad_il.evaluation import run_eval  # noqa: E402
from quad_il.evaluation.episodes import read_results  # noqa: E402
from quad_il.inference.random_policy import export_goal_line_policy  # noqa: E402
from quad_il.learning.dataset import expand_paths, read_source  # noqa: E402

PRIVILEGED = "config/planner_privileged.yaml"  # the fast expert keeps these tests short


def test_a_run_records_every_episode_and_a_resumed_complete_run_flies_nothing(tmp_path) -> None:
    out = tmp_path / "run"
    r = collect.collect(out, "1,2", 2, workers=2, planner_config=PRIVILEGED, progress=False)
    assert r.complete and r.episodes == 2
    rows = EpisodeLog.read(out / "episodes.csv")
    assert [(o.index, o.seed) for o in rows] == [(0, 1), (1, 2)]
    arrays = read_source(*expand_paths([out])[0])
    assert len(arrays["episode_id"]) == r.samples == sum(o.samples for o in rows)
    # Key order: every record of episode 0 (id 1) before those of episode 1 (id 2).
    ids = np.asarray(arrays["episode_id"])
    assert list(ids) == sorted(ids) and set(ids) == {1, 2}
    summary = yaml.safe_load((out / "collect_summary.yaml").read_text())
    assert summary["complete"] and summary["samples"] == r.samples
    again = collect.collect(out, "1,2", 2, workers=1, planner_config=PRIVILEGED, resume=True, progress=False)
    assert again.complete and again.samples == r.samples
    assert len(read_source(*expand_paths([out])[0])["episode_id"]) == r.samples


def test_a_directory_holding_a_dataset_is_refused_without_resume(tmp_path) -> None:
    out = tmp_path / "run"
    collect.collect(out, "1", 1, planner_config=PRIVILEGED, progress=False)
    with pytest.raises(PrepareError, match="already holds a dataset"):
        collect.collect(out, "1", 1, planner_config=PRIVILEGED, progress=False)
    with pytest.raises(ValueError, match="episodes"):  # resuming with other arguments names the one
        collect.collect(out, "1", 2, planner_config=PRIVILEGED, resume=True, progress=False)


def test_bad_arguments_name_what_is_wrong(tmp_path, capsys) -> None:
    assert collect.main(["--out", str(tmp_path / "a"), "--planner-config", "config/nope.yaml"]) == 2
    assert "planner_config" in capsys.readouterr().err
    with pytest.raises(ValueError, match="backend 'mpi'"):
        collect.collect(tmp_path / "b", "1", 1, backend="mpi", progress=False)
    assert dagger.main(["--policy", str(tmp_path / "none.ts"), "--out", str(tmp_path / "c")]) == 2
    assert "no such file" in capsys.readouterr().err
    policy = export_goal_line_policy(tmp_path / "p.ts")
    argv = ["--policy", str(policy), "--out", str(tmp_path / "d"), "--sim-config", "config/nope.yaml"]
    assert dagger.main(argv) == 2
    assert "sim_config " in capsys.readouterr().err and not (tmp_path / "d").exists()


def test_both_tools_record_one_run_identity(tmp_path) -> None:
    from quad_il.engine.run_identity import collection_run_args
    from quad_il.tools.repo import repo_root

    args = collection_run_args(
        "1-3",
        5,
        0,
        30.0,
        {"sim_config": "config/sim.yaml"},
        {"policy": "p.ts", "policy_config": "config/policy.yaml"},
    )
    assert args["sim_config"] == str(repo_root() / "config" / "sim.yaml")  # relative: under the repository
    assert args["policy"] == str(repo_root() / "p.ts")  # not a config: not checked
    assert (args["episodes"], args["max_samples"], args["time_mode"]) == ("5", "0", "lockstep")
    with pytest.raises(ValueError, match=r"policy_config .*nope.yaml: no such file"):
        collection_run_args("1", 1, 0, 30.0, {}, {"policy_config": str(tmp_path / "nope.yaml")})


@pytest.fixture(scope="module")
def goal_line(tmp_path_factory):
    return export_goal_line_policy(tmp_path_factory.mktemp("policy") / "goal_line.ts")


def test_a_dagger_rounds_labels_are_a_training_dataset(tmp_path, goal_line) -> None:
    out = tmp_path / "round"
    s = dagger.run_round(
        str(goal_line),
        str(out),
        "1,2",
        2,
        slots=2,
        planner_config=PRIVILEGED,
        episode_timeout_s=2.0,
        progress=False,
    )
    assert s["complete"] and s["episodes"] == 2 and s["labels"] > 0
    assert s["decisions_per_forward_pass"] >= 1.0
    rows = EpisodeLog.read(out / "episodes.csv")
    assert [o.index for o in rows] == [0, 1] and sum(o.samples for o in rows) == s["labels"]
    arrays = read_source(*expand_paths([out])[0])
    assert len(arrays["episode_id"]) == s["labels"]
    assert set(np.asarray(arrays["episode_id"])) <= {1, 2}


def test_the_evaluations_engine_backend_writes_the_runners_results(tmp_path, goal_line) -> None:
    out = tmp_path / "eval"
    code = run_eval.main(
        [
            "--policy",
            str(goal_line),
            "--seeds",
            "9000-9001",
            "--episodes",
            "2",
            "--out",
            str(out),
            "--episode-timeout-s",
            "3",
            "--controllers",
            "expert,cpp",
        ]
    )
    assert code == 0
    for controller in ("expert", "cpp"):
        results = read_results(out / f"{controller}.jsonl")
        assert sorted(r.index for r in results) == [0, 1]  # in completion order
        for r in results:
            assert r.outcome in ("goal_reached", "collision", "timeout"), r
            assert r.lockstep_timeouts == 0 and r.flight_time_s > 0 and r.path_length_m > 0
    cpp = read_results(out / "cpp.jsonl")
    assert all(r.decisions > 0 and r.counts for r in cpp)
    assert json.loads((out / "pin.json").read_text())["backend"] == "engine"
    # A resume on the other backend is refused: the pin names the backend.
    assert (
        run_eval.main(
            [
                "--controllers",
                "expert",
                "--seeds",
                "9000-9001",
                "--episodes",
                "2",
                "--out",
                str(out),
                "--episode-timeout-s",
                "3",
                "--backend",
                "ros",
            ]
        )
        == 1
    )


def test_a_rounds_worlds_come_from_its_sim_config_overlay(tmp_path, goal_line) -> None:
    """--sim-config (an overlay: the round's worlds at 1.5x the box density) is the config the round flies and
    records in its identity; the denser worlds give the same episodes other labels."""
    dense = tmp_path / "sim_dense.yaml"
    base = Path(__file__).resolve().parents[2] / "config" / "sim.yaml"
    dense.write_text(  # in tmp_path: its relative vehicle_file would name tmp_path's, so it names config/'s
        f"overlay_of: {base}\nvehicle_file: {base.parent / 'vehicle.yaml'}\n"
        "world:\n  generator:\n    density_boxes_per_100m2: 18.75\n"
    )
    argv = ["--policy", str(goal_line), "--seeds", "1", "--episodes", "1", "--slots", "1"]
    argv += ["--planner-config", PRIVILEGED, "--episode-timeout-s", "2", "--no-progress"]
    assert dagger.main([*argv, "--out", str(tmp_path / "default")]) == 0
    assert dagger.main([*argv, "--out", str(tmp_path / "dense"), "--sim-config", str(dense)]) == 0
    identity = yaml.safe_load((tmp_path / "dense" / "collect_run.yaml").read_text())["identity"]
    assert identity["sim_config"] == "sha256:" + hashlib.sha256(dense.read_bytes()).hexdigest()
    a, b = (read_source(*expand_paths([tmp_path / d])[0]) for d in ("default", "dense"))
    assert len(a["episode_id"]) > 0 and len(b["episode_id"]) > 0
    assert not np.array_equal(np.asarray(a["depth_m"])[:1], np.asarray(b["depth_m"])[:1])


def test_a_killed_dagger_round_resumes_to_the_dataset_of_a_straight_run(tmp_path, goal_line, capsys) -> None:
    """A round killed after writing an episode's labels but before logging it, with its writer dead (the
    manifest left incomplete): --resume recovers the dataset, cuts that episode's records, flies it again and
    ends with the straight run's dataset; other arguments or another learner are refused."""
    kw = dict(slots=2, planner_config=PRIVILEGED, episode_timeout_s=2.0, progress=False)
    straight, killed = tmp_path / "straight", tmp_path / "killed"
    dagger.run_round(str(goal_line), str(straight), "1,2", 2, **kw)
    dagger.run_round(str(goal_line), str(killed), "1,2", 2, **kw)
    rows = EpisodeLog.read(killed / "episodes.csv")
    assert rows[1].samples > 0
    EpisodeLog.rewrite(killed / "episodes.csv", rows[:1])
    manifest = killed / "manifest.yaml"
    manifest.write_text(manifest.read_text().replace("status: complete", "status: incomplete"))
    with pytest.raises(PrepareError, match="already holds a dataset"):
        dagger.run_round(str(goal_line), str(killed), "1,2", 2, **kw)
    with pytest.raises(PrepareError, match=r"collected with episodes .2., this launch has .3."):
        dagger.run_round(str(goal_line), str(tmp_path / "straight"), "1,2", 3, resume=True, **kw)
    other = export_goal_line_policy(tmp_path / "other.ts", speed_mps=1.0)
    with pytest.raises(PrepareError, match="the content of policy differs"):
        dagger.run_round(str(other), str(killed), "1,2", 2, resume=True, **kw)
    capsys.readouterr()
    s = dagger.run_round(str(goal_line), str(killed), "1,2", 2, resume=True, **kw)
    assert s["complete"] and s["episodes"] == 2
    err = capsys.readouterr().err
    assert "quad_il.engine.dagger: resume: recover:" in err
    assert "quad_il.engine.dagger: resume: truncate:" in err
    assert EpisodeLog.read(killed / "episodes.csv") == EpisodeLog.read(straight / "episodes.csv")
    a, b = (read_source(*expand_paths([d])[0]) for d in (straight, killed))
    assert set(a) == set(b)
    for key in a:
        np.testing.assert_array_equal(np.asarray(a[key]), np.asarray(b[key]), err_msg=key)


def test_a_dagger_round_is_the_same_dataset_on_one_worker_or_two(tmp_path, goal_line) -> None:
    arrays = {}
    for workers in (1, 2):
        out = tmp_path / f"w{workers}"
        s = dagger.run_round(
            str(goal_line),
            str(out),
            "1,2,3",
            3,
            slots=2,
            workers=workers,
            planner_config=PRIVILEGED,
            episode_timeout_s=2.0,
            progress=False,
        )
        assert s["complete"] and s["workers"] == workers
        assert [o.index for o in EpisodeLog.read(out / "episodes.csv")] == [0, 1, 2]  # key order
        arrays[workers] = read_source(*expand_paths([out])[0])
    assert len(arrays[1]["episode_id"]) > 0
    assert set(arrays[1]) == set(arrays[2])
    for key in arrays[1]:
        np.testing.assert_array_equal(np.asarray(arrays[1][key]), np.asarray(arrays[2][key]), err_msg=key)


def test_the_evaluations_results_do_not_depend_on_its_workers(tmp_path, goal_line, capsys) -> None:
    results = {}
    for workers in (1, 2):
        out = tmp_path / f"w{workers}"
        args = ["--policy", str(goal_line), "--seeds", "9000-9002", "--episodes", "3", "--out", str(out)]
        args += ["--episode-timeout-s", "3", "--controllers", "cpp", "--workers", str(workers)]
        assert run_eval.main(args) == 0
        results[workers] = sorted(
            (r.index, r.outcome, r.reason, r.flight_time_s, r.path_length_m, r.decisions)
            for r in read_results(out / "cpp.jsonl")
        )
    assert len(results[1]) == 3 and results[1] == results[2]
    with pytest.raises(SystemExit):
        run_eval.main(["--workers", "0", "--out", str(tmp_path / "bad")])
    assert "--workers 0: must be >= 1" in capsys.readouterr().err
    with pytest.raises(ValueError, match="workers 0: must be >= 1"):
        dagger.run_round(str(goal_line), str(tmp_path / "d"), "1", 1, workers=0, progress=False)
