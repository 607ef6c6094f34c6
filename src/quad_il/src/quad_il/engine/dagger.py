"""A DAgger-family round on the rollout engine (issue 32, docs/engine.md, "DAgger rounds"): the learner (an
exported policy, LibTorch, the tier of its policy config) flies the round's episodes while the expert, in
labeller mode beside it, plans from exactly the states the learner visits; the expert's plans are written as
an ordinary demonstration dataset (docs/data_format.md), which `python training_only/train_on_cpp_datasets.py`
trains on unchanged.

    python -m quad_il.engine.dagger --policy runs/x/policy.ts --out data/dagger_r1 --seeds 100-299
        --episodes 200 [--workers 2] [--slots 8] [--policy-config config/policy_plain.yaml] [--resume]

Episode i is keyed (world seed seeds[i % len(seeds)], index i) with the collection's start and goal
(quad_il.collection.episodes.plan_episode), so a round is the same dataset whatever --slots and --workers
are; episodes are written in key order. OUT holds the dataset, episodes.csv (the learner's outcome of each
episode; samples = its labels) and dagger_summary.yaml. --workers threads (quad_il.engine.policy_fleet) each
fly --slots episodes together, every frame at which several decide answered by one batched forward pass.
A round stopped early (Ctrl-C, a crash, the machine's stop) is continued with the same command and --resume,
as collection runs are (quad_il.collection.resume): the round's identity (OUT/collect_run.yaml: arguments,
configs and the learner by content) must be the same, a dataset left incomplete is recovered and the
unfinished episode's records are cut before the remaining episodes are flown.
`--policy none` (the IL manager's round 0 without an initial policy) collects the expert's own
demonstrations instead (quad_il.engine.collect), as BC.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import yaml
from tqdm import tqdm

from quad_il.collection import prepare
from quad_il.collection.episodes import EpisodeLog, EpisodeOutcome, manager_config, plan_episode
from quad_il.engine import native
from quad_il.engine.policy_fleet import fly_policy
from quad_il.engine.run_identity import absolute, collection_run_args
from quad_il.tools import config_overlay
from quad_il.tools.cli import HelpFormatter
from quad_il.tools.repo import repo_root


def _abs(text: str) -> Path:
    return Path(absolute(text))


def run_round(
    policy: str,
    output_dir: str,
    seeds: str,
    episodes: int,
    *,
    slots: int = 8,
    workers: int = 2,
    label_stride: int = 3,
    resume: bool = False,
    policy_config: str = "config/policy_plain.yaml",
    collect_config: str = "config/collect.yaml",
    collector_config: str = "config/collector.yaml",
    sim_config: str = "config/sim.yaml",
    planner_config: str = "config/planner.yaml",
    tracker_config: str = "config/tracker.yaml",
    vehicle_config: str = "config/vehicle.yaml",
    episode_timeout_s: float = 0.0,
    progress: bool = True,
) -> dict:
    """Flies the round's episodes OUT does not hold yet; returns the summary (also OUT/dagger_summary.yaml).
    Raises ValueError naming a bad argument before anything is written."""
    e = native()
    if slots < 1:
        raise ValueError(f"slots {slots}: must be >= 1")
    if workers < 1:
        raise ValueError(f"workers {workers}: must be >= 1")
    if policy == "none":  # round 0 without a learner (the manager's {policy}): the expert flies, as BC
        from quad_il.engine.collect import collect

        r = collect(
            output_dir,
            seeds,
            episodes,
            workers=workers,
            resume=resume,
            episode_timeout_s=episode_timeout_s,
            collect_config=collect_config,
            collector_config=collector_config,
            sim_config=sim_config,
            planner_config=planner_config,
            tracker_config=tracker_config,
            vehicle_config=vehicle_config,
            progress=progress,
        )
        summary = {
            "complete": r.complete,
            "episodes": r.episodes,
            "labels": r.samples,
            "learner": "none (expert)",
            "expert_outcomes": r.outcomes,
            "wall_s": round(r.wall_s, 3),
        }
        (r.output_dir / "dagger_summary.yaml").write_text(yaml.safe_dump(summary, sort_keys=False))
        return summary
    if not _abs(policy).is_file():
        raise ValueError(f"policy {policy}: no such file (an exported policy.ts)")
    cfg = manager_config(
        str(_abs(collect_config)),
        {
            "seeds": seeds,
            "episodes": episodes,
            "episode_timeout_s": episode_timeout_s,
            "output_dir": output_dir,
        },
    )
    # The run's identity (quad_il.collection.resume, with the learner and its config): --resume continues only
    # the same round, recovering a dataset a killed round left and cutting its unfinished episode's records.
    run_args = collection_run_args(
        seeds,
        episodes,
        0,
        episode_timeout_s,
        {
            "collect_config": collect_config,
            "collector_config": collector_config,
            "sim_config": sim_config,
            "planner_config": planner_config,
            "tracker_config": tracker_config,
            "vehicle_config": vehicle_config,
        },
        {"policy": policy, "policy_config": policy_config},
    )  # a missing config is refused here, before OUT is created
    out = prepare.prepare_output_dir(
        output_dir, repo_root(), resume=resume, run_args=run_args, tool="quad_il.engine.dagger"
    )
    log_path = out / "episodes.csv"
    previous = EpisodeLog.read(log_path) if log_path.exists() else []
    first = len(previous)
    specs = [plan_episode(cfg, i) for i in range(first, cfg.episodes)]
    configs = e.load_configs(
        str(config_overlay.resolve(_abs(sim_config))),
        str(config_overlay.resolve(_abs(planner_config))),
        str(_abs(tracker_config)),
        str(_abs(vehicle_config)),
    )
    e.TorchPolicy(str(_abs(policy)))  # a file that is no exported policy fails here, before the sink opens
    policy_cfg = e.load_policy_config(str(_abs(policy_config)))
    e.configure_torch_threads(policy_cfg.num_threads)  # the nodes' setting (config/policy.yaml num_threads)
    run_info = [
        ("launch", "quad_il.engine.dagger"),
        ("policy", str(_abs(policy))),
        ("policy_config", str(_abs(policy_config))),
        ("seeds", seeds),
        ("episodes", str(cfg.episodes)),
        ("planner_config", str(_abs(planner_config))),
    ]
    sink = e.DatasetSink(str(_abs(collector_config)), str(out), prepare.software_commit(), run_info, resume)
    log = EpisodeLog(log_path)
    outcomes: dict[str, int] = {}
    for o in previous:
        outcomes[o.outcome] = outcomes.get(o.outcome, 0) + 1
    samples = sum(o.samples for o in previous)
    pending: dict[int, tuple[dict, object]] = {}  # finished ahead of the key order (other workers)
    state = {"next": 0, "samples": samples}
    bar = tqdm(total=cfg.episodes, initial=first, unit="ep", desc="dagger", disable=not progress)
    wall0 = time.monotonic()

    def on_done(k: int, result: dict, labels) -> None:
        pending[k] = (result, labels)
        while state["next"] in pending:  # key order
            result, labels = pending.pop(state["next"])
            spec = specs[state["next"]]
            sink.write(labels)
            log.append(
                EpisodeOutcome(
                    spec.index,
                    spec.seed,
                    result["outcome"],
                    result["reason"],
                    result["flight_time_s"],
                    labels.num_records,
                )
            )
            outcomes[result["outcome"]] = outcomes.get(result["outcome"], 0) + 1
            state["samples"] += labels.num_records
            state["next"] += 1
            bar.update(1)
            bar.set_postfix(labels=state["samples"])

    tuples = [(s.index, s.seed, s.start_world, s.start_yaw_rad, s.goal_world) for s in specs]
    try:
        stats = fly_policy(
            e,
            configs,
            str(_abs(policy)),
            policy_cfg,
            tuples,
            on_done,
            workers=workers,
            slots=slots,
            takeoff_timeout_s=cfg.takeoff_timeout_s,
            episode_timeout_s=cfg.episode_timeout_s,
            labeller=True,
            label_stride=label_stride,
        )
    finally:
        bar.close()
        log.close()
        ok, text = sink.finalize()
        print(f"[engine dagger] {text}", file=sys.stdout if ok else sys.stderr, flush=True)
    wall = time.monotonic() - wall0
    summary = {
        "complete": first + state["next"] >= cfg.episodes,
        "episodes": first + state["next"],
        "labels": state["samples"],
        "learner_outcomes": outcomes,
        "forward_passes": stats.forward_passes,
        "decisions_per_forward_pass": round(stats.decisions_per_forward_pass, 3),
        "workers": workers,
        "wall_s": round(wall, 3),
    }
    (out / "dagger_summary.yaml").write_text(yaml.safe_dump(summary, sort_keys=False))
    if not ok:
        raise RuntimeError(f"{out}: the dataset writer failed: {text}")
    return summary


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m quad_il.engine.dagger", formatter_class=HelpFormatter, description=__doc__
    )
    ap.add_argument(
        "--policy", required=True, help="the learner: an exported policy.ts; none: the expert flies"
    )
    ap.add_argument("--out", required=True, help="the round's dataset directory")
    ap.add_argument("--seeds", default="100-299", help="world seeds, cycled (ranges allowed)")
    ap.add_argument("--episodes", type=int, default=200, help="episodes of the round")
    ap.add_argument(
        "--slots", type=int, default=8, help="episodes a worker flies together (one batched forward pass)"
    )
    ap.add_argument("--workers", type=int, default=2, help="engine workers (threads; one core each)")
    ap.add_argument(
        "--label-stride", type=int, default=3, help="keep the expert's labels of every n-th frame (30 Hz / n)"
    )
    ap.add_argument("--resume", action="store_true", help="continue the round --out holds")
    ap.add_argument("--policy-config", default="config/policy_plain.yaml", help="the learner's tier config")
    ap.add_argument("--planner-config", default="config/planner.yaml", help="the labelling expert's config")
    ap.add_argument(
        "--sim-config",
        default="config/sim.yaml",
        help="the simulator's config or an overlay of it (e.g. a round's worlds at another box density)",
    )
    ap.add_argument(
        "--episode-timeout-s", type=float, default=0.0, help="episode limit (0: collect config's)"
    )
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    a = ap.parse_args(argv)
    try:
        s = run_round(
            a.policy,
            a.out,
            a.seeds,
            a.episodes,
            slots=a.slots,
            workers=a.workers,
            label_stride=a.label_stride,
            resume=a.resume,
            policy_config=a.policy_config,
            planner_config=a.planner_config,
            sim_config=a.sim_config,
            episode_timeout_s=a.episode_timeout_s,
            progress=not a.no_progress,
        )
    except (ValueError, FileNotFoundError) as exc:
        print(f"quad_il.engine.dagger: error: {exc}", file=sys.stderr)
        return 2
    print(f"[engine dagger] {s}", flush=True)
    return 0 if s["complete"] else 1


if __name__ == "__main__":
    sys.exit(main())
