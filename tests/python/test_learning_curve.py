"""quad_il.evaluation.learning_curve: success per point from run_eval directories, the table, the figure and
the errors that name the bad point."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from quad_il.evaluation.episodes import EpisodeResult, EpisodeSpec, append_result, write_episodes
from quad_il.evaluation.learning_curve import LearningCurveError, load_points, main, table


def _specs(n: int, seed0: int = 9000) -> list[EpisodeSpec]:
    return [EpisodeSpec(i, seed0 + i, (0.0, 0.0, 0.125), 0.0, (20.0, 0.0, 2.0)) for i in range(n)]


def _run(d: Path, outcomes: list[str], seed0: int = 9000) -> Path:
    d.mkdir(parents=True)
    write_episodes(d / "episodes.json", _specs(len(outcomes), seed0))
    for i, o in enumerate(outcomes):
        append_result(d / "cpp.jsonl", EpisodeResult("cpp", i, seed0 + i, o, ""))
    return d


def _spec(tmp: Path, points: list[dict], name: str = "curve.yaml") -> Path:
    p = tmp / name
    p.write_text(yaml.safe_dump({"title": "t", "points": points}))
    return p


def test_points_table_and_figure(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _run(tmp_path / "bc", ["goal_reached"] * 3 + ["collision"] * 7)
    _run(tmp_path / "r1", ["goal_reached"] * 6 + ["collision"] * 2 + ["timeout"] * 2)
    spec = _spec(
        tmp_path,
        [
            {"name": "bc", "samples": 1000, "round": 0, "eval": "bc"},
            {"name": "r0", "samples": 1000, "round": 0, "series": "dagger", "eval": "bc"},
            {"name": "r1", "samples": 5000, "round": 1, "eval": "r1"},
        ],
    )
    title, pts = load_points(spec)
    assert title == "t"
    assert [(p.name, p.series, p.successes, p.collisions, p.episodes) for p in pts] == [
        ("bc", "bc", 3, 7, 10),
        ("r0", "dagger", 3, 7, 10),
        ("r1", "dagger", 6, 2, 10),
    ]
    lo, hi = pts[2].interval
    assert lo < 0.6 < hi
    text = table(pts)
    assert "| r1 | dagger | 1 | 5,000 | 60 % [31-83] | 20 % [6-51] |" in text
    fig = tmp_path / "out" / "curve.png"
    md = tmp_path / "curve.md"
    assert main([str(spec), "--out", str(fig), "--table", str(md)]) == 0
    assert fig.stat().st_size > 1000 and fig.read_bytes()[:4] == b"\x89PNG"
    assert md.read_text() == text
    assert "60 % [31-83]" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("points", "message"),
    [
        ([{"name": "a", "samples": 0, "round": 0, "eval": "bc"}], "'samples' must be an integer >= 1"),
        ([{"name": "a", "samples": 10, "round": -1, "eval": "bc"}], "'round' must be an integer >= 0"),
        ([{"name": "a", "samples": 10, "round": 0, "eval": "nowhere"}], "no episodes.json"),
        ([{"name": "a", "samples": 10, "round": 0, "eval": "bc", "epochs": 3}], "unknown key(s) ['epochs']"),
        (
            [
                {"name": "a", "samples": 10, "round": 0, "eval": "bc"},
                {"name": "a", "samples": 20, "round": 1, "eval": "bc"},
            ],
            "point 'a': the name is used twice",
        ),
        (
            [
                {"name": "a", "samples": 10, "round": 0, "eval": "bc"},
                {"name": "b", "samples": 20, "round": 1, "eval": "other"},
            ],
            "every point must be evaluated on the same episodes",
        ),
        ([{"name": "a", "samples": 10, "round": 0, "eval": "partial"}], "finish the run"),
        ([], "needs a non-empty list 'points'"),
    ],
)
def test_bad_spec_names_the_point(tmp_path: Path, points: list[dict], message: str) -> None:
    _run(tmp_path / "bc", ["goal_reached", "collision"])
    _run(tmp_path / "other", ["goal_reached", "collision"], seed0=31000)
    partial = _run(tmp_path / "partial", ["goal_reached"])
    write_episodes(partial / "episodes.json", _specs(2))  # two episodes, one result
    spec = _spec(tmp_path, points)
    with pytest.raises(LearningCurveError) as e:
        load_points(spec)
    assert message in str(e.value)
    assert main([str(spec)]) == 2


def test_unreadable_spec(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main([str(tmp_path / "missing.yaml")]) == 2
    assert "missing.yaml: cannot read" in capsys.readouterr().err
    bad = tmp_path / "bad.yaml"
    bad.write_text("points: [a: b: c]\n")
    assert main([str(bad)]) == 2
    assert "not YAML" in capsys.readouterr().err


def test_recorded_counts_keep_a_point_when_its_directory_is_gone(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from quad_il.evaluation.learning_curve import episodes_digest

    _run(tmp_path / "bc", ["goal_reached"] * 3 + ["collision"] * 7)
    _run(tmp_path / "r1", ["goal_reached"] * 6 + ["collision"] * 2 + ["timeout"] * 2)
    digest = episodes_digest(_specs(10))
    spec = _spec(
        tmp_path,
        [
            {"name": "bc", "samples": 1000, "round": 0, "eval": "bc"},
            {"name": "r1", "samples": 5000, "round": 1, "eval": "r1"},
        ],
    )
    assert main([str(spec), "--print-recorded"]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert (
        printed[1]
        == f"r1: recorded: {{episodes: 10, goal_reached: 6, collision: 2, episodes_sha256: {digest}}}"
    )
    recorded = {
        "episodes": 10,
        "goal_reached": 6,
        "collision": 2,
        "episodes_sha256": digest,
        "note": "old box",
    }
    points = [
        {"name": "bc", "samples": 1000, "round": 0, "eval": "bc"},
        {"name": "r1", "samples": 5000, "round": 1, "eval": "r1", "recorded": recorded},
    ]
    assert [p.successes for p in load_points(_spec(tmp_path, points))[1]] == [3, 6]  # checked: they agree
    (tmp_path / "r1" / "cpp.jsonl").unlink()
    (tmp_path / "r1" / "episodes.json").unlink()
    (tmp_path / "r1").rmdir()
    assert [p.successes for p in load_points(_spec(tmp_path, points))[1]] == [3, 6]  # from the record
    # a record of other episodes, or counts the directory contradicts, are refused
    other = {**recorded, "episodes_sha256": episodes_digest(_specs(10, seed0=31000))}
    with pytest.raises(LearningCurveError, match="every point must be evaluated on the same episodes"):
        load_points(_spec(tmp_path, [points[0], {**points[1], "recorded": other}]))
    wrong = {**recorded, "goal_reached": 4}
    with pytest.raises(LearningCurveError, match="goal_reached 4 recorded, 3 in the directory"):
        load_points(_spec(tmp_path, [{**points[0], "recorded": wrong}]))
    with pytest.raises(LearningCurveError, match="'episodes_sha256' must be 64 lowercase hex digits"):
        load_points(_spec(tmp_path, [{**points[1], "recorded": {**recorded, "episodes_sha256": "x"}}]))
