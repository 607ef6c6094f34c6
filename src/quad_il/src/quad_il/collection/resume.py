"""Resuming an interrupted collection run: `roslaunch quad_il collect.launch ... resume:=true`
(docs/collect.md, "Resuming"; issue 30, fault table "ROS master killed during collect.launch").

A collection run can end before its last episode: the ROS master killed (roslaunch then shuts every node
down and the planner finalises the dataset), the planner killed (the dataset is left incomplete), Ctrl-C.
Re-running the same command with `resume:=true` into the same output directory completes the missing
episodes without touching the finished ones:

- the run's identity (`collect_run.yaml`, written when the run started: the launch arguments that decide
  which episodes are flown and how, and the sha256 of every config file) must be the same, or the launch
  stops naming the argument that differs;
- a finished episode is a row of `episodes.csv` (fsynced per row) whose records are all in the dataset:
  its records are found by the episode's goal (`plan_episode(cfg, index).goal_world`, a pure function of
  the seed and the index, stored in every record), and it must have at least the row's `samples` records.
  A row whose records are not all on disk (the planner killed with records still queued) and every row
  after it are dropped;
- a dataset left incomplete by a killed writer is recovered (`read_dataset recover`: every record whose
  write completed is kept), then the records that belong to no finished episode (the interrupted one, at
  the end of the dataset) are cut (`read_dataset truncate`). Records of finished episodes are never
  rewritten;
- the planner's collector then appends to the dataset (`cpp_data_collector::OpenMode::kAppend`: shard
  indices, seqs and counts continue, episode ids are kept) and the episode manager starts at the first
  episode index that is not finished. Episodes are keyed (issue 32, `quad_core/episode_key.h`): episode i
  starts at sim time 1 s + (i + 1) * 1000 s with episode id i + 1 in every launch, so the resumed episodes
  get the stamps, ids and therefore records a straight run gives them. A dataset whose finished episodes do
  not carry their keyed ids (collected before episodes were keyed) cannot be continued that way and is
  refused.

Resuming into a directory that holds no dataset yet starts the run, so the same command can be used for the
first run and every resumption. Everything here runs while roslaunch parses the launch file, before any node
starts, and is idempotent (collect.launch evaluates it once per parameter that needs the output directory).
"""

from __future__ import annotations

import hashlib
import subprocess
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from quad_il.collection.episodes import (
    EpisodeLog,
    EpisodeOutcome,
    manager_config,
    parse_seed_ranges,
    plan_episode,
)

RUN_FILE = "collect_run.yaml"
EPISODES_FILE = "episodes.csv"
MANIFEST_FILE = "manifest.yaml"
# Launch arguments naming config files: compared by the sha256 of their content, not by path.
CONFIG_KEYS = (
    "collect_config",
    "collector_config",
    "sim_config",
    "planner_config",
    "tracker_config",
    "vehicle_config",
)
# Files a run may add to its identity, compared by content when either run has them: the learner of a DAgger
# round (quad_il.engine.dagger) and its policy config decide its episodes as much as the configs above do.
OPTIONAL_FILE_KEYS = ("policy", "policy_config")
# Launch arguments that decide which episodes are flown and how they are recorded.
VALUE_KEYS = ("seeds", "episodes", "max_samples", "episode_timeout_s", "time_mode", "time_factor")


class ResumeError(ValueError):
    """The run cannot be resumed; the message names the file, key or value and what to do."""


def _sha256(path: Path) -> str:
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError as exc:
        raise ResumeError(f"{path}: cannot read ({exc.strerror})") from None


def run_identity(args: Mapping[str, str]) -> dict[str, str]:
    """The identity of a run from its launch arguments: values as given (seeds normalised to a list), config
    files by content (`sha256:...`; OPTIONAL_FILE_KEYS only when given). Missing or unknown keys are errors
    naming them."""
    missing = [k for k in (*VALUE_KEYS, *CONFIG_KEYS) if k not in args]
    unknown = sorted(set(args) - set(VALUE_KEYS) - set(CONFIG_KEYS) - set(OPTIONAL_FILE_KEYS))
    if missing or unknown:
        raise ResumeError(f"run identity: missing keys {missing}, unknown keys {unknown}")
    out: dict[str, str] = {}
    for k in VALUE_KEYS:
        v = str(args[k]).strip()
        out[k] = ",".join(map(str, parse_seed_ranges(v))) if k == "seeds" else v
    for k in (*CONFIG_KEYS, *OPTIONAL_FILE_KEYS):
        if k in args:
            out[k] = "sha256:" + _sha256(Path(args[k]))
    return out


@dataclass
class ResumePlan:
    finished: list[EpisodeOutcome] = field(default_factory=list)
    records_kept: int = 0
    records_cut: int = 0
    actions: list[str] = field(default_factory=list)


