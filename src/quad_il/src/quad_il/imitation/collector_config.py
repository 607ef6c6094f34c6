"""The interactive collector node's parameters: config/imitation_collector.yaml, loaded strictly, with the
node's private parameters of the same names laid over it (MEGA-DAgger's command line sets the mappings).

No defaults here: every key must be in the file (a missing or unknown key is an error naming it and the file).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from quad_il.imitation.types import ImitationError
from quad_il.tools.repo import repo_path


class CollectorNodeConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    consumer_name: str = Field(min_length=1)
    expert_topics: dict[str, str] = Field(min_length=1)
    learner_topic: str = Field(min_length=1)
    source_consumers: dict[str, str]
    expert_noise_std_m: dict[str, Any]
    ack_grace_s: float = Field(ge=0.0)
    pair_timeout_s: float = Field(gt=0.0)
    tracker_accept_timeout_s: float = Field(ge=0.0)
    odom_period_s: float = Field(gt=0.0)
    odom_wait_s: float = Field(ge=0.0)
    voxel_size_m: float = Field(gt=0.0)
    timing_log: str


KEYS = tuple(CollectorNodeConfig.model_fields)


def shipped_config_path() -> Path:
    """config/imitation_collector.yaml of this checkout (the node's one parameter file)."""
    return repo_path("config", "imitation_collector.yaml")


def load_collector_node_config(path: str | Path, overrides: Mapping[str, Any]) -> CollectorNodeConfig:
    """The file's keys, then `overrides` (the node's private parameters of those names)."""
    p = Path(path)
    try:
        data = yaml.safe_load(p.read_text())
    except (OSError, yaml.YAMLError) as e:
        raise ImitationError(f"{p}: cannot read the collector config: {e}") from None
    if not isinstance(data, dict):
        raise ImitationError(
            f"{p}: the collector config must be a mapping of keys, got {type(data).__name__}"
        )
    merged = {**data, **overrides}
    try:
        return CollectorNodeConfig.model_validate(merged)
    except ValidationError as e:
        problems = "; ".join(f"'{'.'.join(str(x) for x in err['loc'])}': {err['msg']}" for err in e.errors())
        raise ImitationError(f"{p}: {problems}") from None
