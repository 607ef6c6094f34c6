"""quad_il.evaluation.expert_refusals (issue 33): the safety layer judges the expert's own plans on their
frames. One privileged-expert episode collected on the engine (about 5 s)."""

from __future__ import annotations

import json

import pytest

from quad_il.engine.collect import collect
from quad_il.evaluation import expert_refusals
from quad_il.tools.repo import repo_root

ROOT = repo_root()


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("refusals") / "data"
    r = collect(out, "1", 1, planner_config="config/planner_privileged.yaml", progress=False)
    assert r.complete and r.samples > 5
    return out


def test_every_record_gets_a_verdict_and_the_expert_is_mostly_accepted(dataset, tmp_path, capsys) -> None:
    out = tmp_path / "tally.json"
    assert expert_refusals.main(["--data", str(dataset), "--out", str(out), "--no-progress"]) == 0
    tally = json.loads(out.read_text())
    from quad_il.data.shards import open_dataset

    assert tally["records"] == len(open_dataset(dataset))
    assert sum(tally["verdicts"].values()) == tally["records"]
    assert tally["verdicts"].get("accepted", 0) > tally["records"] // 2
    assert "expert plans judged by the safety layer" in capsys.readouterr().out


def test_the_policy_configs_checks_are_the_ones_applied(dataset, tmp_path) -> None:
    # A speed limit no plan keeps: every plan is refused for its velocity.
    strict = tmp_path / "strict.yaml"
    strict.write_text(f"overlay_of: {ROOT / 'config' / 'policy.yaml'}\nsafety:\n  max_vel_mps: 0.05\n")
    out = tmp_path / "tally.json"
    args = ["--data", str(dataset), "--policy-config", str(strict), "--out", str(out), "--no-progress"]
    assert expert_refusals.main(args) == 0
    tally = json.loads(out.read_text())
    assert tally["verdicts"] == {"velocity_limit": tally["records"]}
    assert "velocity" in tally["examples"]["velocity_limit"]


def test_max_records_caps_the_records_judged(dataset, tmp_path) -> None:
    out = tmp_path / "tally.json"
    assert (
        expert_refusals.main(
            ["--data", str(dataset), "--max-records", "3", "--out", str(out), "--no-progress"]
        )
        == 0
    )
    assert json.loads(out.read_text())["records"] == 3


def test_bad_input_is_named(tmp_path, capsys) -> None:
    with pytest.raises(SystemExit):
        expert_refusals.main(["--data", str(tmp_path / "missing")])
    err = capsys.readouterr().err
    assert f"--data {tmp_path / 'missing'}: no such directory" in err
    (tmp_path / "empty").mkdir()
    assert expert_refusals.main(["--data", str(tmp_path / "empty"), "--no-progress"]) == 2
    assert "empty" in capsys.readouterr().err


def test_a_bad_config_is_named(dataset, tmp_path, capsys) -> None:
    bad = tmp_path / "train.yaml"
    bad.write_text("data:\n  shards:\n    horizon_s: -1.0\n")
    assert expert_refusals.main(["--data", str(dataset), "--train-config", str(bad), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "horizon_s" in err
