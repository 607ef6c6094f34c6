"""The interactive collector's logic without ROS: what `ros_collector` (the rospy node) feeds with converted
messages and asks what to do (tests/python/test_imitation_collector_core.py).

- `CollectorCore`: pairer -> learner -> the round's dataset (quad_il.imitation.dataset: shards + manifest,
  the episodes appended as they end);
- `EpisodeBook`: which episode is open and whether its goal is known (from the status and goal topics);
- `AckBook`: which frames each plan source has acknowledged (a source that acknowledged a frame without a plan
  has no plan for it);
- `OdometryBuffer`: the frame's odometry by the pairing rule (quad_il.frame_pairing), waiting for it;
- `HeldFrames`: when each held observation arrived (the pair timeout);
- `CollectorCounters` and `collector_manifest`: what the node reports in collector_manifest.json;
- `perturb_spline`, `expert_noise_from_param`: MEGA-DAgger's imperfect experts;
- `TimingLog`: the CSV of each paired frame's odometry (the stamp-mismatch study).

Pairing in lockstep: every plan carries the stamp of the depth frame it was planned from as `start_time`. A
source that has no plan for a frame says so by acknowledging the frame without publishing a plan (the
labeller also publishes an empty B-spline); the node completes the frame with None for that source once its
acknowledgement is in (AckBook) and `ack_grace_s` has passed without a plan (plans and acknowledgements
travel on different connections). `pair_timeout_s` completes a frame whose source went silent (HeldFrames).
Frames outside an episode or before the episode's goal are acknowledged at once, unpaired.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import os
import tempfile
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any, Generic, TypeVar

import numpy as np
import yaml

from quad_il.frame_pairing import newest_at_or_before, period_arrived
from quad_il.imitation.bspline import SplineAction
from quad_il.imitation.config import MegaDAggerConfig, RoundAlgorithmConfig
from quad_il.imitation.dataset import EpisodeWriter
from quad_il.imitation.learners import ImitationLearnerBase
from quad_il.imitation.pairing import PairedFrame, StampPairer, stamp_key
from quad_il.imitation.safety import WorldClearance
from quad_il.imitation.types import EpisodeOutcome, ImitationError, Pair, Record

T = TypeVar("T")


def load_round_config(path: str | Path) -> RoundAlgorithmConfig:
    with open(path) as fh:
        return RoundAlgorithmConfig.model_validate(yaml.safe_load(fh))


def perturb_spline(action: SplineAction, std_m: float, rng: np.random.Generator) -> SplineAction:
    """An imperfect expert for MEGA-DAgger (`~expert_noise_std_m`): independent Gaussian noise of `std_m`
    metres on every control point except the first `order` ones, which fix the plan's start state (position,
    velocity, acceleration at the frame), so the noisy plan still starts where the vehicle is."""
    if not np.isfinite(std_m) or std_m < 0.0:
        raise ImitationError(f"expert noise std must be a finite number >= 0 m, got {std_m}")
    ctrl = action.ctrl_pts_world.copy()
    keep = min(int(action.order), len(ctrl))
    ctrl[keep:] += rng.normal(0.0, std_m, size=ctrl[keep:].shape)
    return SplineAction(ctrl, action.knots, action.order, action.start_time_s, action.traj_id)


def expert_noise_from_param(value: Any, expert_topics: dict[str, str]) -> dict[str, float]:
    """`~expert_noise_std_m` checked: a mapping from expert names of `~expert_topics` to standard deviations
    (metres, finite, >= 0)."""
    if not isinstance(value, dict):
        raise ImitationError(f"~expert_noise_std_m must be a mapping {{expert: metres}}, got {value!r}")
    out = {}
    for name, std in value.items():
        if name not in expert_topics:
            raise ImitationError(
                f"~expert_noise_std_m names {name!r}, which is not in ~expert_topics {sorted(expert_topics)}"
            )
        try:
            out[str(name)] = float(std)
        except (TypeError, ValueError):
            raise ImitationError(
                f"~expert_noise_std_m[{name!r}] must be a number of metres, got {std!r}"
            ) from None
        if not math.isfinite(out[str(name)]) or out[str(name)] < 0.0:
            raise ImitationError(f"~expert_noise_std_m[{name!r}] must be finite and >= 0 m, got {std!r}")
    return out


def write_json_atomic(path: Path, payload: dict[str, Any]) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    with os.fdopen(fd, "w") as fh:
        json.dump(payload, fh, indent=2, sort_keys=True)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def mega_clearance(cfg: RoundAlgorithmConfig, expert_topics: dict[str, str]) -> WorldClearance | None:
    """MEGA-DAgger's clearance map (None for the other algorithms), after checking that every expert of the
    algorithm has a plan topic. The simulator publishes (latched) the voxel map of each world at its reset,
    before the episode's goal; the node swaps it in (not waited for: in lockstep the simulator starts only
    once the node subscribes to depth)."""
    if not isinstance(cfg.algorithm, MegaDAggerConfig):
        return None
    missing = [e for e in cfg.algorithm.experts if e not in expert_topics]
    if missing:
        raise ImitationError(f"expert_topics lacks the MEGA-DAgger experts {missing}")
    return WorldClearance()


class CollectorCore:
    """Glue between pairer, learner and writer (the node feeds it converted messages)."""

    def __init__(
        self,
        learner: ImitationLearnerBase,
        sources: list[str],
        primary: str,
        output_dir: Path,
        run_info: dict[str, str],
        **writer_config: object,
    ) -> None:
        """run_info: the dataset manifest's (round_index at least); writer_config: keys of
        config/collector.yaml to replace (software_commit, fsync, ...)."""
        self.learner = learner
        self.primary = primary
        self.experts = [s for s in sources if s != "learner"]
        self.pairer = StampPairer(sources)
        self.output_dir = output_dir
        self.writer = EpisodeWriter(output_dir, run_info, **writer_config)
        self.episode_records: list[Record] = []
        self.episodes_written = 0  # episodes closed (with or without records)
        self.episodes_flown = 0  # closed episodes that had a goal
        self.files_written = 0  # closed episodes with records (appended to the dataset)
        self.write_error = ""  # the dataset writer's first failure (disk full: names the file)

    def frames(self, frames: list[PairedFrame]) -> list[tuple[PairedFrame, Any]]:
        out = []
        for f in frames:
            pair = Pair(
                obs=f.obs,
                learner=f.actions.get("learner"),
                experts={e: f.actions.get(e) for e in self.experts},
                primary_expert=self.primary,
            )
            decision = self.learner.step(pair)
            self.episode_records.extend(decision.records)
            out.append((f, decision))
        return out

    def finish_episode(
        self,
        episode_id: int,
        outcome: EpisodeOutcome,
        flown: bool = True,
        world_seed: int = 0,
        **writer_config: object,
    ) -> None:
        """Ends the learner's episode and appends its records (world_seed: the simulator's world of the
        episode; writer_config: camera intrinsics known by now, used when the dataset is created)."""
        self.episode_records.extend(self.learner.end_episode(outcome))
        records, self.episode_records = self.episode_records, []
        self.episodes_written += 1
        self.episodes_flown += int(flown)
        if records and not self.write_error:
            try:
                self.writer.write(world_seed, records, **writer_config)
                self.files_written += 1
            except ImitationError as e:  # the episodes written before stay readable
                self.write_error = str(e)

    @property
    def records_written(self) -> int:
        return self.writer.written

    def finalize(self) -> bool:
        """Completes the dataset (manifest status complete); False after a writer error."""
        return self.writer.finalize()


class EpisodeBook:
    """Which episode is open and whether its goal is known, from the simulator's status and the goal topic.

    `status()` returns the transitions to apply, in order: ("end", old_id, flown) and/or ("start", new_id,
    False). A goal counts for the open episode only if it is stamped at or after the episode's first status
    (the goal topic is latched: the previous episode's goal is delivered again to late subscribers). An
    episode is "flown" once it received its goal."""

    def __init__(self) -> None:
        self.episode_id: int | None = None
        self.start_s = 0.0
        self.goal: np.ndarray | None = None
        self.had_goal = False
        self.ended: set[int] = set()
        self.world_seeds: dict[int, int] = {}  # episode -> the world seed of its first status

    def status(
        self, episode_id: int, active: bool, stamp_s: float, world_seed: int = 0
    ) -> list[tuple[str, int, bool]]:
        """Transitions ("end", id, flown) and/or ("start", id, False), in this order."""
        out: list[tuple[str, int, bool]] = []
        if self.episode_id is not None and (episode_id != self.episode_id or not active):
            out.append(("end", self.episode_id, self.had_goal))
            self.ended.add(self.episode_id)
            self.episode_id, self.goal = None, None
        if self.episode_id is None and active and episode_id not in self.ended:
            self.episode_id, self.start_s, self.goal, self.had_goal = (
                int(episode_id),
                float(stamp_s),
                None,
                False,
            )
            self.world_seeds[self.episode_id] = int(world_seed)
            out.append(("start", self.episode_id, False))
        return out

    def set_goal(self, stamp_s: float, goal: np.ndarray) -> bool:
        if self.episode_id is None or stamp_s < self.start_s - 1e-9:
            return False
        self.goal = np.asarray(goal, dtype=np.float64)
        self.had_goal = True
        return True

    @property
    def flying(self) -> bool:
        return self.episode_id is not None and self.goal is not None


class AckBook:
    """The frames each source has acknowledged (FrameAck), by stamp; the newest `keep` per source."""

    def __init__(self, sources: list[str], keep: int = 256) -> None:
        self._acked: dict[str, dict[int, float]] = {s: {} for s in sources}
        self._keep = keep

    def add(self, source: str, stamp_s: float) -> None:
        d = self._acked[source]
        d[stamp_key(stamp_s)] = stamp_s
        if len(d) > self._keep:
            for k in sorted(d)[: self._keep // 2]:
                del d[k]

    def acked(self, source: str, stamp_s: float) -> bool:
        return stamp_key(stamp_s) in self._acked[source]

    def any_acked(self, stamp_s: float) -> bool:
        return any(self.acked(s, stamp_s) for s in self._acked)


@dataclasses.dataclass
class CollectorCounters:
    odom_waits: int = 0
    odom_wait_timeouts: int = 0
    tracker_rejections: int = 0
    unpaired_plans: int = 0
    pair_timeouts: int = 0
    acked_without_plan: int = 0
    tracker_accept_timeouts: int = 0
    voxel_maps: int = 0
    label_checks_without_map: int = 0


class OdometryBuffer(Generic[T]):
    """The newest `keep` odometry messages by stamp, and the one a frame pairs with (quad_il.frame_pairing).

    Odometry and depth arrive on different connections and threads: the frame's odometry (stamped within one
    period before it, published before it) may still be on its way. `for_frame` waits for it up to `wait_s`
    (0: take what has arrived, as a naive collector would; measured in lockstep: up to 37 ms old)."""

    def __init__(self, period_s: float, wait_s: float, counters: CollectorCounters, keep: int = 400) -> None:
        self.period_s = period_s
        self.wait_s = wait_s
        self.counters = counters
        self._keep = keep
        self._cv = threading.Condition()
        self._stamps: list[float] = []
        self._items: list[T] = []

    def add(self, stamp_s: float, item: T) -> None:
        with self._cv:
            if self._stamps and stamp_s < self._stamps[-1]:  # time went back (a new run): start afresh
                self._stamps.clear()
                self._items.clear()
            self._stamps.append(stamp_s)
            self._items.append(item)
            del self._stamps[: -self._keep], self._items[: -self._keep]
            self._cv.notify_all()

    def for_frame(self, frame_stamp_s: float) -> tuple[T, T] | None:
        """(newest stamped at or before the frame, newest received), or None when all are newer or none
        arrived."""
        with self._cv:

            def arrived() -> bool:
                return bool(self._stamps) and period_arrived(self._stamps[-1], frame_stamp_s, self.period_s)

            if self.wait_s > 0.0 and not arrived():
                self.counters.odom_waits += 1
                if not self._cv.wait_for(arrived, timeout=self.wait_s):
                    self.counters.odom_wait_timeouts += 1
            i = newest_at_or_before(self._stamps, frame_stamp_s)
            return (self._items[i], self._items[-1]) if i >= 0 else None


class HeldFrames:
    """When each held observation arrived (a monotonic clock), so that a frame whose source went silent is
    completed after the pair timeout."""

    def __init__(self, timeout_s: float, clock: Callable[[], float]) -> None:
        self.timeout_s = timeout_s
        self._clock = clock
        self._arrivals: dict[int, float] = {}

    def hold(self, stamp_s: float) -> None:
        self._arrivals[stamp_key(stamp_s)] = self._clock()

    def release(self, stamp_s: float) -> None:
        self._arrivals.pop(stamp_key(stamp_s), None)

    def expired(self) -> list[float]:
        """Stamps (s) held longer than the timeout, oldest first; they are released."""
        now = self._clock()
        keys = sorted(k for k, t0 in self._arrivals.items() if now - t0 > self.timeout_s)
        for k in keys:
            del self._arrivals[k]
        return [k * 1e-9 for k in keys]


class TimingLog:
    """CSV: per paired frame, its stamp, the stamp of the odometry used, the newest odometry received and how
    far the clock was past the frame when it was paired."""

    def __init__(self, path: str | Path) -> None:
        self._fh = open(path, "w", newline="")  # noqa: SIM115 - closed by close()
        self._csv = csv.writer(self._fh)
        self._csv.writerow(["depth_stamp_s", "odom_used_stamp_s", "odom_latest_stamp_s", "clock_delay_s"])

    def row(self, frame_s: float, used_s: float, latest_s: float, delay_s: float) -> None:
        self._csv.writerow([f"{frame_s:.9f}", f"{used_s:.9f}", f"{latest_s:.9f}", f"{delay_s:.6f}"])

    def close(self) -> None:
        self._fh.close()


def collector_manifest(
    cfg: RoundAlgorithmConfig,
    core: CollectorCore,
    interrupted: bool,
    counters: CollectorCounters,
) -> dict[str, Any]:
    """The content of collector_manifest.json (written when the node stops)."""
    learner = core.learner
    return {
        "round_config": cfg.model_dump(mode="json"),
        "episodes": core.episodes_flown,
        "episodes_closed": core.episodes_written,
        "files": core.files_written,
        "records": core.records_written,
        "dataset_rejected": core.writer.rejected[:20],  # records the dataset writer refused, and why
        "dataset_error": core.write_error,
        "interrupted": interrupted,
        "stats": vars(learner.stats),
        "algorithm_stats": learner.algorithm_stats(),
        "pairer": vars(core.pairer.stats),
        "collector": dataclasses.asdict(counters),
    }
