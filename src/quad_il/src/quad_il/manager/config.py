"""The manager's single YAML file (pydantic v2, unknown keys rejected; every error names the key and the
value).

Sections: run, ros, simulator, tracker, expert, learner, collector, algorithm, rounds, training, eval, signals
(docs/imitation_learning.md, "Manager configuration"). Commands are argv lists whose elements may contain
`{placeholders}` filled per round (PLACEHOLDERS); an unknown placeholder is a configuration error naming the
key.
"""

from __future__ import annotations

import hashlib
import string
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from quad_il.imitation.config import AlgorithmConfig
from quad_il.tools import config_overlay


class ConfigError(ValueError):
    """The manager configuration is invalid; the message names the key and the value."""


# Placeholders available in every command and env value (filled per round by runner.RoundContext).
PLACEHOLDERS: dict[str, str] = {
    "run_dir": "absolute run directory",
    "round": "round index (0-based)",
    "round_name": "round_XXX",
    "round_dir": "run_dir/round_XXX",
    "data_dir": "round_dir/data (collector output)",
    "checkpoint_dir": "round_dir/checkpoint (training output)",
    "metrics_dir": "round_dir/metrics (evaluation output)",
    "logs_dir": "round_dir/logs (one log per child)",
    "data_dirs": "comma-separated data dirs of rounds 0..round (the aggregated dataset)",
    "policy": "policy file the learner flies this round ('none' when there is none yet)",
    "algorithm_config": "round_dir/algorithm.yaml (algorithm, round, seed, beta) for the collector",
    "seed": "run.seed + round",
    "episodes": "collector.episodes_per_round",
    "ros_port": "private ROS master port of this round",
    "ros_master_uri": "http://localhost:<ros_port>",
    "python": "the interpreter running the manager",
    "config_dir": "directory of the manager's YAML file",
}


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


Command = list[str]


class RunSection(_Strict):
    run_dir: str = Field(min_length=1)
    seed: int = Field(0, ge=0, le=2**31 - 1)


class RosSection(_Strict):
    enabled: bool = True
    port: int | Literal["auto"] = "auto"
    roscore_command: Command = Field(default_factory=lambda: ["roscore", "-p", "{ros_port}"], min_length=1)
    ready_timeout_s: float = Field(20.0, gt=0.0)

    @field_validator("port")
    @classmethod
    def _port_range(cls, port: int | str) -> int | str:
        if isinstance(port, int) and not 1024 <= port <= 65535:
            raise ValueError("must be 'auto' or in [1024, 65535]")
        return port


class ServiceSection(_Strict):
    """A long-running child of the collection stage (started before the collector, stopped after it)."""

    enabled: bool = True
    command: Command | None = None
    env: dict[str, str] = Field(default_factory=dict)

    @model_validator(mode="after")
    def _command_when_enabled(self) -> ServiceSection:
        if self.enabled and not self.command:
            raise ValueError("'command' is required when 'enabled' is true")
        return self


class CollectorSection(_Strict):
    command: Command = Field(min_length=1)
    episodes_per_round: int = Field(10, ge=1)
    timeout_s: float = Field(3600.0, gt=0.0)
    env: dict[str, str] = Field(default_factory=dict)


class RoundsSection(_Strict):
    count: int = Field(ge=1, le=10000)
    initial_policy: str | None = None


class TrainingSection(_Strict):
    command: Command = Field(min_length=1)
    timeout_s: float = Field(24 * 3600.0, gt=0.0)
    policy_file: str = Field("policy.pt", min_length=1)
    env: dict[str, str] = Field(default_factory=dict)


class EvalSection(_Strict):
    enabled: bool = False
    command: Command | None = None
    timeout_s: float = Field(3600.0, gt=0.0)
    env: dict[str, str] = Field(default_factory=dict)

    @model_validator(mode="after")
    def _command_when_enabled(self) -> EvalSection:
        if self.enabled and not self.command:
            raise ValueError("'command' is required when 'enabled' is true")
        return self


