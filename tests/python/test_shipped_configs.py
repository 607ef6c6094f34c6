"""Every shipped YAML file loads with the strict loader its user reads it with (issue 30).

The files are every *.yaml / *.yml that git tracks or would track (`git ls-files --cached --others
--exclude-standard`), so a newly added config is covered at once; a file no rule below names fails with
"no loader for <file>". Python configs load through their pydantic loaders; C++ configs through
fast_planner's `config_check KIND FILE`, which calls the same StrictYaml loaders as the nodes. A manager
config's references to other configs (`{config_dir}/...yaml` in its commands) must exist too. An overlay
(`overlay_of: BASE`, quad_il.tools.config_overlay) is checked merged over its base, as its users load it (the
Python loaders merge it themselves; a C++ node is given the merged file by its launch file).
"""

from __future__ import annotations

import fnmatch
import re
import subprocess
from collections.abc import Callable
from pathlib import Path

import pytest

from quad_il.collection.episodes import load_collect_config
from quad_il.evaluation.learning_curve import parse_spec as load_learning_curve_spec
from quad_il.evaluation.sets import load_eval_sets
from quad_il.imitation.collector_config import load_collector_node_config
from quad_il.inference.config import load_policy_config
from quad_il.learning.config import load_config as load_train_config
from quad_il.manager.config import load_config as load_manager_config
from quad_il.tools import config_overlay
from quad_il.tools.binaries import find_binary

ROOT = Path(__file__).resolve().parents[2]


