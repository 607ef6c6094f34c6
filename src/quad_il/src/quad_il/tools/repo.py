"""The repository root, for code that needs the repository's files (config/, training data, devel/).

One place decides it (issue 31): $QUAD_IL_ROOT when set (scripts/env.sh exports it), else the checkout this
package's source lies in (found by walking up from this file, which is how the editable install and catkin's
devel space both import it). Either way the directory must hold `config/` and `src/quad_il/package.xml`;
otherwise RepoRootError says what was looked at.
"""

from __future__ import annotations

import os
from pathlib import Path

ROOT_ENV = "QUAD_IL_ROOT"
_MARKERS = ("config", "src/quad_il/package.xml")


class RepoRootError(FileNotFoundError):
    """The repository root cannot be found; the message names the directories looked at."""


def _is_root(path: Path) -> bool:
    return all((path / m).exists() for m in _MARKERS)


def repo_root() -> Path:
    """The quad_il repository root (absolute), or RepoRootError."""
    env = os.environ.get(ROOT_ENV)
    if env:
        root = Path(env).resolve()
        if not _is_root(root):
            raise RepoRootError(
                f"{ROOT_ENV}={env} is not a quad_il repository root (it needs {' and '.join(_MARKERS)})"
            )
        return root
    here = Path(__file__).resolve()
    for candidate in here.parents:
        if _is_root(candidate):
            return candidate
    raise RepoRootError(
        f"cannot find the quad_il repository root above {here} (no directory holding "
        f"{' and '.join(_MARKERS)}): set {ROOT_ENV} to the checkout (source scripts/env.sh does)"
    )


def repo_path(*parts: str) -> Path:
    """A path inside the repository root, e.g. repo_path("config", "train.yaml")."""
    return repo_root().joinpath(*parts)
