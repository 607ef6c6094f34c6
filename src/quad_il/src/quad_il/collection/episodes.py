"""Start/goal sampling, stop conditions and the episode log of a collection run.

Everything here is ROS-free and deterministic given the seed, so the same seeds give the same episodes.
"""

from __future__ import annotations

import csv
import io
import math
import os
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from quad_il.tools import config_overlay


class StartGoalConfig(BaseModel):
    """Where episodes start and end: inside the world's flying area, a margin from its edges."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    bounds_min_xy_m: tuple[float, float] = (-20.0, -20.0)
    bounds_max_xy_m: tuple[float, float] = (20.0, 20.0)
    margin_m: float = Field(2.0, ge=0.0)
    min_distance_m: float = Field(20.0, gt=0.0)
    max_distance_m: float = Field(30.0, gt=0.0)
    altitude_min_m: float = Field(1.0, gt=0.0)
    altitude_max_m: float = Field(2.0, gt=0.0)
    max_tries: int = Field(1000, ge=1)

    @model_validator(mode="after")
    def _check_ranges(self) -> StartGoalConfig:
        lo = np.asarray(self.bounds_min_xy_m) + self.margin_m
        hi = np.asarray(self.bounds_max_xy_m) - self.margin_m
        if np.any(lo >= hi):
            raise ValueError(
                f"start_goal: bounds {self.bounds_min_xy_m}..{self.bounds_max_xy_m} leave no room "
                f"after margin_m={self.margin_m}"
            )
        if self.min_distance_m > self.max_distance_m:
            raise ValueError(
                f"start_goal: min_distance_m={self.min_distance_m} > max_distance_m={self.max_distance_m}"
            )
        if self.altitude_min_m > self.altitude_max_m:
            raise ValueError(
                f"start_goal: altitude_min_m={self.altitude_min_m} > altitude_max_m={self.altitude_max_m}"
            )
        if self.min_distance_m > float(np.linalg.norm(hi - lo)):
            raise ValueError(f"start_goal: min_distance_m={self.min_distance_m} does not fit in the area")
        return self


class CollectConfig(BaseModel):
    """A collection run (config/collect.yaml); launch arguments override single keys."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    output_dir: str = "data/demo_dataset"
    # World seeds of the episodes, used in order and cycled; an empty list means first_seed, first_seed+1, ...
    seeds: list[int] = Field(default_factory=list)
    first_seed: int = Field(0, ge=0)
    episodes: int = Field(10, ge=1)
    # Stop once this many samples (expert plans) were recorded; 0 = no limit.
    max_samples: int = Field(0, ge=0)
    # Sim-time limit of one episode (from the goal); a slower episode ends with outcome "timeout".
    episode_timeout_s: float = Field(60.0, gt=0.0)
    # Sim-time limit of the take-off (from the reset) to the start altitude.
    takeoff_timeout_s: float = Field(15.0, gt=0.0)
    # Restart the tracker before every reset, so that it starts from the new episode's start (kr_tracker keeps
    # its previous reference across a simulator reset) and every episode starts from the same tracker state.
    restart_tracker: bool = True
    start_goal: StartGoalConfig = StartGoalConfig()