def shipped_yaml_files() -> list[str]:
    out = subprocess.run(
        ["git", "ls-files", "--cached", "--others", "--exclude-standard", "*.yaml", "*.yml"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    # src/quad_il/config is a symlink to config/: git lists each file once, under config/.
    return sorted(f for f in set(out) if (ROOT / f).is_file())


def cpp_loader(kind: str, out_dir: Path | None = None) -> Callable[[Path], None]:
    """config_check KIND on the file, or on an overlay's merged config (written to out_dir)."""

    def load(path: Path) -> None:
        full = config_overlay.resolve(path, out_dir)
        proc = subprocess.run(
            [str(find_binary("quad_bench", "config_check")), kind, str(full)],
            capture_output=True,
            text=True,
        )
        assert proc.returncode == 0, f"{path} does not load as a {kind} config: {proc.stderr.strip()}"
        assert proc.stdout.strip() == f"ok: {kind} {full}"

    return load


CONFIG_REF = re.compile(r"\{config_dir\}/([^\s\"',]+\.ya?ml)")


def load_manager(path: Path) -> None:
    cfg, _ = load_manager_config(path)
    for key, argv in cfg.commands().items():
        for arg in argv:
            for ref in CONFIG_REF.findall(arg):
                target = path.parent / ref
                assert target.is_file(), f"{path}: {key} refers to {ref}, which does not exist ({target})"


def load_train_overlay(path: Path) -> None:
    """An experiment overlay is layered on config/train.yaml (training_only/run_experiment.py,
    docs/learning.md)."""
    load_train_config([ROOT / "config" / "train.yaml", path])


# (pattern, loader name, loader); the first pattern matching the repository-relative path wins.
RULES: list[tuple[str, str, Callable[[Path], None]]] = [
    ("config/collect.yaml", "collect", load_collect_config),
    ("config/il/episodes*.yaml", "collect", load_collect_config),
    ("tests/rostest/collect_*.yaml", "collect", load_collect_config),
    ("config/collector.yaml", "c++ collector", cpp_loader("collector")),
    ("config/eval_sets.yaml", "eval sets", load_eval_sets),
    ("config/imitation_collector.yaml", "collector node", lambda p: load_collector_node_config(p, {})),
    ("config/il_manager.yaml", "manager", load_manager),
    ("config/il/planner*.yaml", "c++ planner (overlay of config/planner.yaml)", cpp_loader("planner")),
    ("config/il/*.yaml", "manager", load_manager),
    ("config/planner_*.yaml", "c++ planner (overlay of config/planner.yaml)", cpp_loader("planner")),
    ("config/planner.yaml", "c++ planner", cpp_loader("planner")),
    ("config/policy*.yaml", "policy", load_policy_config),
    ("config/sim.yaml", "c++ sim", cpp_loader("sim")),
    ("config/sim_*.yaml", "c++ sim (overlay of config/sim.yaml)", cpp_loader("sim")),
    ("tests/rostest/*.yaml", "c++ sim", cpp_loader("sim")),
    ("config/tracker.yaml", "c++ tracker", cpp_loader("tracker")),
    ("config/train.yaml", "train", lambda p: load_train_config([p])),
    (
        "models/*/train_config.yaml",
        "train (a shipped policy's resolved config)",
        lambda p: load_train_config([p]),
    ),
    ("config/experiments/*.yaml", "train overlay", load_train_overlay),
    ("config/vehicle.yaml", "c++ vehicle", cpp_loader("vehicle")),
    (
        "docs/figures/*.yaml",
        "learning curve (the evaluations are not in the repository)",
        load_learning_curve_spec,
    ),
    ("config/worlds/*.yaml", "c++ world", cpp_loader("world")),
]


def loader_for(rel: str) -> tuple[str, Callable[[Path], None]] | None:
    for pattern, name, load in RULES:
        if fnmatch.fnmatchcase(rel, pattern):
            return name, load
    return None


FILES = shipped_yaml_files()


def test_the_shipped_files_are_found() -> None:
    # The 14 interactive-learning configs and the other shipped ones (a glob that found nothing would pass).
    assert len([f for f in FILES if f.startswith("config/il/")]) == 14
    for expected in (
        "config/sim.yaml",
        "config/planner.yaml",
        "config/policy_keep.yaml",
        "config/train.yaml",
    ):
        assert expected in FILES


@pytest.mark.parametrize("rel", FILES)
def test_shipped_config_loads_with_its_strict_loader(rel: str) -> None:
    found = loader_for(rel)
    if found is None:
        pytest.fail(f"no loader for {rel}: add a rule to RULES in {Path(__file__).name}")
    _, load = found
    load(ROOT / rel)


def test_a_file_without_a_rule_fails_with_no_loader() -> None:
    assert loader_for("config/new_component.yaml") is None
    assert loader_for("docs/example.yaml") is None


@pytest.mark.parametrize(
    ("kind", "rel", "edit", "needle"),
    [
        ("planner", "config/planner.yaml", ("  max_acc_mps2:", "  max_accel_mps2:"), "limits.max_acc_mps2"),
        ("tracker", "config/tracker.yaml", ("controller:", "bogus_key: 1\ncontroller:"), "'bogus_key'"),
        ("world", "config/worlds/gate.yaml", ("bounds_max_m:", "bounds_maximum_m:"), "bounds_max"),
        ("collector", "config/collector.yaml", ("fsync: true", "fsync: 3"), "fsync"),
    ],
)
def test_the_cpp_loader_refuses_a_broken_shipped_file(
    tmp_path: Path, kind: str, rel: str, edit: tuple[str, str], needle: str
) -> None:
    # The check can fail: a shipped file with one key broken makes config_check exit 1 naming the key.
    text = (ROOT / rel).read_text()
    assert edit[0] in text
    bad = tmp_path / Path(rel).name
    bad.write_text(text.replace(edit[0], edit[1], 1))
    proc = subprocess.run(
        [str(find_binary("quad_bench", "config_check")), kind, str(bad)], capture_output=True, text=True
    )
    assert proc.returncode == 1, proc.stdout
    assert str(bad) in proc.stderr and needle in proc.stderr, proc.stderr


def test_an_unknown_key_in_a_shipped_sim_config_is_refused(tmp_path: Path) -> None:
    # config/sim.yaml beside its vehicle file, with one key misspelt.
    (tmp_path / "vehicle.yaml").write_text((ROOT / "config" / "vehicle.yaml").read_text())
    text = (ROOT / "config" / "sim.yaml").read_text()
    assert "\nodometry_rate_hz:" in text
    good = tmp_path / "sim.yaml"
    good.write_text(text)
    cpp_loader("sim")(good)
    bad = tmp_path / "sim_misspelt.yaml"
    bad.write_text(text.replace("\nodometry_rate_hz:", "\nodometry_rate_hertz:", 1))
    with pytest.raises(AssertionError, match="odometry_rate_h"):
        cpp_loader("sim")(bad)


def test_a_manager_config_referring_to_a_missing_config_is_refused(tmp_path: Path) -> None:
    text = (ROOT / "config" / "il" / "dagger_cmp.yaml").read_text()
    assert "{config_dir}/../train.yaml" in text
    bad = tmp_path / "il" / "dagger_cmp.yaml"
    bad.parent.mkdir()
    bad.write_text(text)  # tmp_path has no train.yaml beside il/
    with pytest.raises(AssertionError, match=r"refers to \.\./(policy_plain|train)\.yaml, which does not"):
        load_manager(bad)
