"""Small deterministic datasets written by the real C++ writer, for tests (collector and learning stack).

    from quad_il.data.synthetic import write_synthetic_dataset
    ds_dir = write_synthetic_dataset(tmp_path / "ds", seed=3, records=64, width=64, height=48)

Runs the `write_synthetic_dataset` tool of cpp_data_collector (record i depends only on seed and i;
realistic depth images rendered from seeded box worlds, Fast-Planner-like cubic B-splines). The tool is looked
up in $QUAD_IL_COLLECTOR_BIN (a directory), then in lib/cpp_data_collector/ of every $CMAKE_PREFIX_PATH entry
(a sourced catkin devel space), then in the repository's devel/ space.
"""

from __future__ import annotations

import os
import subprocess
from collections.abc import Sequence
from pathlib import Path

from quad_il.tools.repo import RepoRootError, repo_path


def find_collector_tool(name: str) -> Path:
    """Path of a cpp_data_collector executable (write_synthetic_dataset, read_dataset)."""
    candidates: list[Path] = []
    if os.environ.get("QUAD_IL_COLLECTOR_BIN"):
        candidates.append(Path(os.environ["QUAD_IL_COLLECTOR_BIN"]) / name)
    for prefix in os.environ.get("CMAKE_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            candidates.append(Path(prefix) / "lib" / "cpp_data_collector" / name)
    try:
        candidates.append(repo_path("devel", "lib", "cpp_data_collector", name))
    except RepoRootError:
        pass  # outside a checkout: the two places above are the only ones
    for c in candidates:
        if c.is_file() and os.access(c, os.X_OK):
            return c
    raise FileNotFoundError(
        f"cpp_data_collector tool '{name}' not found "
        f"(looked in: {', '.join(str(c.parent) for c in candidates)}); "
        "build the workspace (make build) or set QUAD_IL_COLLECTOR_BIN to the directory holding it"
    )


def write_synthetic_dataset(
    out_dir: str | os.PathLike[str],
    *,
    seed: int = 1,
    records: int = 64,
    width: int = 96,
    height: int = 72,
    records_per_episode: int = 40,
    shard_size_mb: float = 64.0,
    queue_capacity: int = 32,
    policy: str = "block",
    fsync: bool = False,
    extra_args: Sequence[str] = (),
    timeout_s: float = 600.0,
) -> Path:
    """Writes `records` synthetic records to out_dir (which must not hold a dataset) and returns out_dir.

    fsync=False (the default, for tests) skips the writer's fsync of completed shards and manifests.
    """
    tool = find_collector_tool("write_synthetic_dataset")
    cmd = [
        str(tool),
        "--out",
        str(out_dir),
        "--seed",
        str(seed),
        "--records",
        str(records),
        "--width",
        str(width),
        "--height",
        str(height),
        "--records-per-episode",
        str(records_per_episode),
        "--shard-size-mb",
        repr(float(shard_size_mb)),
        "--queue-capacity",
        str(queue_capacity),
        "--policy",
        policy,
        *([] if fsync else ["--no-fsync"]),
        *extra_args,
    ]
    result = subprocess.run(cmd, capture_output=True, text=True, check=False, timeout=timeout_s)
    if result.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({result.returncode}): {result.stderr.strip()}")
    return Path(out_dir)
