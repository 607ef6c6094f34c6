"""Trustworthy evaluation (issue 30) without ROS: pinned runs, tiers and evaluation sets.

run_eval's flying (`run_controller`) is replaced by a fake that records one result per episode, so these tests
exercise exactly the bookkeeping: what is pinned, when a resume is refused and what the message names."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from quad_il.evaluation import run_eval
from quad_il.evaluation.episodes import EpisodeResult, append_result, read_episodes, read_results
from quad_il.evaluation.pin import RunPin, cpu_signature, read_pin
from quad_il.evaluation.sets import EvalSetError, get_eval_set, load_eval_sets, world_density
from quad_il.evaluation.tiers import TierError, apply_tier, render_tier_config
from quad_il.evaluation.tiers import main as tiers_main
from quad_il.inference.config import config_from_tree, load_policy_config
from quad_il.tools.config_overlay import load_tree
from quad_il.tools.provenance import sha256_file as sha256_of

ROOT = Path(__file__).resolve().parents[2]
KEEP = ROOT / "config" / "policy_keep.yaml"


# ---------------------------------------------------------------- tiers


def test_the_bare_tier_leaves_only_the_non_finite_refusal_and_braking() -> None:
    base = load_tree(KEEP)  # an overlay of config/policy.yaml, merged
    bare = config_from_tree(apply_tier(base, "bare"))
    assert bare.safety.enabled is False  # only non-finite outputs are refused
    assert bare.refusal.action == "stop"  # a refusal brakes
    assert bare.recovery.goal_yaw_offsets_deg == [] and bare.recovery.final_approach_m == 0.0
    assert bare.keeping.commit_s == 0.0 and bare.keeping.on_refusal is False
    # What the tier does not name keeps the base's value.
    assert bare.replan_rate_hz == 10.0 and bare.safety.max_vel_mps == base["safety"]["max_vel_mps"]


def test_the_safety_tier_refuses_and_brakes_but_adds_nothing() -> None:
    base = load_tree(KEEP)  # an overlay of config/policy.yaml, merged
    safety = config_from_tree(apply_tier(base, "safety"))
    assert safety.safety.enabled is True and safety.safety.vehicle_radius_m == 0.40
    assert safety.recovery.goal_yaw_offsets_deg == [] and safety.recovery.final_approach_m == 0.0
    assert safety.keeping.commit_s == 0.0 and safety.keeping.on_refusal is False
    assert safety.refusal.action == "stop"


def test_the_shield_tier_is_the_base_config_unchanged() -> None:
    base = load_tree(KEEP)  # an overlay of config/policy.yaml, merged
    assert apply_tier(base, "shield") == base
    assert config_from_tree(yaml.safe_load(render_tier_config(KEEP, "shield"))) == load_policy_config(KEEP)


def test_tier_errors_name_the_tier_the_file_and_the_key(tmp_path: Path) -> None:
    base = load_tree(KEEP)  # an overlay of config/policy.yaml, merged
    with pytest.raises(TierError, match="unknown tier 'naked' \\(choose from bare, safety, shield\\)"):
        apply_tier(base, "naked")
    del base["keeping"]["on_refusal"]
    with pytest.raises(TierError, match="b.yaml: tier bare needs the key keeping.on_refusal"):
        apply_tier(base, "bare", "b.yaml")
    with pytest.raises(TierError, match="keeping.on_refusal"):  # the nodes' schema, through the shield tier
        apply_tier(base, "shield")
    missing = tmp_path / "none.yaml"
    assert tiers_main(["--tier", "bare", "--base", str(missing), "--out", str(tmp_path / "o.yaml")]) == 2


def test_the_tier_cli_writes_a_config_both_nodes_load(tmp_path: Path) -> None:
    out = tmp_path / "bare.yaml"
    assert tiers_main(["--tier", "bare", "--base", str(KEEP), "--out", str(out)]) == 0
    assert load_policy_config(out).safety.enabled is False
    assert out.read_text().startswith("# Policy node config of evaluation tier 'bare': policy_keep.yaml")


# ---------------------------------------------------------------- evaluation sets


def test_the_shipped_sets_separate_development_from_test() -> None:
    sets = load_eval_sets(ROOT / "config" / "eval_sets.yaml")
    assert {"dev", "dev_dense", "dev_wide", "test", "test_dense"} <= set(sets)
    dev, test = set(sets["dev"].seed_list()), set(sets["test"].seed_list())
    assert not dev & test
    assert sets["test"].episodes >= 100 and sets["test_dense"].episodes >= 100
    # Every world seed flown by an earlier evaluation (docs/RESULTS.md: 9000-9239) is outside the test set.
    assert not set(range(9000, 9240)) & test
    wide = set(sets["dev_wide"].seed_list())
    assert sets["dev_wide"].episodes == 300 and len(wide) == 300 and not wide & (test | dev)
    sim = yaml.safe_load((ROOT / "config" / "sim.yaml").read_text())
    assert world_density(sets["test"], sim) is None
    assert world_density(sets["test_dense"], sim) == pytest.approx(1.5 * 200 / 16.0)  # 200 boxes in 40 x 40 m


def test_a_sets_file_with_a_test_set_overlapping_development_is_refused(tmp_path: Path) -> None:
    p = tmp_path / "sets.yaml"
    p.write_text(
        "sets:\n  dev: {seeds: '1-10', episodes: 10, density_scale: 1.0}\n"
        "  test: {seeds: '10-20', episodes: 10, density_scale: 1.0}\n"
    )
    with pytest.raises(EvalSetError, match="sets dev and test share world seeds at the same density"):
        load_eval_sets(p)
    p.write_text("sets:\n  dev: {seeds: '1-10', episodes: 0, density_scale: 1.0}\n")
    with pytest.raises(EvalSetError, match="sets.dev.episodes: Input should be greater than or equal to 1"):
        load_eval_sets(p)
    p.write_text("sets:\n  dev: {seeds: '1-10', episodes: 3, density_scale: 1.0, colour: red}\n")
    with pytest.raises(EvalSetError, match="sets.dev.colour: Extra inputs are not permitted"):
        load_eval_sets(p)
    with pytest.raises(
        EvalSetError, match="no evaluation set 'tset' \\(sets: dev, dev_dense, dev_wide, test, test_dense\\)"
    ):
        get_eval_set(ROOT / "config" / "eval_sets.yaml", "tset")


# ---------------------------------------------------------------- pinned runs (run_eval with faked flights)


@pytest.fixture
def fake_flights(monkeypatch: pytest.MonkeyPatch) -> list[tuple[str, int]]:
    """run_controller records a goal for each unflown episode (and reports which it flew)."""
    flown: list[tuple[str, int]] = []

    def fly(args, controller, out, episodes_file):  # noqa: ANN001, ANN202
        done = {r.index for r in read_results(out / f"{controller}.jsonl")}
        for spec in read_episodes(episodes_file):
            if spec.index not in done:
                append_result(
                    out / f"{controller}.jsonl",
                    EpisodeResult(controller, spec.index, spec.seed, "goal_reached", "", lockstep_timeouts=0),
                )
                flown.append((controller, spec.index))
        return ""

    monkeypatch.setattr(run_eval, "run_controller", fly)
    return flown


def _policy(tmp_path: Path, name: str, content: bytes) -> Path:
    p = tmp_path / name
    p.write_bytes(content)
    return p


def _eval(out: Path, *extra: str) -> int:
    return run_eval.main(["--seeds", "9000-9001", "--episodes", "2", "--out", str(out), *extra])


def test_a_run_records_its_pin_and_the_report_prints_it(
    tmp_path: Path, fake_flights: list, capsys: pytest.CaptureFixture[str]
) -> None:
    a = _policy(tmp_path, "a.ts", b"policy A")
    out = tmp_path / "ev"
    assert _eval(out, "--policy", str(a), "--controllers", "expert,cpp", "--tier", "bare") == 0
    pin = read_pin(out)
    assert pin is not None
    assert pin.policy_sha256 == sha256_of(a) and pin.tier == "bare"
    assert pin.policy_config_sha256 == sha256_of(out / "policy_config.yaml")
    assert load_policy_config(out / "policy_config.yaml").safety.enabled is False  # what the nodes read
    assert pin.sim_config_sha256 == sha256_of(ROOT / "config" / "sim.yaml")
    assert len(pin.commit) == 40 or pin.commit == "unknown"
    assert pin.cpu == cpu_signature() and pin.cpu
    report = (out / "report.md").read_text()
    for value in (pin.policy_sha256, pin.policy_config_sha256, pin.sim_config_sha256, pin.commit, pin.cpu):
        assert value in report
    assert "tier **`bare`**" in report
    assert "| policy, C++ (LibTorch) | bare | 2 | 100 % [34-100] | 0 % [0-66] | 0 % [0-66] |" in report
    assert "| expert (fast_planner) | - | 2 | 100 % [34-100] |" in report
    assert report.count("| 0 % | yes |") == 2  # no lockstep timeout: reproducible
    out_lines = capsys.readouterr().out.splitlines()
    assert "BENCH eval_cpp_bare_success_rate 1.0000 ratio" in out_lines
    assert "BENCH eval_expert_success_rate 1.0000 ratio" in out_lines
    assert not any(line.startswith("BENCH eval_cpp_success_rate") for line in out_lines)


def test_resuming_with_another_policy_stops_naming_the_policy_hash(
    tmp_path: Path, fake_flights: list, capsys: pytest.CaptureFixture[str]
) -> None:
    a = _policy(tmp_path, "a.ts", b"policy A")
    b = _policy(tmp_path, "b.ts", b"policy B")
    out = tmp_path / "ev"
    assert _eval(out, "--policy", str(a), "--controllers", "cpp") == 0
    before = (out / "cpp.jsonl").read_text()
    capsys.readouterr()
    assert _eval(out, "--policy", str(b), "--controllers", "cpp") == 1
    err = capsys.readouterr().err
    assert f"policy_sha256: run has '{sha256_of(a)}', this invocation '{sha256_of(b)}'" in err
    assert "--force-new" in err
    assert (out / "cpp.jsonl").read_text() == before  # nothing touched
    # Same policy, other tier or node config: refused too, naming the field.
    assert _eval(out, "--policy", str(a), "--controllers", "cpp", "--tier", "safety") == 1
    err = capsys.readouterr().err
    assert "tier: run has 'shield', this invocation 'safety'" in err and "policy_config_sha256" in err
    # Same everything: resumes (nothing left to fly).
    n = len(fake_flights)
    assert _eval(out, "--policy", str(a), "--controllers", "cpp") == 0
    assert len(fake_flights) == n


def test_resuming_with_another_simulator_config_or_commit_is_refused(
    tmp_path: Path, fake_flights: list, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "ev"
    assert _eval(out, "--controllers", "expert") == 0
    sim = yaml.safe_load((ROOT / "config" / "sim.yaml").read_text())
    sim["vehicle_file"] = str((ROOT / "config" / sim["vehicle_file"]).resolve())
    sim["physics"]["dt_s"] = 0.002
    other = tmp_path / "sim.yaml"
    other.write_text(yaml.safe_dump(sim))
    capsys.readouterr()
    assert _eval(out, "--controllers", "expert", "--sim-config", str(other)) == 1
    assert "sim_config_sha256: run has" in capsys.readouterr().err
    assert "The expert alone (no policy, no tier)." in (out / "report.md").read_text()
    pin = json.loads((out / "pin.json").read_text())
    pin["commit"] = "0" * 40
    (out / "pin.json").write_text(json.dumps(pin))
    assert _eval(out, "--controllers", "expert") == 1
    assert f"commit: run has '{'0' * 40}'" in capsys.readouterr().err


def test_force_new_moves_the_old_run_aside_and_starts_over(
    tmp_path: Path, fake_flights: list, capsys: pytest.CaptureFixture[str]
) -> None:
    a = _policy(tmp_path, "a.ts", b"policy A")
    b = _policy(tmp_path, "b.ts", b"policy B")
    out = tmp_path / "ev"
    assert _eval(out, "--policy", str(a), "--controllers", "cpp") == 0
    assert _eval(out, "--policy", str(b), "--controllers", "cpp", "--force-new") == 0
    assert "--force-new: the earlier run moved to" in capsys.readouterr().err
    old = [p for p in tmp_path.iterdir() if p.name.startswith("ev.old-")]
    assert len(old) == 1 and RunPin.from_json(
        (old[0] / "pin.json").read_text(), "x"
    ).policy_sha256 == sha256_of(a)
    assert len(read_results(old[0] / "cpp.jsonl")) == 2  # nothing lost
    assert read_pin(out).policy_sha256 == sha256_of(b)
    assert fake_flights == [("cpp", 0), ("cpp", 1), ("cpp", 0), ("cpp", 1)]
    # An expert-only fresh start keeps nothing of the run it moved aside: another policy may fly after it.
    assert _eval(out, "--controllers", "expert", "--force-new") == 0
    assert read_pin(out).policy_sha256 == ""
    assert _eval(out, "--policy", str(a), "--controllers", "cpp") == 0


def test_the_expert_may_be_flown_first_and_the_policy_added(
    tmp_path: Path, fake_flights: list, capsys: pytest.CaptureFixture[str]
) -> None:
    a = _policy(tmp_path, "a.ts", b"policy A")
    out = tmp_path / "ev"
    assert _eval(out, "--controllers", "expert") == 0
    assert read_pin(out).policy_sha256 == ""
    assert _eval(out, "--policy", str(a), "--controllers", "cpp") == 0
    assert read_pin(out).policy_sha256 == sha256_of(a)
    # An expert-only resume keeps the policy's pin; once a policy flew, another one is refused.
    assert _eval(out, "--controllers", "expert") == 0
    assert read_pin(out).policy_sha256 == sha256_of(a)
    b = _policy(tmp_path, "b.ts", b"policy B")
    assert _eval(out, "--policy", str(b), "--controllers", "py") == 1
    assert "policy_sha256" in capsys.readouterr().err


def test_results_without_a_pin_are_not_resumed(
    tmp_path: Path, fake_flights: list, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "ev"
    out.mkdir()
    append_result(out / "expert.jsonl", EpisodeResult("expert", 0, 9000, "goal_reached", ""))
    assert _eval(out, "--controllers", "expert") == 1
    assert "holds results without a pin" in capsys.readouterr().err


def test_a_set_fixes_the_episodes_and_conflicts_with_seeds(
    tmp_path: Path, fake_flights: list, capsys: pytest.CaptureFixture[str]
) -> None:
    sets = tmp_path / "sets.yaml"
    sets.write_text(
        "sets:\n  dev: {seeds: '100-102', episodes: 3, density_scale: 1.0}\n"
        "  dense: {seeds: '100-102', episodes: 3, density_scale: 2.0}\n"
    )
    out = tmp_path / "ev"
    assert (
        run_eval.main(
            ["--set", "dense", "--sets-file", str(sets), "--controllers", "expert", "--out", str(out)]
        )
        == 0
    )
    assert [s.seed for s in read_episodes(out / "episodes.json")] == [100, 101, 102]
    assert read_pin(out).eval_set == "dense" and read_pin(out).density == pytest.approx(25.0)
    assert "`dense` (config/eval_sets.yaml)" in (out / "report.md").read_text()
    args = [
        "--set",
        "dev",
        "--sets-file",
        str(sets),
        "--controllers",
        "expert",
        "--out",
        str(tmp_path / "o2"),
    ]
    assert run_eval.main([*args, "--seeds", "1-3"]) == 1
    assert (
        "--set dev fixes the seeds, episodes and density; do not also give --seeds" in capsys.readouterr().err
    )
    assert run_eval.main(["--set", "nope", "--sets-file", str(sets), "--out", str(tmp_path / "o3")]) == 1
    assert "no evaluation set 'nope'" in capsys.readouterr().err


def test_the_pin_records_the_cpu_and_an_old_pin_without_it_matches_any() -> None:
    import dataclasses
    import json

    from quad_il.evaluation.pin import differences

    info = "processor : 0\nmodel name : Some CPU\nflags : fpu sse4_2 avx2 fma\n\nprocessor : 1\n"
    assert cpu_signature(info) == "Some CPU; avx2 fma sse4_2"
    assert (
        cpu_signature("model name : Other\nflags : fpu avx512f avx2 amx_tile\n")
        == "Other; amx_tile avx512f avx2"
    )
    pin = RunPin(
        "bare",
        "dev",
        "a" * 64,
        "/p.ts",
        "b" * 64,
        "/c.yaml",
        "c" * 64,
        "/s.yaml",
        "d" * 64,
        "e" * 64,
        None,
        "f" * 40,
        False,
        "engine",
        "Some CPU; avx2 fma sse4_2",
    )
    assert RunPin.from_json(pin.to_json(), "pin") == pin  # round trip
    old = json.loads(pin.to_json())
    del old["cpu"]  # written before the CPU was recorded
    old_pin = RunPin.from_json(json.dumps(old), "old pin")
    assert old_pin.cpu == "" and differences(old_pin, pin, True) == []
    other = dataclasses.replace(pin, cpu="Other; amx_tile avx512f avx2")
    assert differences(pin, other, True) == [
        "cpu: run has 'Some CPU; avx2 fma sse4_2', this invocation 'Other; amx_tile avx512f avx2'"
    ]
