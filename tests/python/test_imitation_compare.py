"""Round-by-round closed-loop comparison of interactive runs (quad_il.imitation.compare)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from test_imitation_dataset import make_records

from quad_il.evaluation.episodes import EpisodeResult, append_result
from quad_il.imitation.compare import main
from quad_il.imitation.dataset import write_episode


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
    write_episode(run / "round_000" / "data", 1, make_records(5))
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
    assert "| DAgger | 1 | 4 | 50 % | 25 % | 25 % | 5 |" in md
    assert (out / "comparison.png").stat().st_size > 1000


def test_bad_arguments_are_named(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--run", "nodir", "--out", str(tmp_path / "o")]) == 2
    assert "--run 'nodir': expected NAME=DIRECTORY" in capsys.readouterr().err
    assert main(["--run", f"X={tmp_path}", "--out", str(tmp_path / "o")]) == 2
    assert "no round_XXX directories (not a manager run directory)" in capsys.readouterr().err
    (tmp_path / "round_000").mkdir()
    assert main(["--run", f"X={tmp_path}", "--baseline", f"B={tmp_path}", "--out", str(tmp_path / "o")]) == 2
    assert "no cpp.jsonl (not a run_eval output directory)" in capsys.readouterr().err
