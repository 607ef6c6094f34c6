"""Config overlays: a variant of a config holds only the keys it changes (issue 31, STYLE.md point 17).

An overlay file names its base with one top-level key, `overlay_of: PATH` (relative to the overlay's own
directory); every other key is merged over the base as `config/experiments/` files are merged over
config/train.yaml: a mapping merges key by key, any other value (a scalar, a list) replaces the base's value.
Unlike an experiment overlay, every key an overlay sets must exist in its base with the same kind of value
(a section stays a section), so a misspelt key is an error naming it and both files instead of a key the
strict loader meets only later. An overlay may name another overlay as its base (a chain, no cycle).

The merged tree is the config the variant always meant: relative paths in it are read, as before, against the
overlay's directory by the loaders that resolve them (the IL manager, the episode manager). `resolve` writes
the merged file elsewhere, so it makes the file paths the C++ loaders read relative to their config (the keys
of FILE_KEYS: the simulator's vehicle, world and OctoMap files) absolute against the overlay's directory.

Python loaders call `load_tree`. A C++ node reads its file itself, so its launch file resolves the overlay
while it is parsed (`<param name="config" command="PYTHON -m quad_il.tools.config_overlay resolve FILE"/>`,
launch/il_expert.launch): `resolve` prints FILE's own path when it is a full config, else writes the merged
config (named by its content hash, written atomically) and prints that path, without a newline.

    python -m quad_il.tools.config_overlay resolve FILE [--out-dir DIR]   # path of the full config
    python -m quad_il.tools.config_overlay merge FILE                     # the full config as YAML on stdout
"""

from __future__ import annotations

import argparse
import copy
import hashlib
import os
import sys
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from quad_il.tools.cli import HelpFormatter

OVERLAY_KEY = "overlay_of"
# Keys whose relative values a C++ loader reads against its config file's directory (quad_sim's config:
# vehicle_file, world.file, voxel_map.octomap_file); a merged overlay written elsewhere gets them absolute.
FILE_KEYS = ("vehicle_file", "file", "octomap_file")


class OverlayError(ValueError):
    """An unreadable file, a missing base, a cycle, or an overlay key its base does not have; the message
    names the file and the key."""


def deep_merge(base: Mapping[str, Any], update: Mapping[str, Any]) -> dict[str, Any]:
    """`update` over `base`: mappings merge key by key, any other value replaces (config/experiments/'s rule).
    New keys are allowed here; `merge_overlay` is the strict form."""
    out = copy.deepcopy(dict(base))
    for key, value in update.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), dict):
            out[key] = deep_merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def merge_overlay(
    base: Mapping[str, Any], overlay: Mapping[str, Any], source: str = "<overlay>", prefix: str = ""
) -> dict[str, Any]:
    """`overlay` over `base`, where every key of the overlay must exist in the base with the same kind of
    value (mapping or not). `source` names the overlay (and its base) in errors."""
    out = copy.deepcopy(dict(base))
    for key, value in overlay.items():
        name = f"{prefix}{key}"
        if key not in out:
            raise OverlayError(f"{source}: key '{name}' does not exist in the base config")
        if isinstance(out[key], dict) != isinstance(value, Mapping):
            kind = "a section" if isinstance(out[key], dict) else "a value"
            raise OverlayError(
                f"{source}: key '{name}' is {kind} in the base config, the overlay gives {value!r}"
            )
        if isinstance(value, Mapping):
            out[key] = merge_overlay(out[key], value, source, f"{name}.")
        else:
            out[key] = copy.deepcopy(value)
    return out


