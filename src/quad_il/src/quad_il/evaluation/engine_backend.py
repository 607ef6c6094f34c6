"""Closed-loop evaluation on the rollout engine (`make eval BACKEND=engine`, `run_eval --backend engine`;
issue 32, docs/engine.md). The episodes of OUT/episodes.json are flown in-process: the simulator, the tracker
and the controller as infer.launch connects them, driven by the evaluation runner's logic (take-off, goal,
end; quad_engine's PolicyEpisode), keyed by the episode's index as the ROS runner's resets are. Results go to
OUT/<controller>.jsonl with the ROS runner's fields and measures (quad_il.evaluation.metrics.summarise_flight
on the odometry from the goal to the end and the world's boxes), so the report reads both backends alike.

Controllers: `expert` (the planner in flight mode) and `cpp` (the exported policy through LibTorch and the
one C++ decider, at the run's tier, flown by `workers` threads of quad_il.engine.policy_fleet; every slot
deciding at the same time answered by one batched forward pass). The Python node's own forward pass (`py`)
runs on the ROS backend only. Lockstep timeouts do not exist here: every result has lockstep_timeouts 0.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import yaml

from quad_il.engine import native
from quad_il.engine.policy_fleet import fly_policy
from quad_il.evaluation.episodes import EpisodeResult, append_result, read_episodes, read_results
from quad_il.evaluation.metrics import Box, summarise_flight
from quad_il.tools import config_overlay
from quad_il.tools.repo import repo_root

ENGINE_CONTROLLERS = ("expert", "cpp")
STAMP_EPS_S = 1e-6
VEHICLE_BOX_M = np.array([0.25, 0.25, 0.25])  # the ROS runner's default (runner_args --vehicle-box-m)
TAKEOFF_TIMEOUT_S = 20.0  # the ROS runner's default (runner_args --takeoff-timeout-s)


def to_result(controller: str, spec, r: dict) -> EpisodeResult:
    """The engine's episode as the ROS runner records it."""
    res = EpisodeResult(controller, spec.index, spec.seed, r["outcome"], r["reason"], lockstep_timeouts=0)
    if r["outcome"] in ("reset_failed", "takeoff_failed"):
        return res
    t0, t_end = r["t_goal_s"], r["t_end_s"]
    pts = np.asarray(r["points"], dtype=np.float64).reshape(-1, 4)
    pts = pts[(pts[:, 0] >= t0 - STAMP_EPS_S) & (pts[:, 0] <= t_end + STAMP_EPS_S)]
    boxes = [Box(np.asarray(c), np.asarray(q), np.asarray(s)) for c, q, s in r["boxes"]]
    counts = {k: int(v) for k, v in r["counts"].items()}
    res = summarise_flight(
        res,
        t0,
        t_end,
        pts,
        boxes,
        VEHICLE_BOX_M,
        decision_ms=[],
        plan_ms=[],
        counts=counts or None,
        tracker_rejections=counts.get("tracker_rejection", 0),
    )
    res.decisions = int(r["decisions"])
    return res


def run_controller(
    controller: str,
    out: Path,
    episodes_file: Path,
    sim_config: dict,
    episode_timeout_s: float,
    policy: str | None = None,
    policy_config: Path | None = None,
    slots: int = 8,
    workers: int = 2,
) -> str:
    """Flies the episodes not yet in OUT/<controller>.jsonl on the engine; '' or why the controller is
    skipped."""
    if controller not in ENGINE_CONTROLLERS:
        return f"controller '{controller}' runs on the ros backend only (the engine has {ENGINE_CONTROLLERS})"
    e = native()
    root = repo_root()
    results_path = out / f"{controller}.jsonl"
    done = {r.index for r in read_results(results_path)}
    specs = [s for s in read_episodes(episodes_file) if s.index not in done]
    if not specs:
        return ""
    sim_path = out / f"sim_{controller}.yaml"
    sim_path.write_text(yaml.safe_dump(sim_config))
    configs = e.load_configs(
        str(sim_path),
        str(config_overlay.resolve(root / "config" / "planner.yaml")),
        str(root / "config" / "tracker.yaml"),
        str(root / "config" / "vehicle.yaml"),
    )
    tuples = [(s.index, s.seed, s.start_world, s.start_yaw_rad, s.goal_world) for s in specs]
    wall0 = time.monotonic()
    finished = 0

    def on_done(k: int, r: dict, _labels=None) -> None:
        nonlocal finished
        res = to_result(controller, specs[k], r)
        append_result(results_path, res)
        finished += 1
        print(
            f"[eval {controller} engine] episode {res.index} seed {res.seed}: {res.outcome} ({res.reason}); "
            f"{res.flight_time_s:.1f} s sim; {finished}/{len(specs)} done, "
            f"{time.monotonic() - wall0:.1f} s wall",
            file=sys.stderr,
            flush=True,
        )

    print(f"[eval] {controller}: {len(specs)} episode(s) on the engine", file=sys.stderr, flush=True)
    if controller == "expert":
        vec = e.PolicyVec.experts(configs, 1)
        vec.run_expert(tuples, TAKEOFF_TIMEOUT_S, episode_timeout_s, on_done)
    else:
        policy_cfg = e.load_policy_config(str(policy_config))
        e.configure_torch_threads(policy_cfg.num_threads)  # the nodes' setting (config/policy.yaml)
        fly_policy(
            e,
            configs,
            str(Path(policy).resolve()),
            policy_cfg,
            tuples,
            on_done,
            workers=workers,
            slots=slots,
            takeoff_timeout_s=TAKEOFF_TIMEOUT_S,
            episode_timeout_s=episode_timeout_s,
        )
    return ""
