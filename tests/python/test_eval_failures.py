"""quad_il.evaluation.failures: every failed episode gets the kind its outcome, trajectory and goal say."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from quad_il.evaluation.episodes import EpisodeResult, EpisodeSpec, append_result, write_episodes
from quad_il.evaluation.failures import Thresholds, classify, failures_of, main, table

GOAL = (20.0, 0.0, 2.0)
SPEC = EpisodeSpec(0, 9000, (0.0, 0.0, 0.125), 0.0, GOAL)


def _line(x0: float, x1: float, seconds: float, t0: float = 0.0) -> list[list[float]]:
    """A 10 Hz trajectory along x from x0 to x1 at 2 m height, starting at t0."""
    t = t0 + np.arange(0.0, seconds + 1e-9, 0.1)
    x = np.linspace(x0, x1, len(t))
    return [[float(a), float(b), 0.0, 2.0] for a, b in zip(t, x, strict=True)]


def _circle(seconds: float, radius: float) -> list[list[float]]:
    t = np.arange(0.0, seconds + 1e-9, 0.1)
    return [[float(a), GOAL[0] + radius * np.cos(a), radius * np.sin(a), 2.0] for a in t]


@pytest.mark.parametrize(
    ("outcome", "trajectory", "kind"),
    [
        ("collision", _line(0, 18.5, 9.0), "collision_near_goal"),  # 1.5 m from the goal
        ("collision", _line(0, 10, 5.0), "collision_moving"),  # 2 m/s into a box half way
        (
            "collision",
            _line(0, 10, 5.0) + _line(10, 10.2, 2.0, t0=5.0)[1:],
            "collision_slow",
        ),  # drifting 0.1 m/s
        ("timeout", _circle(60.0, 2.0), "timeout_circling"),
        (
            "timeout",
            _line(0, 5, 10.0) + [[10.0 + 0.1 * i, 5.0, 0.0, 2.0] for i in range(1, 500)],
            "timeout_stuck",
        ),
        ("timeout", _line(0, 15, 60.0), "timeout_creeping"),  # 0.25 m/s, 5 m short
        ("takeoff_failed", [], "takeoff_failed"),
    ],
)
def test_kinds(outcome: str, trajectory: list, kind: str) -> None:
    f = classify(EpisodeResult("cpp", 0, 9000, outcome, "why", trajectory=trajectory), SPEC)
    assert f is not None and f.kind == kind and f.reason == "why"


def test_success_is_no_failure_and_thresholds_move_the_line() -> None:
    assert (
        classify(EpisodeResult("cpp", 0, 9000, "goal_reached", "", trajectory=_line(0, 20, 10)), SPEC) is None
    )
    r = EpisodeResult("cpp", 0, 9000, "collision", "", trajectory=_line(0, 16, 8.0))  # 4 m short
    assert classify(r, SPEC).kind == "collision_moving"
    assert classify(r, SPEC, Thresholds(near_goal_m=5.0)).kind == "collision_near_goal"


def test_run_directory_table_and_csv(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = tmp_path / "run"
    run.mkdir()
    specs = [EpisodeSpec(i, 9000 + i, (0.0, 0.0, 0.125), 0.0, GOAL) for i in range(4)]
    write_episodes(run / "episodes.json", specs)
    outcomes = [
        ("goal_reached", _line(0, 20, 10)),
        ("collision", _line(0, 10, 5.0)),
        ("collision", _line(0, 8, 4.0)),
        ("timeout", _circle(60.0, 1.0)),
    ]
    for i, (o, tr) in enumerate(outcomes):
        append_result(run / "cpp.jsonl", EpisodeResult("cpp", i, 9000 + i, o, f"r{i}", trajectory=tr))
    episodes, fails = failures_of(run)
    assert episodes == 4 and [f.kind for f in fails] == ["collision_moving"] * 2 + ["timeout_circling"]
    text = table(episodes, fails)
    assert "| collision_moving | 2 | 50 % [15-85] |" in text and "| all failures | 3 | 75 % [30-95] |" in text
    out = tmp_path / "f.csv"
    assert main([str(run), "--csv", str(out)]) == 0
    rows = out.read_text().splitlines()
    assert rows[0].startswith("index,seed,kind") and rows[1].startswith(
        "1,9001,collision_moving,collision,10.0"
    )
    assert main([str(tmp_path / "nowhere")]) == 2
    assert "no episodes.json" in capsys.readouterr().err
