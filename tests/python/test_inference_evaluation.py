"""The ROS-free parts of the closed-loop evaluation: the episode list, clearance geometry against brute force,
per-controller summaries, the results format and the report with its BENCH lines."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from quad_il.collection.episodes import StartGoalConfig
from quad_il.evaluation.episodes import (
    EpisodeResult,
    append_result,
    plan_eval_episodes,
    read_episodes,
    read_results,
    write_episodes,
)
from quad_il.evaluation.metrics import Box, clearance_lower_bound, path_length, point_box_distances, summarise
from quad_il.evaluation.report import bench_lines, write_report
from quad_il.evaluation.run_eval import eval_sim_config, parse_seeds

ROOT = Path(__file__).resolve().parents[2]


def test_episodes_are_seeded_identical_per_call_and_round_trip(tmp_path: Path) -> None:
    cfg = StartGoalConfig()
    a = plan_eval_episodes([9000, 9001, 9002], 7, cfg)
    assert a == plan_eval_episodes([9000, 9001, 9002], 7, cfg)
    assert [s.seed for s in a] == [9000, 9001, 9002, 9000, 9001, 9002, 9000]
    # Episodes in the same world differ (the stream depends on the index too).
    assert a[0].start_world != a[3].start_world
    for s in a:
        d = math.dist(s.start_world[:2], s.goal_world[:2])
        assert cfg.min_distance_m <= d <= cfg.max_distance_m
    write_episodes(tmp_path / "e.json", a)
    assert read_episodes(tmp_path / "e.json") == a
    with pytest.raises(ValueError, match="at least one world seed"):
        plan_eval_episodes([], 3, cfg)


def test_seed_lists_and_ranges_parse() -> None:
    assert parse_seeds("9000-9003,9010") == [9000, 9001, 9002, 9003, 9010]
    with pytest.raises(RuntimeError, match="bad seed range"):
        parse_seeds("5-3")


def _brute_distance(p: np.ndarray, b: Box, n: int = 41) -> float:
    """Distance to a densely sampled solid box (grid of its volume): an upper bound that converges."""
    g = np.linspace(-0.5, 0.5, n)
    local = np.stack(np.meshgrid(g, g, g), -1).reshape(-1, 3) * b.size
    pts = local @ Rotation.from_quat(b.q_xyzw).as_matrix().T + b.center
    return float(np.linalg.norm(pts - p, axis=1).min())


def test_point_to_oriented_box_distance_matches_sampling() -> None:
    rng = np.random.default_rng(5)
    for _ in range(20):
        q = rng.normal(size=4)
        b = Box(rng.uniform(-2, 2, 3), q / np.linalg.norm(q), rng.uniform(0.3, 2.0, 3))
        p = rng.uniform(-4, 4, 3)
        exact = point_box_distances(p[None], [b])[0]
        approx = _brute_distance(p, b)
        cell = float(np.linalg.norm(b.size)) / 40
        assert exact <= approx + 1e-9
        assert approx - exact <= cell
    # Inside: 0; an axis-aligned box: closed form.
    b = Box(np.zeros(3), np.array([0, 0, 0, 1.0]), np.array([2.0, 2.0, 2.0]))
    np.testing.assert_allclose(
        point_box_distances(np.array([[0.5, 0, 0], [3, 0, 0], [2, 2, 1]]), [b]), [0.0, 2.0, math.sqrt(2)]
    )


def test_clearance_is_the_centre_distance_less_the_circumscribed_radius() -> None:
    b = Box(np.zeros(3), np.array([0, 0, 0, 1.0]), np.array([2.0, 2.0, 2.0]))
    pts = np.array([[3.0, 0, 0], [2.5, 0, 0], [4, 4, 0]])
    r = 0.5 * math.sqrt(3 * 0.25**2)
    assert clearance_lower_bound(pts, [b], np.array([0.25, 0.25, 0.25])) == pytest.approx(1.5 - r)
    assert path_length(pts) == pytest.approx(0.5 + math.hypot(1.5, 4))
    assert math.isnan(clearance_lower_bound(np.zeros((0, 3)), [b], np.ones(3)))


def _result(c: str, i: int, outcome: str, **kw) -> EpisodeResult:
    return EpisodeResult(c, i, 9000 + i, outcome, "r", **kw)


def test_summaries_rates_means_and_latency_percentiles(tmp_path: Path) -> None:
    rs = [
        _result(
            "cpp",
            0,
            "goal_reached",
            time_to_goal_s=10.0,
            path_length_m=20.0,
            min_clearance_m=0.4,
            decision_ms=[1.0, 2.0],
            counts={"accepted": 5, "velocity_limit": 2},
        ),
        _result(
            "cpp",
            1,
            "collision",
            min_clearance_m=-0.1,
            decision_ms=[3.0],
            counts={"collision_in_depth": 4, "recovered": 3},
        ),
        _result("cpp", 2, "timeout", min_clearance_m=0.8, decision_ms=[4.0]),
        _result("cpp", 3, "takeoff_failed"),
    ]
    s = summarise("cpp", rs)
    assert (s.success_rate, s.collision_rate, s.timeout_rate, s.other_rate) == (0.25, 0.25, 0.25, 0.25)
    assert s.mean_time_to_goal_s == 10.0 and s.mean_path_length_m == 20.0
    assert s.min_clearance_m == -0.1 and s.median_min_clearance_m == pytest.approx(0.4)
    assert s.decision_ms_median == 2.0 and s.decision_ms_p99 == 4.0
    assert s.refusals == 6 and s.recovered == 3  # recovered decisions stay counted as refusals
    with pytest.raises(ValueError, match="no results"):
        summarise("py", rs)
    with pytest.raises(ValueError, match="outcome must be one of"):
        _result("cpp", 5, "crashed")
    # The results file round-trips (NaN included) and appends.
    for r in rs:
        append_result(tmp_path / "cpp.jsonl", r)
    back = read_results(tmp_path / "cpp.jsonl")
    assert [r.outcome for r in back] == [r.outcome for r in rs]
    assert math.isnan(back[3].time_to_goal_s) and back[0].counts == {"accepted": 5, "velocity_limit": 2}


def test_the_report_has_the_table_plots_and_bench_lines(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    specs = plan_eval_episodes([9000, 9001], 2, StartGoalConfig())
    traj = [[0.0, *specs[0].start_world], [1.0, *specs[0].goal_world]]
    for c, outcome in (("expert", "goal_reached"), ("cpp", "collision")):
        for spec in specs:
            append_result(
                tmp_path / f"{c}.jsonl",
                EpisodeResult(
                    c,
                    spec.index,
                    spec.seed,
                    outcome,
                    "r",
                    time_to_goal_s=9.0,
                    trajectory=traj,
                    decision_ms=[2.0, 2.5],
                    counts={
                        "collision_in_depth": 2,
                        "recovered": 1,
                        "final_approach": 5,
                        "kept": 2,
                        "committed": 4,
                    }
                    if c == "cpp"
                    else {},
                ),
            )
    report = write_report(
        tmp_path,
        ["expert", "py", "cpp"],
        specs,
        {"py": "quad_il/policy_node.py is not built"},
        {"policy": "p.ts", "episode_timeout_s": 60},
    )
    text = report.read_text()
    assert "| expert (fast_planner) | - | 2 | 100 % [34-100] | 0 % [0-66] |" in text
    assert "| policy, C++ (LibTorch) | shield | 2 | 0 % [0-66] | 100 % [34-100] |" in text
    assert "Not pinned" in text  # no pin given: the report says so
    assert "not run: quad_il/policy_node.py is not built" in text
    assert "refusals (recovered) | final approach | kept (committed) |" in text
    assert text.count("| 4 (2) | 10 | 12 (8) |") == 1  # the C++ row, 2 episodes
    for png in ("outcomes.png", "latency.png", "trajectories.png"):
        assert (tmp_path / png).stat().st_size > 0 and f"({png})" in text
    out = capsys.readouterr().out.splitlines()
    assert "BENCH eval_expert_success_rate 1.0000 ratio" in out
    assert "BENCH eval_cpp_shield_collision_rate 1.0000 ratio" in out
    assert not any("eval_py_" in line for line in out)
    assert len(bench_lines({}, "bare")) == 0


def test_the_evaluation_simulator_config_is_lockstepped_with_the_controller_and_the_runner(
    tmp_path: Path,
) -> None:
    cfg = eval_sim_config(ROOT / "config" / "sim.yaml", "cpp", 10.0)
    assert cfg["time"]["mode"] == "lockstep"
    assert cfg["lockstep"]["depth_consumers"] == ["policy", "eval_runner"]
    assert cfg["lockstep"]["wait_for_command"] is True
    assert cfg["world"]["generator"]["density_boxes_per_100m2"] == 10.0
    assert Path(cfg["vehicle_file"]).is_absolute() and Path(cfg["vehicle_file"]).is_file()
    assert eval_sim_config(ROOT / "config" / "sim.yaml", "expert", None)["lockstep"]["depth_consumers"] == [
        "fast_planner",
        "eval_runner",
    ]
    # Every key the simulator reads is still there (the file is the base config with values changed).
    base = yaml.safe_load((ROOT / "config" / "sim.yaml").read_text())
    assert set(cfg) == set(base)


def test_bad_policy_and_policy_config_paths_are_named(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from quad_il.evaluation.run_eval import main

    policy = tmp_path / "policy.ts"
    policy.write_bytes(b"x")
    base = ["--controllers", "cpp", "--out", str(tmp_path / "out"), "--episodes", "1"]
    assert main([*base, "--policy", str(tmp_path / "none.ts")]) == 1
    assert "--policy must name an exported policy file" in capsys.readouterr().err
    assert main([*base, "--policy", str(policy), "--policy-config", str(tmp_path / "nope.yaml")]) == 1
    assert f"--policy-config: no such file '{tmp_path / 'nope.yaml'}'" in capsys.readouterr().err
    # A config the nodes would refuse is refused before anything is launched, naming the key.
    bad = tmp_path / "bad.yaml"
    bad.write_text(
        (ROOT / "config" / "policy.yaml").read_text().replace("final_approach_acc_mps2: 2.0\n", "")
    )
    assert main([*base, "--policy", str(policy), "--policy-config", str(bad)]) == 1
    err = capsys.readouterr().err
    assert (
        f"--policy-config: {bad} (tier shield): missing required key 'recovery.final_approach_acc_mps2'"
        in err
    ), err
    assert not (tmp_path / "out" / "logs").exists()  # nothing was launched


def test_a_lockstep_runner_without_the_controllers_consumer_name_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from quad_il.evaluation.runner_args import parse_args

    args = ["--episodes", str(tmp_path / "e.json"), "--controller", "cpp", "--out", str(tmp_path / "o")]
    with pytest.raises(SystemExit) as exc:
        parse_args([*args, "--lockstep-consumer", "eval_runner"])
    assert exc.value.code == 2
    assert "--lockstep-consumer needs --controller-consumer" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()
    ok = parse_args([*args, "--lockstep-consumer", "eval_runner", "--controller-consumer", "policy"])
    assert (ok.episode_timeout_s, ok.vehicle_box_m) == (60.0, "0.25,0.25,0.25")


def test_a_flight_is_summarised_from_its_odometry_decisions_and_boxes() -> None:
    from types import SimpleNamespace

    from quad_il.evaluation.episodes import EpisodeResult
    from quad_il.evaluation.metrics import boxes_from_markers, summarise_flight

    def marker(ns: str, x: float, action: int = 0) -> SimpleNamespace:
        pose = SimpleNamespace(
            position=SimpleNamespace(x=x, y=0.0, z=1.0), orientation=SimpleNamespace(x=0, y=0, z=0, w=1)
        )
        return SimpleNamespace(
            ns=ns, action=action, ADD=0, pose=pose, scale=SimpleNamespace(x=1.0, y=1.0, z=2.0)
        )

    boxes = boxes_from_markers([marker("boxes", 5.0), marker("goal", 9.0), marker("boxes", 7.0, action=2)])
    assert len(boxes) == 1 and boxes[0].center[0] == 5.0
    t = np.arange(0.0, 2.0, 0.005)
    points = np.stack([10.0 + t, t, np.zeros_like(t), np.ones_like(t)], axis=1)  # 1 m/s along x at z = 1
    res = EpisodeResult("cpp", 0, 9000, "goal_reached", "goal")
    summarise_flight(
        res,
        10.0,
        12.0,
        points,
        boxes,
        np.full(3, 0.25),
        [1.23456, 2.0],
        [9.0],
        counts={"accepted": 2},
        tracker_rejections=1,
    )
    assert res.time_to_goal_s == pytest.approx(2.0) and res.flight_time_s == pytest.approx(2.0)
    assert res.path_length_m == pytest.approx(1.995, abs=1e-9)
    assert res.decisions == 2 and res.decision_ms == [1.2346, 2.0]  # the policy's, not the expert's
    assert (res.counts, res.tracker_rejections) == ({"accepted": 2}, 1)
    assert len(res.trajectory) == 20  # 10 Hz over 2 s
    # Nearest box face at x = 4.5 from the end at x = 1.995: minus the vehicle's circumscribed radius.
    assert res.min_clearance_m == pytest.approx(4.5 - 1.995 - math.sqrt(3) * 0.125, abs=1e-6)
    expert = summarise_flight(
        EpisodeResult("expert", 0, 1, "collision", "box"),
        0.0,
        1.0,
        points[:1],
        boxes,
        np.full(3, 0.25),
        [],
        [3.5, 4.0],
    )
    assert math.isnan(expert.time_to_goal_s) and expert.decision_ms == [3.5, 4.0] and expert.counts == {}


def _fake_relaunch_eval(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, failures: list[bool], retries: int
) -> tuple[list[str], Path]:
    """run_controller in relaunch mode with the launch and the runner faked: runner call i fails before
    recording its episode when failures[i] is true, else records a goal."""
    import argparse

    from quad_il.evaluation import run_eval

    calls: list[str] = []
    monkeypatch.setattr(run_eval, "node_available", lambda controller: "")
    monkeypatch.setattr(run_eval, "_launch", lambda *a: (None, {}))
    monkeypatch.setattr(run_eval, "_stop_group", lambda proc: None)

    def runner(args, controller, out, env, todo, tag):  # noqa: ANN001, ANN202
        calls.append(tag)
        if failures[len(calls) - 1]:
            raise run_eval.EvalError(f"the {controller} runner failed (exit 1); see {tag}_runner.log")
        spec = read_episodes(todo)[0]
        append_result(
            out / f"{controller}.jsonl", EpisodeResult(controller, spec.index, spec.seed, "goal_reached", "")
        )

    monkeypatch.setattr(run_eval, "_run_runner", runner)
    episodes = tmp_path / "episodes.json"
    write_episodes(episodes, plan_eval_episodes([9000, 9001], 2, StartGoalConfig()))
    args = argparse.Namespace(
        backend="ros",
        episode_mode="relaunch",
        sim_config=str(ROOT / "config" / "sim.yaml"),
        density=None,
        snapshots="",
        setup_retries=retries,
    )
    out = tmp_path / "out"
    out.mkdir()
    run_eval.run_controller(args, "cpp", out, episodes)
    return calls, out


def test_an_episode_whose_nodes_fail_to_start_is_relaunched_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    calls, out = _fake_relaunch_eval(tmp_path, monkeypatch, [True, False, False], retries=1)
    assert calls == ["ep000", "ep000_retry1", "ep001"]  # the retry's logs do not overwrite the failed one's
    assert [r.index for r in read_results(out / "cpp.jsonl")] == [0, 1]
    err = capsys.readouterr().err
    assert (
        "cpp episode 0: the cpp runner failed (exit 1); see ep000_runner.log; relaunching it (attempt 2 of 2)"
        in err
    )


def test_a_start_up_failure_beyond_the_retries_stops_the_controller(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from quad_il.evaluation.run_eval import EvalError

    with pytest.raises(EvalError, match="the cpp runner failed"):
        _fake_relaunch_eval(tmp_path, monkeypatch, [False, True, True], retries=1)
    # The episode recorded before the failure is kept (a rerun resumes after it).
    assert [r.index for r in read_results(tmp_path / "out" / "cpp.jsonl")] == [0]
    # Without retries the first start-up failure stops it.
    (tmp_path / "b").mkdir()
    with pytest.raises(EvalError, match="the cpp runner failed"):
        _fake_relaunch_eval(tmp_path / "b", monkeypatch, [True, False], retries=0)


def test_negative_setup_retries_are_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from quad_il.evaluation.run_eval import main

    assert main(["--controllers", "expert", "--out", str(tmp_path / "o"), "--setup-retries", "-1"]) == 1
    assert "--setup-retries must be >= 0, got -1" in capsys.readouterr().err