class SignalsSection(_Strict):
    sigint_timeout_s: float = Field(15.0, gt=0.0)
    sigterm_timeout_s: float = Field(5.0, gt=0.0)
    poll_interval_s: float = Field(0.1, gt=0.0, le=1.0)


class ManagerConfig(_Strict):
    run: RunSection
    ros: RosSection = RosSection()
    simulator: ServiceSection
    tracker: ServiceSection = ServiceSection(enabled=False)
    expert: ServiceSection
    learner: ServiceSection = ServiceSection(enabled=False)
    collector: CollectorSection
    algorithm: AlgorithmConfig
    rounds: RoundsSection
    training: TrainingSection
    eval: EvalSection = EvalSection()
    signals: SignalsSection = SignalsSection()

    def commands(self) -> dict[str, list[str]]:
        """Every command and env value by its config key, for placeholder validation."""
        out: dict[str, list[str]] = {"ros.roscore_command": list(self.ros.roscore_command)}
        for name in ("simulator", "tracker", "expert", "learner", "collector", "training", "eval"):
            sec = getattr(self, name)
            if sec.command:
                out[f"{name}.command"] = list(sec.command)
            for k, v in sec.env.items():
                out[f"{name}.env.{k}"] = [v]
        return out


def placeholders_in(text: str) -> list[str]:
    names = []
    for _, field, _, _ in string.Formatter().parse(text):
        if field is not None:
            names.append(field)
    return names


def _check_placeholders(cfg: ManagerConfig) -> None:
    for key, argv in cfg.commands().items():
        for i, arg in enumerate(argv):
            where = key if key.count(".env.") else f"{key}[{i}]"
            try:
                names = placeholders_in(arg)
            except ValueError as e:
                raise ConfigError(f"config key '{where}': bad template {arg!r}: {e}") from None
            for name in names:
                if name not in PLACEHOLDERS:
                    raise ConfigError(
                        f"config key '{where}': unknown placeholder {{{name}}} in {arg!r}; "
                        f"known: {', '.join(sorted(PLACEHOLDERS))}"
                    )


def _format_validation_error(err: ValidationError) -> str:
    lines = []
    for e in err.errors():
        key = ".".join(str(p) if not isinstance(p, int) else f"[{p}]" for p in e["loc"]).replace(".[", "[")
        value = e.get("input")
        shown = "" if isinstance(value, Mapping) or e["type"] == "missing" else f" (got {value!r})"
        lines.append(f"config key '{key or '<root>'}': {e['msg']}{shown}")
    return "invalid manager config:\n  " + "\n  ".join(lines)


def config_from_tree(tree: Mapping[str, Any]) -> ManagerConfig:
    try:
        cfg = ManagerConfig.model_validate(tree)
    except ValidationError as e:
        raise ConfigError(_format_validation_error(e)) from None
    _check_placeholders(cfg)
    return cfg


def load_config(path: str | Path) -> tuple[ManagerConfig, str]:
    """(validated config, the file's text). The text is what the run directory keeps. A file that is an
    overlay of another (`overlay_of:`, quad_il.tools.config_overlay) is merged over its base; its text is then
    the merged config, so the run directory holds the whole of it. Relative paths resolve against `path`'s
    directory either way."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"config file not found: {p}")
    text = p.read_text()
    try:
        if config_overlay.base_of(p) is not None:
            tree = config_overlay.load_tree(p)
            text = config_overlay.dump(tree, f"# {p}, merged over its base (quad_il.tools.config_overlay)\n")
        else:
            tree = yaml.safe_load(text)
    except config_overlay.OverlayError as e:
        raise ConfigError(str(e)) from None
    except yaml.YAMLError as e:
        raise ConfigError(f"config file {p} is not valid YAML: {e}") from None
    if not isinstance(tree, dict):
        raise ConfigError(f"config file {p} must hold a mapping at the top level, got {type(tree).__name__}")
    return config_from_tree(tree), text


def config_digest(cfg: ManagerConfig) -> str:
    """SHA-256 of the validated config (key order and comments do not matter)."""
    canonical = yaml.safe_dump(cfg.model_dump(mode="json"), sort_keys=True)
    return hashlib.sha256(canonical.encode()).hexdigest()
