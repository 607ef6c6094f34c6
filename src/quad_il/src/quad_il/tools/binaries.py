"""Finding the workspace's C++ executables (catkin installs them as <devel>/lib/<package>/<name>)."""

from __future__ import annotations

import os
from pathlib import Path


class BinaryNotFound(FileNotFoundError):
    """A workspace executable is not built; the message names it and where it was looked for."""


def find_binary(package: str, name: str) -> Path:
    """The first <prefix>/lib/<package>/<name> on CMAKE_PREFIX_PATH (the sourced devel spaces, in order:
    scripts/env.sh sets it)."""
    prefixes = [p for p in os.environ.get("CMAKE_PREFIX_PATH", "").split(os.pathsep) if p]
    for prefix in prefixes:
        candidate = Path(prefix) / "lib" / package / name
        if candidate.is_file() and os.access(candidate, os.X_OK):
            return candidate
    raise BinaryNotFound(
        f"{package}/{name} is not built: not found under lib/{package}/ of CMAKE_PREFIX_PATH "
        f"({', '.join(prefixes) or 'empty'}) "
        "(build the workspace: make build, then source scripts/env.sh)"
    )