def load_collect_config(path: str | os.PathLike, overrides: dict | None = None) -> CollectConfig:
    """Load and validate a collection config; errors name the offending key. A file that is an overlay of
    another (`overlay_of:`, quad_il.tools.config_overlay: config/il/episodes.yaml) is merged over its base."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"collection config not found: {p}")
    data = config_overlay.load_tree(p)  # OverlayError is a ValueError naming the file and key
    data.update({k: v for k, v in (overrides or {}).items() if v is not None})
    try:
        return CollectConfig.model_validate(data)
    except ValidationError as exc:
        msgs = [f"{'.'.join(str(x) for x in e['loc'])}: {e['msg']}" for e in exc.errors()]
        raise ValueError(f"{p}: invalid collection config: " + "; ".join(msgs)) from None


def parse_seeds(text: str) -> list[int]:
    """'1,2,3' or '1 2 3' -> [1, 2, 3]; errors name the argument."""
    items = [t for t in str(text).replace(",", " ").split() if t]
    try:
        seeds = [int(t) for t in items]
    except ValueError:
        raise ValueError(f"seeds '{text}': not a list of integers (e.g. seeds:=1,2,3)") from None
    if any(x < 0 for x in seeds):
        raise ValueError(f"seeds '{text}': seeds must be >= 0")
    return seeds


def parse_seed_ranges(text: str, distinct: bool = False) -> list[int]:
    """'100-103,110' or '100-103 110' -> [100, 101, 102, 103, 110] (ranges and plain lists, comma or space
    separated); errors (ValueError) name the part. distinct: a seed listed twice is an error."""
    seeds: list[int] = []
    for part in str(text).replace(",", " ").split():
        if "-" in part:
            a, b = part.split("-", 1)
            try:
                lo, hi = int(a), int(b)
            except ValueError:
                raise ValueError(f"seeds '{text}': '{part}' is not a range like 100-199") from None
            if hi < lo:
                raise ValueError(f"seeds '{text}': bad seed range '{part}' is empty (end before start)")
            seeds.extend(range(lo, hi + 1))
        else:
            seeds.extend(parse_seeds(part))
    if not seeds:
        raise ValueError(f"seeds '{text}': no seed given")
    if distinct and len(set(seeds)) != len(seeds):
        raise ValueError(f"seeds '{text}': a seed is listed twice (workers must fly distinct worlds)")
    return seeds


def manager_config(path: str | os.PathLike, params: dict) -> CollectConfig:
    """The episode manager's config: the YAML at `path` with its node parameters (launch arguments) applied.

    params: output_dir (str), seeds (str: a list with ranges, "1,2,10-19"; "" = config's), episodes (int,
    0 = config's), max_samples (int, < 0 = config's), episode_timeout_s (float, 0 = config's). Raises
    ValueError naming the bad argument.
    """
    known = {"output_dir", "seeds", "episodes", "max_samples", "episode_timeout_s"}
    unknown = set(params) - known
    if unknown:
        raise ValueError(f"unknown episode manager parameter(s): {', '.join(sorted(unknown))}")

    def number(key: str, kind: type, default):
        v = params.get(key, default)
        if isinstance(v, bool) or not isinstance(v, int | float | str):
            raise ValueError(f"{key} '{v}': not a number")
        try:
            x = kind(v)
        except (TypeError, ValueError):
            raise ValueError(f"{key} '{v}': not a number") from None
        if kind is int and isinstance(v, float) and v != x:
            raise ValueError(f"{key} '{v}': not an integer")
        return x

    overrides: dict = {}
    out = str(params.get("output_dir", "") or "").strip()
    if out:
        overrides["output_dir"] = out
    seeds = str(params.get("seeds", "") or "").strip()
    if seeds:
        overrides["seeds"] = parse_seed_ranges(seeds)
    episodes = number("episodes", int, 0)
    if episodes < 0:
        raise ValueError(f"episodes {episodes}: must be >= 1 (0: the config's)")
    if episodes:
        overrides["episodes"] = episodes
    max_samples = number("max_samples", int, -1)
    if max_samples >= 0:
        overrides["max_samples"] = max_samples
    timeout = number("episode_timeout_s", float, 0.0)
    if timeout < 0:
        raise ValueError(f"episode_timeout_s {timeout}: must be > 0 (0: the config's)")
    if timeout > 0:
        overrides["episode_timeout_s"] = timeout
    return load_collect_config(path, overrides)


@dataclass(frozen=True)
class EpisodeSpec:
    index: int
    seed: int
    start_world: tuple[float, float, float]
    start_yaw_rad: float
    goal_world: tuple[float, float, float]


def episode_seed(cfg: CollectConfig, index: int) -> int:
    return cfg.seeds[index % len(cfg.seeds)] if cfg.seeds else cfg.first_seed + index


def sample_start_goal(cfg: StartGoalConfig, rng: np.random.Generator) -> tuple[np.ndarray, float, np.ndarray]:
    """A start and goal inside the area less the margin, [min, max] apart; the start faces the goal."""
    lo = np.asarray(cfg.bounds_min_xy_m) + cfg.margin_m
    hi = np.asarray(cfg.bounds_max_xy_m) - cfg.margin_m
    for _ in range(cfg.max_tries):
        s = rng.uniform(lo, hi)
        heading = rng.uniform(-math.pi, math.pi)
        dist = rng.uniform(cfg.min_distance_m, cfg.max_distance_m)
        g = s + dist * np.array([math.cos(heading), math.sin(heading)])
        if np.all(g >= lo) and np.all(g <= hi):
            zs, zg = rng.uniform(cfg.altitude_min_m, cfg.altitude_max_m, size=2)
            return np.array([s[0], s[1], zs]), heading, np.array([g[0], g[1], zg])
    raise RuntimeError(
        f"could not place a start/goal pair {cfg.min_distance_m}-{cfg.max_distance_m} m apart "
        f"in {cfg.max_tries} tries"
    )


def plan_episode(cfg: CollectConfig, index: int) -> EpisodeSpec:
    """The episode `index` of a run: its world seed and a start/goal drawn from an RNG seeded by that seed."""
    seed = episode_seed(cfg, index)
    # The start/goal stream depends only on (seed, index), never on earlier episodes' outcomes.
    rng = np.random.default_rng([seed, index])
    start, yaw, goal = sample_start_goal(cfg.start_goal, rng)
    return EpisodeSpec(index, seed, tuple(map(float, start)), float(yaw), tuple(map(float, goal)))


EVAL_STREAM = 8  # salt of the evaluation's start/goal RNG (collection uses [seed, index])


def plan_eval_episodes(seeds: list[int], episodes: int, start_goal: StartGoalConfig) -> list[EpisodeSpec]:
    if not seeds:
        raise ValueError("at least one world seed is needed")
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    return [eval_episode(int(seeds[i % len(seeds)]), i, start_goal) for i in range(episodes)]


def eval_episode(seed: int, index: int, start_goal: StartGoalConfig) -> EpisodeSpec:
    """The evaluation's episode `index` in the world of `seed`: its start and goal drawn from an RNG seeded
    with (seed, index, EVAL_STREAM)."""
    rng = np.random.default_rng([seed, index, EVAL_STREAM])
    start, yaw, goal = sample_start_goal(start_goal, rng)
    return EpisodeSpec(index, seed, tuple(map(float, start)), float(yaw), tuple(map(float, goal)))


@dataclass(frozen=True)
class EpisodeOutcome:
    index: int
    seed: int
    # "goal_reached" | "collision" | "timeout" | "goal_rejected" | "reset_failed" | "interrupted"
    outcome: str
    reason: str
    sim_duration_s: float
    samples: int


class StopCondition:
    """When a run is done: after `episodes` episodes, or once `max_samples` samples were recorded."""

    def __init__(self, cfg: CollectConfig) -> None:
        self._cfg = cfg

    def done(self, episodes_finished: int, samples: int) -> tuple[bool, str]:
        if episodes_finished >= self._cfg.episodes:
            return True, f"{episodes_finished} episodes finished"
        if self._cfg.max_samples and samples >= self._cfg.max_samples:
            return True, f"{samples} samples recorded (max_samples={self._cfg.max_samples})"
        return False, ""


class EpisodeLog:
    """episodes.csv in the dataset directory: one row per finished episode, flushed and fsynced per row so a
    crash never loses a finished episode's row."""

    FIELDS = [f for f in EpisodeOutcome.__dataclass_fields__]

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        new = not self.path.exists() or self.path.stat().st_size == 0
        self._f = open(self.path, "a", newline="")  # noqa: SIM115 - kept open for the run
        self._w = csv.DictWriter(self._f, fieldnames=self.FIELDS)
        if new:
            self._w.writeheader()
            self._sync()

    def append(self, outcome: EpisodeOutcome) -> None:
        self._w.writerow(asdict(outcome))
        self._sync()

    def _sync(self) -> None:
        self._f.flush()
        os.fsync(self._f.fileno())

    def close(self) -> None:
        self._f.close()

    @staticmethod
    def read(path: str | os.PathLike) -> list[EpisodeOutcome]:
        """Every row. A last row cut short by a crash (no line end: rows are fsynced whole, so only a kill
        inside write(2) leaves one) is ignored; any other bad row is an error naming the file and line."""
        text = Path(path).read_text()
        if text and not text.endswith("\n"):
            text = text[: text.rfind("\n") + 1]  # the torn last row
        out = []
        reader = csv.DictReader(io.StringIO(text, newline=""))
        for r in reader:
            try:
                out.append(
                    EpisodeOutcome(
                        int(r["index"]),
                        int(r["seed"]),
                        r["outcome"],
                        r["reason"],
                        float(r["sim_duration_s"]),
                        int(r["samples"]),
                    )
                )
            except (TypeError, ValueError, KeyError):
                raise ValueError(f"{path}: line {reader.line_num} is not an episode row: {r}") from None
        return out

    @staticmethod
    def rewrite(path: str | os.PathLike, outcomes: list[EpisodeOutcome]) -> None:
        """Replaces the file atomically with these rows (resuming drops the rows of episodes whose records are
        not all on disk)."""
        p = Path(path)
        tmp = p.with_name(p.name + ".tmp")
        with open(tmp, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=EpisodeLog.FIELDS)
            w.writeheader()
            for o in outcomes:
                w.writerow(asdict(o))
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, p)
