"""Config overlays (issue 31): a variant holds only the keys it changes, merged over the base it names.

The shipped overlays are checked as a whole here (each merged over its base changes exactly its own keys);
that each loads with its strict loader is tests/python/test_shipped_configs.py's job.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml

from quad_il.tools import config_overlay
from quad_il.tools.config_overlay import OverlayError, load_tree, merge_overlay, resolve

ROOT = Path(__file__).resolve().parents[2]

# Variants that are overlays, with their bases (a full copy coming back fails the first test).
SHIPPED_OVERLAYS = {
    "config/il/planner_expert_b.yaml": "config/planner.yaml",
    "config/il/episodes.yaml": "config/collect.yaml",
    "config/il/dagger_fa.yaml": "config/il/dagger_cmp.yaml",
    "config/il/dagger_fa_r0.yaml": "config/il/dagger_fa.yaml",
    "config/il/eil_fa.yaml": "config/il/eil_cmp.yaml",
    "config/il/dagger_small.yaml": "config/il_manager.yaml",
}


def leaves(tree: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(tree, dict):
        out: dict[str, Any] = {}
        for k, v in tree.items():
            out.update(leaves(v, f"{prefix}{k}."))
        return out
    return {prefix[:-1]: tree}


def shipped_overlays() -> list[str]:
    return sorted(
        str(p.relative_to(ROOT))
        for p in (ROOT / "config").rglob("*.yaml")
        if config_overlay.base_of(p) is not None
    )


def test_the_variants_are_overlays_of_their_bases() -> None:
    assert set(SHIPPED_OVERLAYS) <= set(shipped_overlays())
    for rel, base in SHIPPED_OVERLAYS.items():
        assert config_overlay.base_of(ROOT / rel) == (ROOT / base).resolve(), rel


@pytest.mark.parametrize("rel", shipped_overlays())
def test_a_shipped_overlay_changes_exactly_its_own_keys(rel: str) -> None:
    overlay = config_overlay.read_mapping(ROOT / rel)
    del overlay[config_overlay.OVERLAY_KEY]
    base_path = config_overlay.base_of(ROOT / rel)
    assert base_path is not None
    base = load_tree(base_path)
    merged = load_tree(ROOT / rel)
    base_leaves, merged_leaves, own = leaves(base), leaves(merged), leaves(overlay)
    # The merge keeps the base's key set; the keys whose value changed are the overlay's, and every key the
    # overlay names changes something (an overlay holds only the keys it changes).
    assert set(merged_leaves) == set(base_leaves)
    changed = {k for k in merged_leaves if merged_leaves[k] != base_leaves[k]}
    assert changed == set(own), f"{rel}: changed {sorted(changed)}, overlay names {sorted(own)}"
    assert all(merged_leaves[k] == v for k, v in own.items())


def test_planner_expert_b_is_the_planner_with_four_keys_changed() -> None:
    merged = load_tree(ROOT / "config/il/planner_expert_b.yaml")
    base = load_tree(ROOT / "config/planner.yaml")
    diff = {k: v for k, v in leaves(merged).items() if leaves(base)[k] != v}
    assert diff == {
        "map.inflation_m": 0.15,
        "search.time_weight": 20.0,
        "optimizer.w_distance": 20.0,
        "optimizer.safe_distance_m": 0.35,
    }


def write(path: Path, tree: dict[str, Any]) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(tree, sort_keys=False))
    return path


BASE = {"a": 1, "sec": {"x": 1.0, "y": [1, 2], "inner": {"z": "s"}}}


def test_an_overlay_merges_sections_and_replaces_values_and_lists(tmp_path: Path) -> None:
    write(tmp_path / "base.yaml", BASE)
    ov = write(
        tmp_path / "sub" / "ov.yaml",
        {"overlay_of": "../base.yaml", "sec": {"y": [3], "inner": {"z": "t"}}},
    )
    assert load_tree(ov) == {"a": 1, "sec": {"x": 1.0, "y": [3], "inner": {"z": "t"}}}
    # A chain: an overlay of an overlay.
    ov2 = write(tmp_path / "ov2.yaml", {"overlay_of": "sub/ov.yaml", "a": 2})
    assert load_tree(ov2) == {"a": 2, "sec": {"x": 1.0, "y": [3], "inner": {"z": "t"}}}


@pytest.mark.parametrize(
    ("overlay", "message"),
    [
        ({"sec": {"xx": 2.0}}, "key 'sec.xx' does not exist in the base config"),
        ({"b": 1}, "key 'b' does not exist in the base config"),
        ({"sec": 3}, "key 'sec' is a section in the base config"),
        ({"a": {"q": 1}}, "key 'a' is a value in the base config"),
    ],
)
def test_an_overlay_key_the_base_does_not_have_is_refused_naming_it(
    tmp_path: Path, overlay: dict[str, Any], message: str
) -> None:
    write(tmp_path / "base.yaml", BASE)
    ov = write(tmp_path / "ov.yaml", {"overlay_of": "base.yaml", **overlay})
    with pytest.raises(OverlayError, match=message) as e:
        load_tree(ov)
    assert str(ov) in str(e.value) and "base.yaml" in str(e.value)


def test_a_missing_base_and_a_cycle_are_refused(tmp_path: Path) -> None:
    ov = write(tmp_path / "ov.yaml", {"overlay_of": "nope.yaml", "a": 1})
    with pytest.raises(OverlayError, match=r"overlay_of names 'nope.yaml', which does not exist"):
        load_tree(ov)
    write(tmp_path / "p.yaml", {"overlay_of": "q.yaml", "a": 1})
    write(tmp_path / "q.yaml", {"overlay_of": "p.yaml", "a": 2})
    with pytest.raises(OverlayError, match="overlay cycle"):
        load_tree(tmp_path / "p.yaml")
    bad = write(tmp_path / "bad.yaml", {"overlay_of": 3})
    with pytest.raises(OverlayError, match="must be the path of the base config"):
        load_tree(bad)


def test_merge_overlay_does_not_change_its_inputs() -> None:
    base = {"s": {"v": [1]}}
    out = merge_overlay(base, {"s": {"v": [2]}})
    assert base == {"s": {"v": [1]}} and out == {"s": {"v": [2]}}


def test_resolve_gives_a_full_config_its_own_path_and_an_overlay_a_merged_file(tmp_path: Path) -> None:
    base = write(tmp_path / "base.yaml", BASE)
    assert resolve(base, tmp_path / "out") == base
    assert not (tmp_path / "out").exists()
    ov = write(tmp_path / "ov.yaml", {"overlay_of": "base.yaml", "a": 5})
    first = resolve(ov, tmp_path / "out")
    assert first.parent == tmp_path / "out"
    assert yaml.safe_load(first.read_text()) == load_tree(ov)
    assert resolve(ov, tmp_path / "out") == first  # named by content: the same overlay, the same file
    write(ov, {"overlay_of": "base.yaml", "a": 6})
    second = resolve(ov, tmp_path / "out")
    assert second != first and yaml.safe_load(second.read_text())["a"] == 6
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == sorted([first.name, second.name])


def test_a_resolved_sim_overlay_keeps_its_file_paths_pointing_where_they_pointed(tmp_path: Path) -> None:
    """The merged file lives in another directory: the simulator's relative file paths (read against the
    config's directory by the C++ loader) become absolute against the overlay's; others stay as they are."""
    cfg = tmp_path / "cfg"
    cfg.mkdir()
    (cfg / "sim.yaml").write_text((ROOT / "config" / "sim.yaml").read_text())
    (cfg / "dense.yaml").write_text(
        "overlay_of: sim.yaml\nworld:\n  file: worlds/w.yaml\n"
        "  generator:\n    density_boxes_per_100m2: 18.75\n"
    )
    merged = resolve(cfg / "dense.yaml", tmp_path / "out")
    assert merged.parent == tmp_path / "out"
    tree = yaml.safe_load(merged.read_text())
    assert tree["vehicle_file"] == str(cfg / "vehicle.yaml")
    assert tree["world"]["file"] == str(cfg / "worlds" / "w.yaml")
    assert tree["voxel_map"]["octomap_file"] == ""  # empty: still "don't"
    assert tree["world"]["generator"]["density_boxes_per_100m2"] == 18.75
    assert resolve(cfg / "sim.yaml") == cfg / "sim.yaml"  # a full config is read where it is, unchanged


def test_the_cli_prints_the_path_without_a_newline_and_names_a_bad_key(tmp_path: Path) -> None:
    write(tmp_path / "base.yaml", BASE)
    ov = write(tmp_path / "ov.yaml", {"overlay_of": "base.yaml", "a": 5})
    cmd = [sys.executable, "-m", "quad_il.tools.config_overlay", "resolve", str(ov)]
    cmd += ["--out-dir", str(tmp_path)]
    out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
    assert not out.endswith("\n") and yaml.safe_load(Path(out).read_text())["a"] == 5
    write(ov, {"overlay_of": "base.yaml", "sec": {"w": 1}})
    proc = subprocess.run(cmd, capture_output=True, text=True)
    assert proc.returncode == 1 and "key 'sec.w' does not exist in the base config" in proc.stderr


def test_il_mega_experts_launch_gives_expert_b_the_merged_planner_config() -> None:
    # roslaunch evaluates the launch-time merge while it parses; expert_a keeps config/planner.yaml itself.
    proc = subprocess.run(
        ["roslaunch", "--dump-params", "quad_il", "il_mega_experts.launch", f"python:={sys.executable}"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    params = yaml.safe_load(proc.stdout)
    assert Path(params["/fast_planner/config"]).resolve() == (ROOT / "config/planner.yaml").resolve()
    merged = Path(params["/fast_planner_b/config"])
    assert merged.name.startswith("planner_expert_b.")
    assert yaml.safe_load(merged.read_text()) == load_tree(ROOT / "config/il/planner_expert_b.yaml")
