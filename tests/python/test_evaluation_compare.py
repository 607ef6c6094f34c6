"""Paired comparison of two closed-loop evaluations (quad_il.evaluation.compare) on constructed runs."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from quad_il.collection.episodes import EpisodeSpec
from quad_il.evaluation.compare import CompareError, compare, main
from quad_il.evaluation.episodes import EpisodeResult, append_result, write_episodes

SPECS = [EpisodeSpec(i, 9000 + i, (0.0, float(i), 1.5), 0.0, (10.0, float(i), 1.5)) for i in range(4)]


def _run(d: Path, outcomes: list[str], shifts: list[float], specs: list[EpisodeSpec] = SPECS) -> Path:
    d.mkdir(parents=True)
    write_episodes(d / "episodes.json", specs)
    for s, outcome, shift in zip(specs, outcomes, shifts, strict=True):
        traj = [[0.1 * k, shift + 0.5 * k, 0.0, 1.5] for k in range(5)]
        append_result(d / "cpp.jsonl", EpisodeResult("cpp", s.index, s.seed, outcome, "", trajectory=traj))
    return d


def test_pairs_episodes_and_counts_identical_changed_gained_and_lost(tmp_path: Path) -> None:
    a = _run(tmp_path / "a", ["goal_reached", "timeout", "collision", "goal_reached"], [0, 0, 0, 0])
    b = _run(tmp_path / "b", ["goal_reached", "goal_reached", "collision", "timeout"], [0, 1, 1, 0])
    c = compare(a, b)
    assert c.episodes == 4 and c.controller == "cpp"
    assert c.counts_a == {"goal_reached": 2, "collision": 1, "timeout": 1}
    assert c.counts_b == {"goal_reached": 2, "collision": 1, "timeout": 1}
    # Episode 0: same outcome and trajectory; 2: same outcome, another trajectory (not identical).
    assert c.identical == 1
    assert c.changed == [(1, 9001, "timeout", "goal_reached"), (3, 9003, "goal_reached", "timeout")]
    assert (c.goals_gained, c.goals_lost, c.mcnemar_p) == (1, 1, 1.0)
    assert compare(a, a).identical == 4 and compare(a, a).changed == []


def test_unpairable_runs_are_refused_with_the_reason(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    a = _run(tmp_path / "a", ["goal_reached"] * 4, [0] * 4)
    other = [EpisodeSpec(s.index, s.seed + 1, s.start_world, s.start_yaw_rad, s.goal_world) for s in SPECS]
    b = _run(tmp_path / "b", ["goal_reached"] * 4, [0] * 4, other)
    with pytest.raises(CompareError, match="hold different episodes"):
        compare(a, b)
    short = _run(tmp_path / "short", ["goal_reached"] * 4, [0] * 4)
    lines = (short / "cpp.jsonl").read_text().splitlines()
    (short / "cpp.jsonl").write_text("\n".join(lines[:3]) + "\n")  # an interrupted run
    with pytest.raises(CompareError, match="1 of 4 episodes have no result .e.g. index 3.; finish the run"):
        compare(a, short)
    with pytest.raises(CompareError, match="no py.jsonl"):
        compare(a, a, "py")
    assert main([str(a), str(tmp_path / "nothing")]) == 2
    assert f"compare: {tmp_path / 'nothing'}: no episodes.json" in capsys.readouterr().err


def test_main_prints_and_writes_the_markdown_summary(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    a = _run(tmp_path / "a", ["timeout"] * 4, [0] * 4)
    b = _run(tmp_path / "b", ["goal_reached", "goal_reached", "timeout", "collision"], [0] * 4)
    out = tmp_path / "cmp.md"
    assert main([str(a), str(b), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert text == out.read_text()
    assert "| A | 0 | 0 | 4 |" in text and "| B | 2 | 1 | 1 |" in text
    assert "Goals gained in B: 2; lost: 0; exact McNemar p = 0.5." in text
    assert "| 3 | 9003 | timeout | collision |" in text


def test_main_prints_json_for_scripts(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    a = _run(tmp_path / "a", ["timeout"] * 4, [0] * 4)
    b = _run(tmp_path / "b", ["goal_reached", "goal_reached", "timeout", "collision"], [0] * 4)
    out = tmp_path / "cmp.json"
    assert main([str(a), str(b), "--json", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert text == out.read_text()
    obj = json.loads(text)
    assert obj["counts_a"] == {"goal_reached": 0, "collision": 0, "timeout": 4}
    assert obj["counts_b"] == {"goal_reached": 2, "collision": 1, "timeout": 1}
    assert (obj["goals_gained"], obj["goals_lost"], obj["mcnemar_p"]) == (2, 0, 0.5)
    assert obj["changed"][2] == {"index": 3, "seed": 9003, "a": "timeout", "b": "collision"}
    assert obj["episodes"] == 4 and obj["run_b"] == str(b)


def test_runs_flown_on_different_cpus_are_flagged(tmp_path: Path) -> None:
    from quad_il.evaluation.compare import markdown
    from quad_il.evaluation.pin import RunPin, write_pin

    def pinned(d: Path, cpu: str) -> Path:
        _run(d, ["goal_reached"] * 4, [0, 0, 0, 0])
        args = (
            "bare",
            "",
            "a" * 64,
            "/p",
            "b" * 64,
            "/c",
            "c" * 64,
            "/s",
            "d" * 64,
            "e" * 64,
            None,
            "f",
            False,
        )
        write_pin(d, RunPin(*args, "engine", cpu))
        return d

    a, b = pinned(tmp_path / "a", "X; avx2 fma"), pinned(tmp_path / "b", "Y; avx512f avx2 fma")
    c = compare(a, b)
    assert c.cpus == ("X; avx2 fma", "Y; avx512f avx2 fma")
    assert "**Flown on different CPUs** (A: X; avx2 fma; B: Y; avx512f avx2 fma)" in markdown(c, "a", "b")
    same = pinned(tmp_path / "c", "X; avx2 fma")
    assert "different CPUs" not in markdown(compare(a, same), "a", "c")
    unpinned = _run(tmp_path / "d", ["goal_reached"] * 4, [0, 0, 0, 0])  # no pin: nothing to say
    assert "different CPUs" not in markdown(compare(a, unpinned), "a", "d")
