"""Expert demonstrations on the rollout engine (issue 32, docs/engine.md): the episodes of a collect.launch
run, flown in-process, written through the expert's own collector into one dataset in key order.

    python -m quad_il.engine.collect --out data/train --seeds 100-199 --episodes 200 [--workers 2]
        [--backend local|ray] [--ray-address auto] [--resume] [--planner-config config/planner.yaml] ...

Episode i of the run is keyed (world seed seeds[i % len(seeds)], index i), exactly as collect.launch keys it
(quad_il.collection.episodes.plan_episode and quad_core/episode_key.h), so the dataset is the one
`roslaunch quad_il collect.launch seeds:=... episodes:=...` writes (bit-identical records; tested),
whatever the number of workers or the backend. The directory holds what collect.launch's holds: the dataset
(docs/data_format.md), episodes.csv, collect_run.yaml (the run's identity) and collect_summary.yaml. A run
stopped early (Ctrl-C, a crash) is continued with the same command and --resume, as collect.launch's
resume:=true (also a run collect.launch started).

max_samples stops the run after the episode in key order that reaches it (collect.launch stops inside that
episode): a run with max_samples is not the collect.launch one.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import yaml
from tqdm import tqdm

from quad_il.collection import prepare
from quad_il.collection.episodes import EpisodeLog, EpisodeOutcome, EpisodeSpec, manager_config, plan_episode
from quad_il.engine import native
from quad_il.engine.backends import ConfigPaths, Limits, LocalBackend
from quad_il.engine.run_identity import collection_run_args
from quad_il.tools import config_overlay
from quad_il.tools.cli import HelpFormatter
from quad_il.tools.repo import repo_root

BACKENDS = ("local", "ray")


@dataclass
class CollectResult:
    output_dir: Path
    episodes: int  # finished episodes in the directory (resumed ones included)
    samples: int
    outcomes: dict[str, int]
    wall_s: float
    sim_s: float
    complete: bool


def collect(
    output_dir: str | Path,
    seeds: str,
    episodes: int,
    *,
    workers: int = 1,
    backend: str = "local",
    ray_address: str | None = None,
    resume: bool = False,
    max_samples: int = 0,
    episode_timeout_s: float = 0.0,
    collect_config: str = "config/collect.yaml",
    collector_config: str = "config/collector.yaml",
    sim_config: str = "config/sim.yaml",
    planner_config: str = "config/planner.yaml",
    tracker_config: str = "config/tracker.yaml",
    vehicle_config: str = "config/vehicle.yaml",
    progress: bool = True,
) -> CollectResult:
    """Flies the run's episodes that are not finished yet and writes them. Relative paths are under the
    repository root. Raises ValueError (prepare.PrepareError, ResumeError) naming a bad argument before
    anything is written."""
    root = repo_root()
    if backend not in BACKENDS:
        raise ValueError(f"backend '{backend}': one of {', '.join(BACKENDS)}")
    # The identity collect.launch records (quad_il.collection.resume): the engine reproduces its lockstep run.
    run_args = collection_run_args(
        seeds,
        episodes,
        max_samples,
        episode_timeout_s,
        {
            "collect_config": collect_config,
            "collector_config": collector_config,
            "sim_config": sim_config,
            "planner_config": planner_config,
            "tracker_config": tracker_config,
            "vehicle_config": vehicle_config,
        },
    )
    cfgs = {key: path for key, path in run_args.items() if key.endswith("_config")}
    cfg = manager_config(
        run_args["collect_config"],
        {
            "output_dir": str(output_dir),
            "seeds": seeds,
            "episodes": episodes,
            "max_samples": max_samples,
            "episode_timeout_s": episode_timeout_s,
        },
    )
    out = prepare.prepare_output_dir(
        str(output_dir), root, resume=resume, run_args=run_args, tool="quad_il.engine.collect"
    )
    log_path = out / "episodes.csv"
    previous = EpisodeLog.read(log_path) if log_path.exists() else []
    first = len(previous)
    samples = sum(o.samples for o in previous)
    outcomes: dict[str, int] = {}
    for o in previous:
        outcomes[o.outcome] = outcomes.get(o.outcome, 0) + 1
    stopped = any(o.outcome == "stopped" for o in previous) or (
        cfg.max_samples and samples >= cfg.max_samples
    )
    specs: list[EpisodeSpec] = [] if stopped else [plan_episode(cfg, i) for i in range(first, cfg.episodes)]
    # Overlays (config/planner_privileged.yaml) are merged into a full config for the C++ loaders.
    merged = {k: str(config_overlay.resolve(v)) for k, v in cfgs.items()}
    paths = ConfigPaths(
        merged["sim_config"], merged["planner_config"], merged["tracker_config"], merged["vehicle_config"]
    )
    limits = Limits(cfg.takeoff_timeout_s, cfg.episode_timeout_s)
    if backend == "ray":
        from quad_il.engine.ray_backend import RayBackend

        runner = RayBackend(paths, workers=workers, address=ray_address)
    else:
        runner = LocalBackend(paths, workers=workers)

    run_info = [
        ("launch", "quad_il.engine.collect"),
        ("backend", backend),
        ("workers", str(workers)),
        ("seeds", seeds),
        ("episodes", str(cfg.episodes)),
        ("max_samples", str(cfg.max_samples)),
        ("time_mode", "engine (lockstep)"),
        ("collect_config", cfgs["collect_config"]),
        ("sim_config", cfgs["sim_config"]),
        ("planner_config", cfgs["planner_config"]),
    ]
    sink = native().DatasetSink(
        merged["collector_config"], str(out), prepare.software_commit(root), run_info, bool(resume)
    )
    log = EpisodeLog(log_path)
    wall0 = time.monotonic()
    sim_s = 0.0
    finished = first
    interrupted = False
    bar = tqdm(
        total=cfg.episodes, initial=first, unit="ep", desc="collect", disable=not progress, smoothing=0.1
    )
    pending: dict[int, object] = {}
    samples_before = samples
    try:
        for spec, run in runner.run(specs, limits):
            pending[spec.index] = run
            # Written in key order: the dataset does not depend on which worker finished first.
            while finished in pending:
                r = pending.pop(finished)
                sink.write(r)
                outcome = EpisodeOutcome(r.index, r.seed, r.outcome, r.reason, r.sim_duration_s, r.samples)
                log.append(outcome)
                finished += 1
                samples += r.samples
                sim_s += r.sim_s
                outcomes[r.outcome] = outcomes.get(r.outcome, 0) + 1
                bar.update(1)
                rate = (samples - samples_before) / max(time.monotonic() - wall0, 1e-9)
                bar.set_postfix(samples=samples, rec_per_s=f"{rate:.0f}")
                if cfg.max_samples and samples >= cfg.max_samples:
                    stopped = True
                    break
            if stopped:
                break
    except KeyboardInterrupt:
        interrupted = True
    finally:
        bar.close()
        log.close()
        ok, text = sink.finalize()
        print(f"[engine collect] {text}", file=sys.stdout if ok else sys.stderr, flush=True)
    wall_s = time.monotonic() - wall0
    complete = not interrupted and (finished >= cfg.episodes or bool(stopped))
    summary = {
        "complete": complete,
        "backend": backend,
        "workers": workers,
        "episodes_planned": cfg.episodes,
        "resumed_at_episode": first,
        "episodes": finished,
        "samples": samples,
        "outcomes": outcomes,
        "sim_s": round(sim_s, 6),
        "wall_s": round(wall_s, 3),
        "records_per_s": round((samples - samples_before) / wall_s, 3) if wall_s > 0 else 0.0,
    }
    (out / "collect_summary.yaml").write_text(yaml.safe_dump(summary, sort_keys=False))
    if not ok:
        raise RuntimeError(f"{out}: the dataset writer failed: {text}")
    return CollectResult(out, finished, samples, outcomes, wall_s, sim_s, complete)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m quad_il.engine.collect", formatter_class=HelpFormatter, description=__doc__
    )
    ap.add_argument("--out", required=True, help="dataset directory (relative: under the repository root)")
    ap.add_argument("--seeds", default="1,2,3", help="world seeds, cycled (a list with ranges: 1,2,10-19)")
    ap.add_argument("--episodes", type=int, default=3, help="episodes to fly")
    ap.add_argument("--workers", type=int, default=2, help="engine workers (threads, or Ray actors)")
    ap.add_argument("--backend", choices=BACKENDS, default="local", help="where the workers run")
    ap.add_argument("--ray-address", default=None, help="Ray cluster address (ray start --head; None: local)")
    ap.add_argument("--resume", action="store_true", help="continue the interrupted run --out holds")
    ap.add_argument(
        "--max-samples", type=int, default=0, help="stop after the episode reaching this (0: none)"
    )
    ap.add_argument(
        "--episode-timeout-s", type=float, default=0.0, help="sim-time limit (0: collect config's)"
    )
    for name, default in (
        ("collect-config", "config/collect.yaml"),
        ("collector-config", "config/collector.yaml"),
        ("sim-config", "config/sim.yaml"),
        ("planner-config", "config/planner.yaml"),
        ("tracker-config", "config/tracker.yaml"),
        ("vehicle-config", "config/vehicle.yaml"),
    ):
        ap.add_argument(f"--{name}", default=default, help=f"{name.replace('-', ' ')} file")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    a = ap.parse_args(argv)
    try:
        r = collect(
            a.out,
            a.seeds,
            a.episodes,
            workers=a.workers,
            backend=a.backend,
            ray_address=a.ray_address,
            resume=a.resume,
            max_samples=a.max_samples,
            episode_timeout_s=a.episode_timeout_s,
            collect_config=a.collect_config,
            collector_config=a.collector_config,
            sim_config=a.sim_config,
            planner_config=a.planner_config,
            tracker_config=a.tracker_config,
            vehicle_config=a.vehicle_config,
            progress=not a.no_progress,
        )
    except (ValueError, FileNotFoundError) as exc:
        print(f"quad_il.engine.collect: error: {exc}", file=sys.stderr)
        return 2
    print(
        f"[engine collect] {r.episodes} episodes, {r.samples} samples, outcomes {r.outcomes}; "
        f"{r.sim_s:.1f} s sim in {r.wall_s:.1f} s wall; {r.output_dir}",
        flush=True,
    )
    return 0 if r.complete else 1


if __name__ == "__main__":
    sys.exit(main())
