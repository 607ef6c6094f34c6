"""Run-directory layout and the run's state file (written atomically), from which an interrupted run resumes.

Layout (docs/imitation_learning.md, "Run directory"):

    run_dir/
      config.yaml            the manager's YAML as given (a changed config refuses to resume by default)
      state.json             this module's RunState, replaced atomically after every stage transition
      manager.log            the manager's own log
      manager.lock           flock: one manager per run directory
      round_000/
        algorithm.yaml       what the collector runs this round (algorithm, round, seed, beta, expert_only)
        round.json           the manager's summary of the round (stage durations, exit codes, attempts)
        data/                collector output (episode files, collector_manifest.json)
        checkpoint/          training output (checkpoints, the exported policy the next round flies)
        metrics/             evaluation output
        logs/                one log per child (roscore.log, simulator.log, ..., training.log), appended per
                             attempt; ROS's own logs under logs/ros/
        attempts/<stage>_NNN/  outputs of an interrupted or failed attempt of <stage>, moved aside (never
        deleted)
      round_001/ ...
      round_001.discarded-YYYYmmdd-HHMMSS/   a round thrown away by `--redo-from 1` (moved, never deleted)
"""

from __future__ import annotations

import dataclasses
import enum
import json
import os
import tempfile
import time
from pathlib import Path
from typing import Any

STATE_FORMAT_VERSION = 1

STAGES = ("collect", "train", "eval")
STAGE_OUTPUT_DIRS = {"collect": "data", "train": "checkpoint", "eval": "metrics"}


class StateError(RuntimeError):
    """The state file is unreadable or belongs to another format; the message names the file."""


class Status(str, enum.Enum):
    PENDING = "pending"
    RUNNING = "running"
    COMPLETE = "complete"
    INTERRUPTED = "interrupted"
    FAILED = "failed"


@dataclasses.dataclass(frozen=True)
class RoundPaths:
    index: int
    root: Path

    @property
    def name(self) -> str:
        return f"round_{self.index:03d}"

    @property
    def data(self) -> Path:
        return self.root / "data"

    @property
    def checkpoint(self) -> Path:
        return self.root / "checkpoint"

    @property
    def metrics(self) -> Path:
        return self.root / "metrics"

    @property
    def logs(self) -> Path:
        return self.root / "logs"

    @property
    def attempts(self) -> Path:
        return self.root / "attempts"

    @property
    def algorithm_config(self) -> Path:
        return self.root / "algorithm.yaml"

    @property
    def summary(self) -> Path:
        return self.root / "round.json"

    def create(self) -> None:
        for d in (self.data, self.checkpoint, self.metrics, self.logs):
            d.mkdir(parents=True, exist_ok=True)

    def archive_stage_output(self, stage: str, attempt: int) -> Path | None:
        """Move the output dir of a failed/interrupted attempt to attempts/<stage>_NNN/ (never delete
        data)."""
        src = self.root / STAGE_OUTPUT_DIRS[stage]
        if not src.exists() or not any(src.iterdir()):
            return None
        dst = self.attempts / f"{stage}_{attempt:03d}" / STAGE_OUTPUT_DIRS[stage]
        dst.parent.mkdir(parents=True, exist_ok=True)
        os.replace(src, dst)
        src.mkdir()
        return dst


@dataclasses.dataclass(frozen=True)
class RunLayout:
    run_dir: Path

    @property
    def config(self) -> Path:
        return self.run_dir / "config.yaml"

    @property
    def state(self) -> Path:
        return self.run_dir / "state.json"

    @property
    def log(self) -> Path:
        return self.run_dir / "manager.log"

    @property
    def lock(self) -> Path:
        return self.run_dir / "manager.lock"

    def round(self, index: int) -> RoundPaths:
        return RoundPaths(index, self.run_dir / f"round_{index:03d}")


