"""EpisodeResult.lockstep_timeouts (issue 30): the simulator's lockstep timeouts during an episode, recorded
by the evaluation's runner. Round trip through the results file, old files without the field, bad values."""

from __future__ import annotations

import json
from dataclasses import asdict

import pytest

from quad_il.evaluation.episodes import EpisodeResult, append_result, read_results


def test_lockstep_timeouts_round_trip_through_the_results_file(tmp_path):
    path = tmp_path / "expert.jsonl"
    append_result(path, EpisodeResult("expert", 0, 9000, "goal_reached", "goal reached", lockstep_timeouts=0))
    append_result(path, EpisodeResult("expert", 1, 9001, "collision", "box 3", lockstep_timeouts=2))
    got = read_results(path)
    assert [r.lockstep_timeouts for r in got] == [0, 2]


def test_results_written_before_the_field_read_as_unknown(tmp_path):
    old = asdict(EpisodeResult("expert", 0, 9000, "goal_reached", "goal reached"))
    del old["lockstep_timeouts"]  # a line of a results file from before issue 30
    path = tmp_path / "expert.jsonl"
    path.write_text(json.dumps(old) + "\n")
    (r,) = read_results(path)
    assert r.lockstep_timeouts is None  # unknown, not "none happened"


def test_a_result_without_a_count_is_unknown():
    assert EpisodeResult("cpp", 0, 9000, "reset_failed", "reset rejected").lockstep_timeouts is None


@pytest.mark.parametrize("bad", [-1, 1.5, "2", True])
def test_a_bad_count_is_refused_naming_the_value(bad):
    with pytest.raises(ValueError, match=f"lockstep_timeouts must be None or an int >= 0, got {bad!r}"):
        EpisodeResult("expert", 0, 9000, "timeout", "t", lockstep_timeouts=bad)
