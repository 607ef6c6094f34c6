"""Provenance written into every run directory: software commit, versions, dataset manifest."""

from __future__ import annotations

import platform
import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch
import yaml

from quad_il.learning.dataset import PreparedData, Split, expand_paths
from quad_il.tools.provenance import git_commit, sha256_file


def software_info() -> dict[str, Any]:
    return {
        **git_commit(),
        "python": sys.version.split()[0],
        "torch": torch.__version__,
        "numpy": np.__version__,
        "platform": platform.platform(),
        "torch_threads": torch.get_num_threads(),
    }


def _collector_manifest(path: Path) -> dict[str, Any] | None:
    """The collector's manifest (manifest.yaml or .json) in a dataset directory or beside an .npz, if any."""
    folder = path if path.is_dir() else path.parent
    for name in ("manifest.yaml", "manifest.json"):
        candidate = folder / name
        if candidate.is_file():
            try:
                return {"path": str(candidate), "content": yaml.safe_load(candidate.read_text())}
            except (OSError, yaml.YAMLError) as e:
                return {"path": str(candidate), "error": str(e)}
    return None


def dataset_manifest(
    paths: list[str], data: PreparedData, split: Split, hash_files: bool = True
) -> dict[str, Any]:
    files = []
    for path, kind in expand_paths(paths):
        entry: dict[str, Any] = {"path": str(path.resolve()), "kind": kind}
        if kind == "npz":
            entry["size_bytes"] = path.stat().st_size
            if hash_files:
                entry["sha256"] = sha256_file(path)
        else:
            shard_files = sorted(p for p in path.iterdir() if p.is_file())
            entry["files"] = [{"name": p.name, "size_bytes": p.stat().st_size} for p in shard_files]
        manifest = _collector_manifest(path)
        if manifest is not None:
            entry["collector_manifest"] = manifest
        files.append(entry)
    seeds_train = sorted({s for s, _ in split.train_episodes})
    seeds_val = sorted({s for s, _ in split.val_episodes})
    return {
        "sources": files,
        "per_source": [s.__dict__ for s in data.sources],
        "num_samples": len(data),
        "num_ctrl_pts": data.num_ctrl_pts,
        "horizon_s": data.horizon_s,
        "format_version": data.format_version,
        "split": {
            "rule": "by episode = (world_seed, episode_id); seeded permutation; no episode on both sides",
            "num_train_samples": int(len(split.train_idx)),
            "num_val_samples": int(len(split.val_idx)),
            "train_episodes": [list(e) for e in split.train_episodes],
            "val_episodes": [list(e) for e in split.val_episodes],
            "unused_episodes": [list(e) for e in split.unused_episodes],
            "train_world_seeds": seeds_train,
            "val_world_seeds": seeds_val,
        },
    }