def read_mapping(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The YAML mapping a file holds; errors name the file."""
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as e:
        raise OverlayError(f"config file {p} cannot be read ({e.strerror})") from None
    try:
        tree = yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise OverlayError(f"config file {p} is not valid YAML: {e}") from None
    if tree is None:
        return {}
    if not isinstance(tree, dict):
        raise OverlayError(f"config file {p} must hold a mapping at the top level, got {type(tree).__name__}")
    return tree


def base_of(path: str | os.PathLike[str], tree: Mapping[str, Any] | None = None) -> Path | None:
    """The base an overlay names (resolved against the overlay's directory), or None for a full config."""
    p = Path(path)
    tree = read_mapping(p) if tree is None else tree
    if OVERLAY_KEY not in tree:
        return None
    ref = tree[OVERLAY_KEY]
    if not isinstance(ref, str) or not ref.strip():
        raise OverlayError(f"{p}: '{OVERLAY_KEY}' must be the path of the base config, got {ref!r}")
    base = Path(ref)
    return (base if base.is_absolute() else p.resolve().parent / base).resolve()


def load_tree(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The full config tree of `path`: the file itself, or its base's full tree with the overlay's keys
    set."""
    return _load(Path(path), [])


def _load(p: Path, seen: list[Path]) -> dict[str, Any]:
    if p.resolve() in seen:
        chain = " -> ".join(str(s) for s in [*seen, p.resolve()])
        raise OverlayError(f"overlay cycle: {chain}")
    tree = read_mapping(p)
    base = base_of(p, tree)
    if base is None:
        return tree
    if not base.is_file():
        raise OverlayError(f"{p}: {OVERLAY_KEY} names {tree[OVERLAY_KEY]!r}, which does not exist ({base})")
    overlay = {k: v for k, v in tree.items() if k != OVERLAY_KEY}
    full = _load(base, [*seen, p.resolve()])
    return merge_overlay(full, overlay, f"{p} (overlay of {base})")


def dump(tree: Mapping[str, Any], header: str = "") -> str:
    return header + yaml.safe_dump(dict(tree), sort_keys=False, default_flow_style=None)


def with_absolute_files(tree: Any, base_dir: Path) -> Any:
    """A copy of `tree`, every non-empty relative value of a FILE_KEYS key made absolute against base_dir."""
    if isinstance(tree, Mapping):
        out = {}
        for k, v in tree.items():
            if k in FILE_KEYS and isinstance(v, str) and v and not os.path.isabs(v):
                out[k] = os.path.normpath(base_dir / v)
            else:
                out[k] = with_absolute_files(v, base_dir)
        return out
    if isinstance(tree, list):
        return [with_absolute_files(v, base_dir) for v in tree]
    return tree


def default_out_dir() -> Path:
    return Path(tempfile.gettempdir()) / f"quad_il_configs_{os.getuid()}"


def resolve(path: str | os.PathLike[str], out_dir: str | os.PathLike[str] | None = None) -> Path:
    """`path` itself (absolute) for a full config; for an overlay, the merged config written to out_dir."""
    p = Path(os.path.abspath(path))  # a full config keeps the path it was given (symlinks unresolved)
    if not p.is_file():
        raise OverlayError(f"config file {p} not found")
    if base_of(p) is None:
        return p
    header = f"# {p} merged over its base by quad_il.tools.config_overlay; do not edit.\n"
    text = dump(with_absolute_files(load_tree(p), p.parent), header)
    digest = hashlib.sha256(text.encode()).hexdigest()[:16]
    d = Path(out_dir) if out_dir is not None else default_out_dir()
    d.mkdir(parents=True, exist_ok=True)
    out = d / f"{p.stem}.{digest}.yaml"
    if not out.is_file() or out.read_text() != text:
        # Two launches resolving the same overlay at once each write a complete file and rename it into place.
        fd, tmp = tempfile.mkstemp(dir=d, prefix=f".{p.stem}.", suffix=".partial")
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.replace(tmp, out)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        formatter_class=HelpFormatter,
        prog="quad_il.tools.config_overlay",
        description=__doc__.splitlines()[0],
    )
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser(
        "resolve",
        formatter_class=HelpFormatter,
        help="print the path of FILE's full config (written if FILE is an overlay)",
    )
    r.add_argument("file", help="config file or overlay")
    r.add_argument(
        "--out-dir", default=None, help=f"where merged configs are written (default: {default_out_dir()})"
    )
    m = sub.add_parser("merge", formatter_class=HelpFormatter, help="print FILE's full config as YAML")
    m.add_argument("file", help="config file or overlay")
    args = ap.parse_args(argv)
    try:
        if args.cmd == "resolve":
            # No newline: roslaunch uses the output as the parameter's value.
            sys.stdout.write(str(resolve(args.file, args.out_dir)))
        else:
            sys.stdout.write(dump(load_tree(args.file)))
    except OverlayError as e:
        print(f"config_overlay: error: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
