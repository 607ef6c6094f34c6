"""Evaluation tiers (issue 30): how much hand-written behaviour stands between the network and the tracker.

A tier is an overlay of a few policy-node config keys on a base config (default config/policy.yaml, itself
merged over its base when it is an overlay); the result is a complete config that both nodes read strictly,
written into the evaluation directory and pinned by its hash. Keys a tier does not name (rates, odometry age,
the stopping trajectory, limits) keep the base's value.

- `bare`: the network's plan is sent as it is. Only a non-finite output is refused (the node then sends the
  refusal action, a braking trajectory); no depth or limit check, no recovery, final approach or keeping.
- `safety`: the depth and limit checks of `safety` refuse; a refusal brakes. No recovery, final approach or
  keeping.
- `shield`: the base config as it is (config/policy.yaml: recovery, final approach, keeping the plan).

    python -m quad_il.evaluation.tiers --tier bare [--base config/policy.yaml] --out policy_bare.yaml
"""

from __future__ import annotations

import argparse
import copy
import sys
from pathlib import Path
from typing import Any

import yaml

from quad_il.inference.config import PolicyConfigError, config_from_tree
from quad_il.tools.cli import HelpFormatter
from quad_il.tools.config_overlay import OverlayError, load_tree

TIERS = ("bare", "safety", "shield")
DEFAULT_TIER = "shield"

# Everything hand-written that is not the safety layer's refusal, switched off.
_NO_BEHAVIOURS: dict[str, dict[str, Any]] = {
    "refusal": {"action": "stop"},
    "recovery": {"goal_yaw_offsets_deg": [], "final_approach_m": 0.0},
    "keeping": {"commit_s": 0.0, "on_refusal": False},
}
OVERLAYS: dict[str, dict[str, dict[str, Any]]] = {
    "bare": {**_NO_BEHAVIOURS, "safety": {"enabled": False}},
    "safety": {**_NO_BEHAVIOURS, "safety": {"enabled": True}},
    "shield": {},
}


class TierError(ValueError):
    """An unknown tier, or a base config the tier cannot apply to; the message says which."""


def apply_tier(base: Any, tier: str, source: str = "<config>") -> dict[str, Any]:
    """The base config tree with the tier's keys set; checked with the nodes' strict schema. `source` names
    the base in errors."""
    if tier not in OVERLAYS:
        raise TierError(f"unknown tier {tier!r} (choose from {', '.join(TIERS)})")
    if not isinstance(base, dict):
        raise TierError(f"{source}: top level must be a mapping of keys to values")
    tree = copy.deepcopy(base)
    for section, keys in OVERLAYS[tier].items():
        if not isinstance(tree.get(section), dict):
            raise TierError(f"{source}: tier {tier} needs the section {section!r}, which is missing")
        for key, value in keys.items():
            if key not in tree[section]:
                raise TierError(f"{source}: tier {tier} needs the key {section}.{key}, which is missing")
            tree[section][key] = copy.deepcopy(value)
    try:
        config_from_tree(tree, f"{source} (tier {tier})")
    except PolicyConfigError as e:
        raise TierError(str(e)) from None
    return tree


def render_tier_config(base_path: str | Path, tier: str) -> str:
    """The tier's complete node config as YAML text, with a header naming the base and the tier."""
    base_path = Path(base_path)
    try:
        base = load_tree(base_path)  # an overlay: merged over its base chain
    except OverlayError as e:
        raise TierError(f"{base_path}: cannot read the base node config: {e}") from None
    tree = apply_tier(base, tier, str(base_path))
    header = (
        f"# Policy node config of evaluation tier '{tier}': {base_path.name} with quad_il.evaluation.tiers.\n"
    )
    return header + yaml.safe_dump(tree, sort_keys=False)


def write_tier_config(base_path: str | Path, tier: str, out_path: str | Path) -> Path:
    """Writes the tier's complete node config and returns its path."""
    out = Path(out_path)
    text = render_tier_config(base_path, tier)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(formatter_class=HelpFormatter, description=__doc__.split("\n\n")[0])
    ap.add_argument("--tier", required=True, choices=TIERS)
    ap.add_argument("--base", default="config/policy.yaml", help="the node config the tier applies to")
    ap.add_argument("--out", required=True, help="where to write the complete node config")
    args = ap.parse_args(argv)
    try:
        print(write_tier_config(args.base, args.tier, args.out))
    except (TierError, OSError) as e:
        print(f"tiers: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