def write_json_atomic(path: Path, payload: Any) -> None:
    """Write to a temporary file in the same directory, fsync, rename over `path`, fsync the directory."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as fh:
            json.dump(payload, fh, indent=2, sort_keys=True)
            fh.write("\n")
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    dfd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(dfd)
    finally:
        os.close(dfd)


@dataclasses.dataclass
class StageState:
    status: Status = Status.PENDING
    attempts: int = 0
    exit_code: int | None = None
    reason: str = ""
    started: float | None = None
    finished: float | None = None

    def to_json(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["status"] = self.status.value
        return d

    @staticmethod
    def from_json(d: dict[str, Any]) -> StageState:
        return StageState(
            status=Status(d["status"]),
            attempts=int(d["attempts"]),
            exit_code=d.get("exit_code"),
            reason=d.get("reason", ""),
            started=d.get("started"),
            finished=d.get("finished"),
        )


@dataclasses.dataclass
class RunState:
    """What has been done. Rounds are complete or not; stages within a round are tracked individually."""

    config_sha256: str
    rounds: dict[int, dict[str, StageState]] = dataclasses.field(default_factory=dict)
    completed_rounds: list[int] = dataclasses.field(default_factory=list)
    finished: bool = False
    last_event: dict[str, Any] = dataclasses.field(default_factory=dict)
    created: float = dataclasses.field(default_factory=time.time)

    # -- queries ---------------------------------------------------------------------------------------------
    def round_complete(self, index: int) -> bool:
        return index in self.completed_rounds

    def stage(self, index: int, stage: str) -> StageState:
        return self.rounds.setdefault(index, {}).setdefault(stage, StageState())

    def first_incomplete_round(self, count: int) -> int | None:
        for i in range(count):
            if not self.round_complete(i):
                return i
        return None

    # -- transitions -----------------------------------------------------------------------------------------
    def begin_stage(self, index: int, stage: str) -> StageState:
        s = self.stage(index, stage)
        s.status, s.attempts, s.exit_code, s.reason = Status.RUNNING, s.attempts + 1, None, ""
        s.started, s.finished = time.time(), None
        return s

    def end_stage(self, index: int, stage: str, status: Status, exit_code: int | None, reason: str) -> None:
        s = self.stage(index, stage)
        s.status, s.exit_code, s.reason, s.finished = status, exit_code, reason, time.time()
        self.last_event = {
            "round": index,
            "stage": stage,
            "status": status.value,
            "reason": reason,
            "time": s.finished,
        }

    def discard_rounds_from(self, first: int) -> list[int]:
        """Forget rounds `first`, `first`+1, ... (complete or not); returns the indices that had any state."""
        dropped = sorted(i for i in set(self.rounds) | set(self.completed_rounds) if i >= first)
        for i in dropped:
            self.rounds.pop(i, None)
        self.completed_rounds = [i for i in self.completed_rounds if i < first]
        if dropped:
            self.last_event = {
                "round": first,
                "stage": "",
                "status": "discarded",
                "reason": f"rounds {dropped} discarded to be redone",
                "time": time.time(),
            }
        return dropped

    def complete_round(self, index: int) -> None:
        if index not in self.completed_rounds:
            self.completed_rounds.append(index)
            self.completed_rounds.sort()

    # -- persistence -----------------------------------------------------------------------------------------
    def to_json(self) -> dict[str, Any]:
        return {
            "format_version": STATE_FORMAT_VERSION,
            "config_sha256": self.config_sha256,
            "created": self.created,
            "finished": self.finished,
            "completed_rounds": list(self.completed_rounds),
            "last_completed_round": max(self.completed_rounds) if self.completed_rounds else None,
            "last_event": self.last_event,
            "rounds": {
                f"{i:03d}": {
                    "complete": self.round_complete(i),
                    "stages": {k: v.to_json() for k, v in stages.items()},
                }
                for i, stages in sorted(self.rounds.items())
            },
        }

    def save(self, path: Path) -> None:
        write_json_atomic(path, self.to_json())

    @staticmethod
    def load(path: Path) -> RunState:
        try:
            d = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise StateError(f"{path}: unreadable state file: {e}") from None
        if d.get("format_version") != STATE_FORMAT_VERSION:
            raise StateError(
                f"{path}: state format_version {d.get('format_version')}, expected {STATE_FORMAT_VERSION}"
            )
        try:
            rounds = {
                int(k): {s: StageState.from_json(v) for s, v in r["stages"].items()}
                for k, r in d["rounds"].items()
            }
            return RunState(
                config_sha256=d["config_sha256"],
                rounds=rounds,
                completed_rounds=[int(i) for i in d["completed_rounds"]],
                finished=bool(d["finished"]),
                last_event=dict(d.get("last_event", {})),
                created=float(d["created"]),
            )
        except (KeyError, TypeError, ValueError) as e:
            raise StateError(f"{path}: malformed state file: {e!r}") from None
