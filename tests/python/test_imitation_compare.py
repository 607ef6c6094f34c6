"""Round-by-round closed-loop comparison of interactive runs (quad_il.imitation.compare)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from test_imitation_dataset import make_records

from quad_il.collection.episodes import EpisodeSpec
from quad_il.evaluation.episodes import EpisodeResult, append_result, read_results, write_episodes
from quad_il.imitation.compare import failure_modes, main
from quad_il.imitation.dataset import write_dataset


def _eval(path: Path, outcomes: list[str]) -> None:
    path.mkdir(parents=True, exist_ok=True)
    for i, o in enumerate(outcomes):
        append_result(path / "cpp.jsonl", EpisodeResult("cpp", i, 9000 + i, o, ""))


def test_rows_per_generation_with_round_records_plot_and_missing_rounds(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _eval(tmp_path / "bc", ["timeout", "timeout", "collision", "goal_reached"])
    run = tmp_path / "dagger"
    _eval(run / "round_000" / "metrics", ["goal_reached", "goal_reached", "collision", "timeout"])
    write_dataset(run / "round_000" / "data", make_records(5))
    (run / "round_001" / "metrics").mkdir(parents=True)  # collected, not evaluated yet
    out = tmp_path / "cmp"
    assert main(["--baseline", f"BC={tmp_path / 'bc'}", "--run", f"DAgger={run}", "--out", str(out)]) == 0
    assert "DAgger: rounds [1] have no evaluation yet" in capsys.readouterr().err
    rows = json.loads((out / "comparison.json").read_text())
    assert [(r["algorithm"], r["generation"]) for r in rows] == [("BC", 0), ("DAgger", 1)]
    assert (
        rows[0]["success_rate"] == 0.25 and rows[0]["collision_rate"] == 0.25 and rows[0]["records"] is None
    )
    assert rows[1]["success_rate"] == 0.5 and rows[1]["timeout_rate"] == 0.25 and rows[1]["records"] == 5
    steps = sum(1 for r in make_records(5) if r.controller.value in ("expert", "learner"))
    assert rows[1]["expert_steps"] + rows[1]["learner_steps"] == steps
    md = (out / "comparison.md").read_text()
    assert "| DAgger | 1 | 4 | 50 % (15-85 %) | 25 % | 25 % | - | - | - / - | 5 |" in md
    assert (out / "comparison.png").stat().st_size > 1000


def test_failure_modes_from_trajectories_goals_and_refusals(tmp_path: Path) -> None:
    ev = tmp_path / "bc"
    ev.mkdir()
    goals = [(10.0, 0.0, 2.0), (0.0, 10.0, 2.0), (5.0, 5.0, 1.0)]
    write_episodes(
        ev / "episodes.json", [EpisodeSpec(i, 9000 + i, (0, 0, 0), 0.0, g) for i, g in enumerate(goals)]
    )
    trajectories = [
        [[0.0, 0.0, 0.0, 1.0], [1.0, 7.0, 0.0, 2.0], [2.0, 6.0, 0.0, 4.0]],  # closest 3.0 m, highest 4.0 m
        [[0.0, 0.0, 0.0, 1.0], [1.0, 0.0, 9.0, 2.0]],  # closest 1.0 m, highest 2.0 m
        [[0.0, 0.0, 0.0, 1.0], [1.0, 5.0, 5.0, 3.0]],  # closest 2.0 m, highest 3.0 m
    ]
    counts = [
        {"accepted": 6, "collision_in_depth": 3, "no_goal": 50},
        {"accepted": 8, "acceleration_limit": 2},
        {"collision_in_depth": 1},
    ]
    for i, (tr, c) in enumerate(zip(trajectories, counts, strict=False)):
        append_result(
            ev / "cpp.jsonl", EpisodeResult("cpp", i, 9000 + i, "timeout", "", counts=c, trajectory=tr)
        )
    closest, highest, depth, accel = failure_modes(read_results(ev / "cpp.jsonl"), ev / "episodes.json")
    assert closest == pytest.approx(2.0) and highest == 3.0
    assert depth == pytest.approx(4 / 20) and accel == pytest.approx(2 / 20)  # skips are not decisions
    run = tmp_path / "run"
    _eval(run / "round_000" / "metrics", ["timeout"])
    assert main(["--baseline", f"BC={ev}", "--run", f"R={run}", "--out", str(tmp_path / "cmp")]) == 0
    assert (
        "| BC | 0 | 3 | 0 % (0-56 %) | 0 % | 100 % | 2.0 m | 3.0 m | 20 % / 10 % | - | - |"
        in (tmp_path / "cmp" / "comparison.md").read_text()
    )
    assert math.isnan(failure_modes(read_results(ev / "cpp.jsonl"), tmp_path / "none.json")[0])


def test_bad_arguments_are_named(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--run", "nodir", "--out", str(tmp_path / "o")]) == 2
    assert "--run 'nodir': expected NAME=DIRECTORY" in capsys.readouterr().err
    assert main(["--run", f"X={tmp_path}", "--out", str(tmp_path / "o")]) == 2
    assert "no round_XXX directories (not a manager run directory)" in capsys.readouterr().err
    (tmp_path / "round_000").mkdir()
    assert main(["--run", f"X={tmp_path}", "--baseline", f"B={tmp_path}", "--out", str(tmp_path / "o")]) == 2
    assert "no cpp.jsonl (not a run_eval output directory)" in capsys.readouterr().err
