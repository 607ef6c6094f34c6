"""config/policy.yaml, the configuration of both policy nodes, loaded by the C++ loader (bound): strictly
(a missing or unknown key, a wrong type or an out-of-range value is a PolicyConfigError naming the key and the
value), with overlays merged over their base (`overlay_of: BASE`, the rule of quad_il.tools.config_overlay).
docs/inference.md lists every key."""

from __future__ import annotations

import os
from typing import Any

import yaml

from quad_il.inference.core import PolicyConfigError, PolicyNodeConfig, SafetyConfig, _core

__all__ = ["PolicyConfigError", "PolicyNodeConfig", "SafetyConfig", "config_from_tree", "load_policy_config"]


def load_policy_config(path: str | os.PathLike[str]) -> PolicyNodeConfig:
    """The complete config of a file (an overlay merged over its base chain)."""
    return _core.load_policy_config(os.fspath(path))


def config_from_tree(tree: Any, source: str = "<config>") -> PolicyNodeConfig:
    """A complete config from an already parsed YAML tree (no overlay key); `source` names it in errors."""
    if not isinstance(tree, dict):
        raise PolicyConfigError(f"{source}: top level must be a mapping of keys to values")
    return _core.policy_config_from_string(yaml.safe_dump(tree, sort_keys=False), source)
