"""Parallel collection (issue 9, Scale; docs/collect.md "Parallel collection"; issue 32, docs/engine.md).

    python -m quad_il.collection.parallel --workers 2 --seeds 100-199 --episodes 200 --out data/train
        [--backend engine|ros] [--launch-arg key:=value ...] [--timeout-s 7200] [--resume]

--backend engine (the default): one in-process engine run with N worker threads (python -m
quad_il.engine.collect): OUT is one dataset whose episode i is keyed (seeds[i % len(seeds)], i), the records a
single collect.launch run with these seeds gives, whatever N; OUT/collection.yaml summarises it.

--backend ros: N `collect.launch` workers, each on its own ROS master port with its own world seeds, into one
dataset collection directory, as follows.

The seeds are dealt round-robin to the workers (worker k flies seeds[k::N]) and the episodes split as evenly
as possible. The worlds flown do not depend on N; the start/goal pairs do (collect.launch draws them from
(world seed, the worker's episode index)), so runs with different N are different datasets. Worker k writes
the ordinary dataset OUT/worker_k (format: docs/data_format.md); OUT/collection.yaml lists the workers, their
seeds, outcome counts, records and wall times, and the totals. The training scripts take OUT itself as a
dataset path (quad_il.learning.dataset.expand_paths reads every worker dataset under it).

Ctrl-C (SIGINT) is forwarded to every worker: each finalises its dataset and collection.yaml is still written.
A worker that stopped before its last episode (its master died, a crash) makes the command exit 1; the same
command with --resume completes every worker's run (collect.launch resume:=true, docs/collect.md "Resuming").
Progress: every worker's per-episode line, prefixed with its index.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from quad_il.collection import episodes
from quad_il.collection.launch_run import collect_command
from quad_il.tools.cli import HelpFormatter
from quad_il.tools.ports import free_port

COLLECTION_FILE = "collection.yaml"


class ParallelError(RuntimeError):
    """The parallel collection cannot start; the message says why."""


def parse_seed_ranges(text: str) -> list[int]:
    """'100-103,110' -> [100, 101, 102, 103, 110]; every seed at most once (workers fly distinct worlds)."""
    try:
        return episodes.parse_seed_ranges(text, distinct=True)
    except ValueError as exc:
        raise ParallelError(str(exc)) from None


@dataclass
class WorkerPlan:
    index: int
    seeds: list[int]
    episodes: int
    out_dir: Path
    port: int = 0
    extra: dict[str, str] = field(default_factory=dict)


def plan_workers(
    seeds: Sequence[int], episodes: int, workers: int, out: Path, extra: dict[str, str] | None = None
) -> list[WorkerPlan]:
    """Seeds dealt round-robin, episodes split evenly (the first workers take the remainder)."""
    if workers < 1:
        raise ParallelError(f"--workers {workers}: must be >= 1")
    if episodes < workers:
        raise ParallelError(f"--episodes {episodes} < --workers {workers}: every worker needs an episode")
    if len(seeds) < workers:
        raise ParallelError(f"{len(seeds)} seed(s) for {workers} workers: every worker needs its own seed")
    plans = []
    for k in range(workers):
        n = episodes // workers + (1 if k < episodes % workers else 0)
        plans.append(WorkerPlan(k, list(seeds[k::workers]), n, out / f"worker_{k}", extra=dict(extra or {})))
    return plans


def _parse_launch_args(items: Sequence[str]) -> dict[str, str]:
    out: dict[str, str] = {}
    reserved = {"output_dir", "seeds", "episodes", "resume"}
    for item in items:
        if ":=" not in item:
            raise ParallelError(f"--launch-arg '{item}': expected key:=value (a collect.launch argument)")
        k, v = item.split(":=", 1)
        if k in reserved:
            raise ParallelError(f"--launch-arg {k}: set by the parallel collector itself (--{k} / --out)")
        out[k] = v
    return out


def _pump(proc: subprocess.Popen, prefix: str, log_path: Path) -> None:
    with open(log_path, "w") as log:
        assert proc.stdout is not None
        for line in proc.stdout:
            log.write(line)
            if line.startswith("[collect]") or "error" in line.lower():
                sys.stderr.write(f"{prefix} {line}")
                sys.stderr.flush()


def _summary_of(worker_dir: Path) -> dict:
    path = worker_dir / "collect_summary.yaml"
    if not path.is_file():
        return {}
    with open(path) as fh:
        return yaml.safe_load(fh) or {}


def run_parallel(plans: list[WorkerPlan], out: Path, timeout_s: float, resume: bool = False) -> dict:
    """resume: every worker continues the run its directory holds (collect.launch resume:=true; the same
    --workers, --seeds and --episodes give every worker the same arguments, which the launch checks)."""
    out.mkdir(parents=True, exist_ok=True)
    for p in plans:
        if resume:
            p.extra["resume"] = "true"
        elif p.out_dir.exists() and any(p.out_dir.iterdir()):
            raise ParallelError(
                f"{p.out_dir} already exists and is not empty: the parallel collector never overwrites a "
                "dataset; pass another --out, remove it, or --resume to complete the collection it holds"
            )
    procs: list[tuple[WorkerPlan, subprocess.Popen, threading.Thread]] = []
    t0 = time.monotonic()
    stopping = {"flag": False}

    def forward(signum: int, _frame: object) -> None:
        stopping["flag"] = True
        for _, proc, _ in procs:
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)

    old = signal.signal(signal.SIGINT, forward)
    try:
        for p in plans:
            p.port = free_port()
            env = {
                **os.environ,
                "ROS_MASTER_URI": f"http://127.0.0.1:{p.port}",
                "ROS_HOME": str(out / "ros_home" / f"worker_{p.index}"),
            }
            cmd = collect_command(
                p.out_dir, p.port, seeds=",".join(map(str, p.seeds)), episodes=p.episodes, **p.extra
            )
            proc = subprocess.Popen(
                cmd,
                env=env,
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                text=True,
                start_new_session=True,  # Ctrl-C reaches the workers only through `forward`
            )
            th = threading.Thread(
                target=_pump, args=(proc, f"[worker {p.index}]", out / f"worker_{p.index}.log"), daemon=True
            )
            th.start()
            procs.append((p, proc, th))
            print(
                f"[parallel] worker {p.index}: port {p.port}, {p.episodes} episodes, seeds "
                f"{p.seeds[0]}..{p.seeds[-1]} ({len(p.seeds)}) -> {p.out_dir}",
                file=sys.stderr,
                flush=True,
            )
        deadline = t0 + timeout_s
        for p, proc, th in procs:
            try:
                proc.wait(timeout=max(1.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                print(f"[parallel] worker {p.index}: wall timeout, stopping it", file=sys.stderr, flush=True)
                proc.send_signal(signal.SIGINT)
                try:
                    proc.wait(timeout=60)
                except subprocess.TimeoutExpired:
                    os.killpg(proc.pid, signal.SIGKILL)
                    proc.wait()
            th.join(timeout=10)
    finally:
        signal.signal(signal.SIGINT, old)
    wall = time.monotonic() - t0
    workers = []
    totals = {"episodes": 0, "records": 0, "outcomes": {}}
    for p, proc, _ in procs:
        s = _summary_of(p.out_dir)
        records = int(s.get("samples", s.get("records", 0)) or 0)
        episodes = int(s.get("episodes_finished", s.get("episodes", 0)) or 0)
        outcomes = s.get("outcomes", {}) or {}
        workers.append(
            {
                "index": p.index,
                "dir": p.out_dir.name,
                "port": p.port,
                "seeds": p.seeds,
                "episodes_planned": p.episodes,
                "episodes": episodes,
                "records": records,
                "outcomes": dict(outcomes),
                "exit_code": proc.returncode,
                "summary": s,
            }
        )
        totals["episodes"] += episodes
        totals["records"] += records
        for k, v in outcomes.items():
            totals["outcomes"][k] = totals["outcomes"].get(k, 0) + int(v)
    result = {
        "workers": workers,
        "num_workers": len(plans),
        "wall_s": round(wall, 3),
        "records_per_s": round(totals["records"] / wall, 4) if wall > 0 else 0.0,
        "interrupted": stopping["flag"],
        **totals,
    }
    tmp = out / (COLLECTION_FILE + ".tmp")
    tmp.write_text(yaml.safe_dump(result, sort_keys=False))
    os.replace(tmp, out / COLLECTION_FILE)
    return result


# collect.launch arguments the engine takes (as python -m quad_il.engine.collect options).
ENGINE_LAUNCH_ARGS = (
    "planner_config",
    "sim_config",
    "collect_config",
    "collector_config",
    "tracker_config",
    "vehicle_config",
    "episode_timeout_s",
    "max_samples",
)


def run_engine(args: argparse.Namespace) -> int:
    """--backend engine: one `python -m quad_il.engine.collect` run into OUT (one dataset; episode i keyed
    (seeds[i % len(seeds)], i) as in one collect.launch run), and OUT/collection.yaml from its summary."""
    try:
        launch = _parse_launch_args(args.launch_arg)
    except ParallelError as exc:
        print(f"parallel collection: error: {exc}", file=sys.stderr)
        return 2
    unknown = sorted(set(launch) - set(ENGINE_LAUNCH_ARGS))
    if unknown:
        print(
            "parallel collection: error: --backend engine takes the launch arguments "
            f"{list(ENGINE_LAUNCH_ARGS)}, not {unknown} (use --backend ros)",
            file=sys.stderr,
        )
        return 2
    out = args.out.resolve()
    cmd = [sys.executable, "-m", "quad_il.engine.collect", "--out", str(out), "--seeds", args.seeds]
    cmd += ["--episodes", str(args.episodes), "--workers", str(args.workers)]
    cmd += [f"--{k.replace('_', '-')}={v}" for k, v in launch.items()]
    if args.resume:
        cmd.append("--resume")
    t0 = time.monotonic()
    try:
        code = subprocess.run(cmd, timeout=args.timeout_s).returncode
    except subprocess.TimeoutExpired:
        print(f"parallel collection: the engine run exceeded --timeout-s {args.timeout_s:g}", file=sys.stderr)
        return 1
    summary_path = out / "collect_summary.yaml"
    summary = yaml.safe_load(summary_path.read_text()) if summary_path.is_file() else {}
    wall = time.monotonic() - t0
    result = {
        "backend": "engine",
        "num_workers": args.workers,
        "seeds": args.seeds,
        "episodes": summary.get("episodes", 0),
        "records": summary.get("samples", 0),
        "outcomes": summary.get("outcomes", {}),
        "wall_s": round(wall, 3),
        "records_per_s": round(summary.get("samples", 0) / wall, 3) if wall > 0 else 0.0,
        "complete": bool(summary.get("complete", False)),
    }
    if code == 0 and result["complete"]:
        tmp = out / (COLLECTION_FILE + ".tmp")
        tmp.write_text(yaml.safe_dump(result, sort_keys=False))
        os.replace(tmp, out / COLLECTION_FILE)
    print(
        f"[parallel] engine, {args.workers} worker(s): {result['episodes']} episodes, "
        f"{result['records']} records in {wall:.0f} s; outcomes {result['outcomes']}",
        file=sys.stderr,
    )
    return code


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(formatter_class=HelpFormatter, description=__doc__.split("\n\n")[0])
    ap.add_argument("--workers", type=int, default=2, help="parallel collect.launch workers")
    ap.add_argument("--seeds", required=True, help="world seeds, e.g. 100-199 or 1,2,3 (distinct)")
    ap.add_argument("--episodes", type=int, required=True, help="episodes over all workers")
    ap.add_argument("--out", type=Path, required=True, help="collection directory (worker_k/ inside)")
    ap.add_argument(
        "--launch-arg",
        action="append",
        default=[],
        metavar="KEY:=VALUE",
        help="extra collect.launch argument",
    )
    ap.add_argument("--timeout-s", type=float, default=4 * 3600.0, help="wall-time limit of the whole run")
    ap.add_argument(
        "--resume",
        action="store_true",
        help="complete an interrupted collection in --out (same --workers, --seeds, --episodes)",
    )
    ap.add_argument(
        "--backend",
        choices=["engine", "ros"],
        default="engine",
        help="engine: one in-process run (python -m quad_il.engine.collect, OUT one dataset, the keys of one "
        "collect.launch run); ros: the collect.launch workers",
    )
    args = ap.parse_args(argv)
    if args.backend == "engine":
        return run_engine(args)
    try:
        plans = plan_workers(
            parse_seed_ranges(args.seeds),
            args.episodes,
            args.workers,
            args.out.resolve(),
            _parse_launch_args(args.launch_arg),
        )
        result = run_parallel(plans, args.out.resolve(), args.timeout_s, resume=args.resume)
    except ParallelError as exc:
        print(f"parallel collection: error: {exc}", file=sys.stderr)
        return 2
    print(
        f"[parallel] {result['num_workers']} worker(s): {result['episodes']} episodes, {result['records']} "
        f"records in {result['wall_s']:.0f} s ({result['records_per_s']:.2f} records/s); outcomes "
        f"{result['outcomes']} -> {args.out / COLLECTION_FILE}",
        file=sys.stderr,
    )
    failed = [w["index"] for w in result["workers"] if w["exit_code"] != 0]
    if failed and not result["interrupted"]:
        print(
            f"parallel collection: worker(s) {failed} exited with an error (see their logs)", file=sys.stderr
        )
        return 1
    # roslaunch exits 0 even when its master died: the worker's own summary says whether its run completed.
    unfinished = [w["index"] for w in result["workers"] if not w["summary"].get("complete", True)]
    if unfinished and not result["interrupted"]:
        print(
            f"parallel collection: worker(s) {unfinished} stopped before their last episode (see their "
            "logs); the same command with --resume completes them",
            file=sys.stderr,
        )
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
