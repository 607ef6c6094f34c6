"""config/eval_sets.yaml: the development and test sets of the closed-loop evaluation (issue 30), strict.

A set fixes the world seeds, the number of episodes and the box density (a scale of the simulator config's).
Development sets are for every choice; test sets are flown only to report (docs/inference.md, "Evaluation
sets"). `world_density(set, sim_config)` turns the scale into the simulator's `density_boxes_per_100m2`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from quad_il.collection.episodes import parse_seed_ranges


class EvalSetError(ValueError):
    """The sets file or a set name is invalid; the message names the file, the set and the key."""


class EvalSet(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    seeds: str
    episodes: int = Field(ge=1)
    density_scale: float = Field(gt=0.0, le=10.0, allow_inf_nan=False)

    @field_validator("seeds")
    @classmethod
    def _seeds(cls, v: str) -> str:
        parse_seed_ranges(v)  # ValueError names the bad part
        return v

    def seed_list(self) -> list[int]:
        return parse_seed_ranges(self.seeds)


class EvalSets(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    sets: dict[str, EvalSet]


def load_eval_sets(path: str | Path) -> dict[str, EvalSet]:
    p = Path(path)
    try:
        tree = yaml.safe_load(p.read_text())
        sets = EvalSets.model_validate(tree).sets
    except OSError as e:
        raise EvalSetError(f"{p}: cannot read the evaluation sets ({e.strerror})") from None
    except yaml.YAMLError as e:
        raise EvalSetError(f"{p}: not valid YAML ({e})") from None
    except ValidationError as e:
        err = e.errors()[0]
        where = ".".join(str(x) for x in err["loc"])
        raise EvalSetError(f"{p}: {where}: {err['msg']} (got {err.get('input')!r})") from None
    for a, sa in sets.items():
        for b, sb in sets.items():
            if a < b and sa.density_scale == sb.density_scale and set(sa.seed_list()) & set(sb.seed_list()):
                raise EvalSetError(
                    f"{p}: sets {a} and {b} share world seeds at the same density: a test set must never "
                    "fly a development set's episodes"
                )
    return sets


def get_eval_set(path: str | Path, name: str) -> EvalSet:
    sets = load_eval_sets(path)
    if name not in sets:
        raise EvalSetError(f"{path}: no evaluation set {name!r} (sets: {', '.join(sorted(sets))})")
    return sets[name]


def world_density(eval_set: EvalSet, sim_tree: dict[str, Any]) -> float | None:
    """The set's boxes per 100 m^2 for a simulator config tree; None when the set keeps the config's."""
    if eval_set.density_scale == 1.0:
        return None
    gen = sim_tree["world"]["generator"]
    base = float(gen["density_boxes_per_100m2"])
    if base <= 0.0:  # num_boxes over the generator's area
        lo, hi = gen["bounds_min_m"], gen["bounds_max_m"]
        area_100m2 = (hi[0] - lo[0]) * (hi[1] - lo[1]) / 100.0
        base = float(gen["num_boxes"]) / area_100m2
    return base * eval_set.density_scale
