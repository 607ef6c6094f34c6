"""quad_il.evaluation.model_card: the shipped policy's card names its lineage, data, hashes and results, and
refuses what would make it wrong (another policy's evaluation, an incomplete run, a file too large)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest
import yaml

from quad_il.evaluation.episodes import EpisodeResult, EpisodeSpec, append_result, write_episodes
from quad_il.evaluation.model_card import ModelCardError, dataset_hash, lineage, main, write_card
from quad_il.evaluation.pin import RunPin, write_pin


def _dataset(d: Path, seeds: str) -> Path:
    d.mkdir(parents=True)
    (d / "shard_000000.qdr").write_bytes(b"a" * 100)
    (d / "shard_000001.qdr").write_bytes(b"b" * 50)
    run_info = {
        "launch": "quad_il.engine.dagger",
        "seeds": seeds,
        "episodes": "500",
        "policy": "/p/r0.ts",
        "planner_config": "/w/config/planner_privileged.yaml",
    }
    (d / "manifest.yaml").write_text(yaml.safe_dump({"run_info": run_info}))
    return d


def _run(d: Path, data: list[Path], init: str | None, policy: bytes = b"policy-bytes") -> Path:
    (d / "checkpoints").mkdir(parents=True)
    (d / "checkpoints" / "best.pt").write_bytes(b"ckpt")
    (d / "policy.ts").write_bytes(policy)
    (d / "config.yaml").write_text(yaml.safe_dump({"run": {"name": d.name, "init_weights": init}}))
    (d / "run_info.json").write_text(
        json.dumps(
            {
                "started": "2026-12-07T11:00:00+0000",
                "argv": [
                    "training_only/train_on_cpp_datasets.py",
                    "--name",
                    d.name,
                    "--set",
                    "optim.lr=5e-4",
                ],
                "software": {"commit": "abc123", "dirty": False, "torch": "2.13.0+cpu", "torch_threads": 2},
            }
        )
    )
    (d / "summary.json").write_text(json.dumps({"epochs": 2, "best_epoch": 2, "best_val_loss": 0.0123}))
    (d / "metrics.csv").write_text("epoch,val_loss,epoch_wall_s\n1,0.2,60.0\n2,0.1,90.0\n")
    (d / "dataset_manifest.json").write_text(
        json.dumps(
            {
                "num_samples": 30 * len(data),
                "horizon_s": 1.5,
                "num_ctrl_pts": 10,
                "per_source": [{"path": str(p), "num_samples": 30} for p in data],
            }
        )
    )
    return d


def _eval(d: Path, controller: str, outcomes: list[str], policy_sha: str, eval_set: str = "test") -> Path:
    d.mkdir(parents=True)
    specs = [
        EpisodeSpec(i, 31000 + i, (0.0, 0.0, 0.125), 0.0, (20.0, 0.0, 2.0)) for i in range(len(outcomes))
    ]
    write_episodes(d / "episodes.json", specs)
    for i, o in enumerate(outcomes):
        append_result(d / f"{controller}.jsonl", EpisodeResult(controller, i, 31000 + i, o, ""))
    flies = controller != "expert"
    write_pin(
        d,
        RunPin(
            "bare" if flies else "",
            eval_set,
            policy_sha if flies else "",
            "",
            "",
            "",
            "",
            "",
            "",
            "",
            None,
            "abc123",
            False,
            "engine",
        ),
    )
    return d


def test_card_lineage_data_and_results(tmp_path: Path) -> None:
    d0 = _dataset(tmp_path / "data" / "bc", "40000-41499")
    d1 = _dataset(tmp_path / "data" / "r1", "42000-42499")
    r0 = _run(tmp_path / "runs" / "bc", [d0], None)
    r1 = _run(tmp_path / "runs" / "r1", [d0, d1], str(r0 / "checkpoints" / "best.pt"), policy=b"shipped")
    assert lineage(r1) == [r0, r1]
    sha = hashlib.sha256(b"shipped").hexdigest()
    e_pol = _eval(tmp_path / "res" / "bare", "cpp", ["goal_reached"] * 8 + ["collision"] * 2, sha)
    e_exp = _eval(tmp_path / "res" / "expert", "expert", ["goal_reached"] * 10, sha)
    out = tmp_path / "models" / "m"
    card = write_card(r1, out, [e_pol, e_exp]).read_text()
    assert (out / "policy.ts").read_bytes() == b"shipped"
    assert yaml.safe_load((out / "train_config.yaml").read_text())["run"]["name"] == "r1"
    assert f"sha256 `{sha}`" in card
    assert "| test | sim config | cpp | bare | 10 | 80 % [49-94] | 20 % [6-51] | 0 % [0-28] | 80 % |" in card
    assert "| test | sim config | expert | - | 10 | 100 % [72-100] |" in card
    # Both runs, oldest first, with their commands, wall time and data keys and hashes.
    assert card.index(f"### `{r0}`") < card.index(f"### `{r1}`")
    assert "python training_only/train_on_cpp_datasets.py --name r1 --set optim.lr=5e-4" in card
    assert "2.5 min of training" in card
    assert "seeds `42000-42499`" in card and "expert `planner_privileged.yaml`" in card
    assert f"sha256 `{dataset_hash(d1)}`" in card
    assert dataset_hash(d0) == dataset_hash(d1)  # same shard contents and names: same hash
    (d1 / "shard_000001.qdr").write_bytes(b"c" * 50)
    assert dataset_hash(d0) != dataset_hash(d1)
    assert main(["--run", str(r1), "--out", str(out), "--eval", str(e_pol), "--no-hash-data"]) == 0
    assert "not hashed" in (out / "MODEL.md").read_text()


def test_card_refusals_name_the_problem(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    d0 = _dataset(tmp_path / "data" / "bc", "1-2")
    run = _run(tmp_path / "runs" / "a", [d0], None, policy=b"x" * 2048)
    other = _eval(tmp_path / "res" / "other", "cpp", ["goal_reached"], "0" * 64)
    with pytest.raises(ModelCardError, match="not the shipped one"):
        write_card(run, tmp_path / "m", [other])
    with pytest.raises(ModelCardError, match=r"more than the 0.001 MB"):
        write_card(run, tmp_path / "m", [], max_mb=0.001)
    (run / "summary.json").unlink()
    assert main(["--run", str(run), "--out", str(tmp_path / "m")]) == 2
    assert "not a finished training run (missing summary.json)" in capsys.readouterr().err
    bad = _run(tmp_path / "runs" / "b", [d0], str(tmp_path / "elsewhere.pt"))
    with pytest.raises(ModelCardError, match="is not a training run's checkpoint"):
        lineage(bad)
    assert not (tmp_path / "m" / "policy.ts").exists()  # nothing shipped on a refusal


def test_a_run_started_from_an_unfrozen_shipped_policy_carries_that_policys_card(tmp_path: Path) -> None:
    from quad_il.learning.checkpoint import save_checkpoint

    ckpt = tmp_path / "runs" / "unfrozen" / "checkpoints" / "best.pt"
    ckpt.parent.mkdir(parents=True)
    earlier = "## How it was made (oldest run first)\n\n### `runs/dagger_r4`\n\n- commit `c030c3f`\n"
    origin = {
        "policy_file": "models/quad_il_policy/policy.ts",
        "sha256": "ab" * 32,
        "calib": "data/r5_96",
        "command": "python -m quad_il.learning.unfreeze models/quad_il_policy/policy.ts ...",
        "model_card": earlier,
    }
    save_checkpoint({"format": "x", "unfrozen_from": origin}, ckpt)
    d0 = _dataset(tmp_path / "data" / "r5", "44000-44499")
    run = _run(tmp_path / "runs" / "r5", [d0], str(ckpt))
    assert lineage(run) == [run]  # the unfrozen checkpoint is not a run: the lineage stops there
    card = write_card(run, tmp_path / "m", [], hash_data=False).read_text()
    shipped = f"`models/quad_il_policy/policy.ts`, sha256 `{'ab' * 32}`, rebuilt as the training checkpoint"
    assert shipped in card
    assert "BatchNorm statistics from `data/r5_96`" in card
    # the earlier card's lineage, one heading level down, before the new run
    assert card.index("#### `runs/dagger_r4`") < card.index(f"### `{run}`")
    assert "### How it was made (oldest run first)" in card


ROOT = Path(__file__).resolve().parents[2]


def test_the_defaults_fly_the_shipped_policy_and_its_card_matches() -> None:
    import re
    import xml.etree.ElementTree as ET

    from quad_il.learning.export import load_exported
    from quad_il.tools.provenance import sha256_file

    shipped = ROOT / "models" / "quad_il_policy"
    launch = ET.parse(ROOT / "launch" / "infer.launch").getroot()
    default = next(a.get("default") for a in launch.iter("arg") if a.get("name") == "policy")
    assert default == "$(find quad_il)/models/quad_il_policy/policy.ts"
    # $(find quad_il) is src/quad_il, whose models/ is a link to the repository's.
    assert (ROOT / "src" / "quad_il" / default.split(")/", 1)[1]).resolve() == (
        shipped / "policy.ts"
    ).resolve()
    make_default = re.search(r"^POLICY \?= (\S+)$", (ROOT / "Makefile").read_text(), re.M)
    assert make_default is not None and make_default.group(1) == "models/quad_il_policy/policy.ts"
    assert (shipped / "policy.ts").stat().st_size <= 25 * 2**20
    card = (shipped / "MODEL.md").read_text()
    assert (
        f"sha256 `{sha256_file(shipped / 'policy.ts')}`" in card
    ), "MODEL.md describes another file: rerun model_card"
    _, meta = load_exported(shipped / "policy.ts")
    cfg = yaml.safe_load((shipped / "train_config.yaml").read_text())
    assert meta["output"]["horizon_s"] == cfg["data"]["shards"]["horizon_s"]


def test_the_commit_that_shipped_a_file_is_found_by_its_hash(tmp_path: Path, monkeypatch) -> None:
    import subprocess

    from quad_il.evaluation.model_card import _commit_naming

    sha = "cd" * 32
    monkeypatch.chdir(tmp_path)
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t"]
    subprocess.run([*git, "init", "-q"], check=True)
    (tmp_path / "MODEL.md").write_text("first\n")
    subprocess.run([*git, "add", "MODEL.md"], check=True)
    subprocess.run([*git, "commit", "-qm", "a"], check=True)
    (tmp_path / "MODEL.md").write_text(f"`policy.ts`: sha256 `{sha}`\n")
    subprocess.run([*git, "commit", "-qam", "ship"], check=True)
    shipped = subprocess.run(
        ["git", "log", "-1", "--format=%h"], capture_output=True, text=True
    ).stdout.strip()
    (tmp_path / "MODEL.md").write_text("a later card\n")
    subprocess.run([*git, "commit", "-qam", "next"], check=True)
    assert _commit_naming(sha) == shipped  # the oldest commit touching the hash: the one that shipped it
    assert _commit_naming("ef" * 32) == ""
    assert _commit_naming("short") == ""