def _read_run_file(d: Path) -> dict[str, str]:
    try:
        data = yaml.safe_load((d / RUN_FILE).read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise ResumeError(f"{d / RUN_FILE}: unreadable ({exc})") from None
    if not isinstance(data, dict) or not isinstance(data.get("identity"), dict):
        raise ResumeError(f"{d / RUN_FILE}: no 'identity' mapping")
    return {str(k): str(v) for k, v in data["identity"].items()}


def write_run_file(d: Path, identity: Mapping[str, str]) -> None:
    text = (
        "# The arguments of the run writing this directory (collect.launch, quad_il.engine.collect or\n"
        "# quad_il.engine.dagger; quad_il.collection.resume): resuming it (resume:=true, --resume)\n"
        "# continues the run only with the same ones.\n"
        + yaml.safe_dump({"identity": dict(identity)}, sort_keys=False)
    )
    tmp = d / (RUN_FILE + ".tmp")
    tmp.write_text(text)
    tmp.replace(d / RUN_FILE)


def check_identity(d: Path, identity: Mapping[str, str]) -> None:
    recorded = _read_run_file(d)
    for k in (*VALUE_KEYS, *CONFIG_KEYS, *OPTIONAL_FILE_KEYS):
        if recorded.get(k) != identity.get(k):
            what = "the content of " + k if k not in VALUE_KEYS else k
            raise ResumeError(
                f"resume: {d} was collected with {k} {recorded.get(k)!r}, this launch has "
                f"{identity.get(k)!r} ({what} differs); resume with the run's own arguments, or pass "
                "another output_dir:=DIR"
            )


def _tool(name: str) -> str:
    from quad_il.data.synthetic import find_collector_tool

    return str(find_collector_tool(name))


def _run_tool(args: list[str]) -> list[str]:
    proc = subprocess.run([_tool("read_dataset"), *args], capture_output=True, text=True, timeout=600)
    if proc.returncode != 0:
        raise ResumeError(
            f"read_dataset {' '.join(args)} failed: {proc.stderr.strip() or proc.stdout.strip()}"
        )
    return [ln for ln in proc.stdout.splitlines() if ln.strip()]


def plan_resume(d: Path, identity: Mapping[str, str], collect_params: Mapping[str, object]) -> ResumePlan:
    """Makes `d` ready for the resumed run (see the module docstring) and returns what it found and did.

    collect_params: the episode manager's parameters (config path and launch overrides, as
    `episodes.manager_config` takes them), to recompute each finished episode's goal."""
    plan = ResumePlan()
    if (d / RUN_FILE).exists():
        check_identity(d, identity)
    elif (d / MANIFEST_FILE).exists() or (d / EPISODES_FILE).exists():
        raise ResumeError(
            f"resume: {d} holds a collection without {RUN_FILE} (started before runs recorded their "
            "arguments): it cannot be checked that resuming continues the same run; pass another "
            "output_dir:=DIR"
        )
    else:
        write_run_file(d, identity)
    rows = EpisodeLog.read(d / EPISODES_FILE) if (d / EPISODES_FILE).exists() else []
    for i, row in enumerate(rows):
        if row.index != i:
            raise ResumeError(f"{d / EPISODES_FILE}: row {i + 1} is episode {row.index}, expected {i}")
    if not (d / MANIFEST_FILE).exists():
        if any(r.samples for r in rows):
            raise ResumeError(f"{d}: {EPISODES_FILE} lists recorded samples but there is no {MANIFEST_FILE}")
        plan.finished = rows
        return plan

    from quad_il.data import open_dataset

    ds = open_dataset(d)
    if ds.status == "incomplete" or any(s.partial for s in ds.shards):
        plan.actions += [f"recover: {a}" for a in _run_tool(["recover", str(d)])]
        ds = open_dataset(d)
    goals = np.concatenate([s.records["goal_world"] for s in ds.shards]) if ds.shards else np.zeros((0, 3))
    ids = np.concatenate([s.records["episode_id"] for s in ds.shards]) if ds.shards else np.zeros(0, np.int64)
    total = int(goals.shape[0])
    cfg = manager_config(
        str(collect_params["config"]), {k: v for k, v in collect_params.items() if k != "config"}
    )
    # Rows in order; each finished episode's records follow the previous one's.
    kept_rows: list[EpisodeOutcome] = []
    pos = 0
    for row in rows:
        goal = np.asarray(plan_episode(cfg, row.index).goal_world)
        n = 0
        while pos + n < total and np.array_equal(goals[pos + n], goal):
            n += 1
        if n < row.samples:
            plan.actions.append(
                f"episode {row.index}: {n} of its {row.samples} records on disk: not finished, flown again "
                f"(with every later episode: {len(rows) - len(kept_rows)} rows dropped from {EPISODES_FILE})"
            )
            break
        wrong = ids[pos : pos + n] != row.index + 1
        if np.any(wrong):
            raise ResumeError(
                f"{d}: record {pos + int(np.argmax(wrong))} of finished episode {row.index} has episode id "
                f"{int(ids[pos + int(np.argmax(wrong))])}, not its keyed id {row.index + 1}: the dataset was "
                "collected before episodes were keyed (issue 32) and cannot be resumed; pass another "
                "output_dir:=DIR"
            )
        kept_rows.append(row)
        pos += n
    finished_goals = [np.asarray(plan_episode(cfg, r.index).goal_world) for r in kept_rows]
    for i in range(pos, total):
        if any(np.array_equal(goals[i], g) for g in finished_goals):
            raise ResumeError(
                f"{d}: record {i} belongs to the finished episode with goal {goals[i].tolist()} but follows "
                "records of an unfinished episode: the dataset is not in episode order, cannot resume"
            )
    plan.finished = kept_rows
    plan.records_kept, plan.records_cut = pos, total - pos
    if pos < total:
        plan.actions += [f"truncate: {a}" for a in _run_tool(["truncate", str(d), "--keep", str(pos)])]
    if len(kept_rows) < len(rows):
        EpisodeLog.rewrite(d / EPISODES_FILE, kept_rows)
    return plan
