"""The identity of an engine collection run (OUT/collect_run.yaml, quad_il.collection.resume): what
`quad_il.engine.collect` and `quad_il.engine.dagger` record so that `--resume` continues only the same run.
It holds the arguments collect.launch records for a lockstep run, with every config as an absolute path, and
the tool's own keys (a DAgger round: its learner and the learner's policy config)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from quad_il.tools.repo import repo_root


def absolute(path: str | Path) -> str:
    """`path` made absolute: a relative path is under the repository root."""
    p = Path(path)
    return str(p if p.is_absolute() else (repo_root() / p).resolve())


def collection_run_args(
    seeds: str,
    episodes: int,
    max_samples: int,
    episode_timeout_s: float,
    configs: Mapping[str, str | Path],
    extra: Mapping[str, str | Path] | None = None,
) -> dict[str, str]:
    """The run's identity. `configs` (key -> file, e.g. "sim_config") and every `extra` key ending in
    "_config" must name existing files; ValueError naming the key and the file otherwise, so that a bad
    argument is refused before the output directory is created."""
    files = {key: absolute(path) for key, path in configs.items()}
    more = {key: absolute(value) for key, value in (extra or {}).items()}
    for key, path in {**files, **more}.items():
        if key.endswith("_config") and not Path(path).is_file():
            raise ValueError(f"{key} {path}: no such file")
    return {
        "seeds": seeds,
        "episodes": str(episodes),
        "max_samples": str(max_samples),
        "episode_timeout_s": str(episode_timeout_s),
        "time_mode": "lockstep",
        "time_factor": "1.0",
        **files,
        **more,
    }
