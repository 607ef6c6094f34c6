"""`make bench-engine` (scripts/bench/engine.sh; issue 32, "Benchmarks"; docs/engine.md, "Benchmarks"): the
rollout engine against the ROS path, measured in one run on the same episode keys.

    python -m quad_il.engine_bench [--seeds 1-6] [--episodes 6] [--privileged-episodes 48]
        [--parts ros,expert,privileged,policy,ray]

Prints `BENCH <name> <value> <unit>` lines on stdout, and beside them the machine's load (1/5/15-minute load
averages and the number of CPUs, before and after every part) as `load ...` lines; progress on stderr.

- ros: `roslaunch quad_il collect.launch` (lockstep, 1 worker, the depth-mapping expert of
  config/planner.yaml) on a private master. `engine_ros_records_per_s` = records / wall seconds of the whole
  launch (from starting roslaunch to its exit: roscore, node start-up and the dataset's finalisation
  included); the episode manager's own span (collect_summary.yaml `wall_s`, from its first reset to its
  last episode's end) is reported as `engine_ros_manager_records_per_s`.
- expert: `quad_il.engine.collect.collect(workers=1)` in this process, same keys and expert; records / wall
  seconds of the call (configs loaded, the worker built, the dataset written and finalised), and
  `engine_expert_speedup` = that / `engine_ros_records_per_s`; `engine_expert_records_per_s_2workers` and
  `engine_expert_speedup_2workers` the same keys on 2 worker threads in the process.
  `engine_parity_identical` is 1 when the records of both runs equal the ROS run's (records_digest without
  the timing fields, as `python -m quad_il.collection.compare` prints it) and episodes.csv is the same,
  else 0.
- privileged: the same with config/planner_privileged.yaml (map.source: global), over --privileged-episodes
  episodes (the seeds cycled; an episode takes about half a second, so six would measure mostly the start-up);
  `engine_privileged_records_per_s_2workers` is the same run with 2 worker threads in the process.
- policy: 8 evaluation episodes (world seeds 9000-9007, run_eval's start/goal sampling, 20 s sim limit) flown
  together by quad_engine_py.PolicyVec.run_torch with a seeded random policy of config/train.yaml's model
  exported with `forward_net`, config/policy.yaml as it is (the shield tier): every round of decisions is one
  batched LibTorch forward pass. `engine_policy_rtf_batch8` = sim seconds summed over the 8 episodes / wall
  seconds of run_torch; the forward passes and decisions per pass are printed too, and the same episodes at
  the safety tier (`engine_policy_rtf_batch8_safety_tier`, no recovery) for comparison. `--policy FILE`
  flies a trained policy instead of the random one.
- ray: quad_il.engine.ray_backend.bench_records_per_s with 1 and 2 actors, the privileged expert, the
  privileged part's keys.
"""

from __future__ import annotations

import argparse
import csv
import os
import shutil
import sys
import tempfile
import time
import traceback
from collections.abc import Callable, Sequence
from pathlib import Path

import yaml

from quad_il.collection.compare import compare_records, dataset_records, records_digest
from quad_il.tools.bench_check import format_bench_line
from quad_il.tools.cli import HelpFormatter
from quad_il.tools.repo import repo_root

PARTS = ("ros", "expert", "privileged", "policy", "ray")
DEPTH_EXPERT = "config/planner.yaml"
PRIVILEGED_EXPERT = "config/planner_privileged.yaml"
POLICY_SEEDS = list(range(9000, 9008))
POLICY_BATCH = 8
# run_eval's start-goal sampling (20-30 m apart) and take-off limit (quad_il.evaluation.runner: 20 s). The
# episode limit is 20 s of sim time, not run_eval's 60 s: the random policy reaches no goal, so every episode
# lasts the whole limit, and 8 x 60 s took 4.5 minutes here (the whole bench has to fit in about 10).
POLICY_EPISODE_TIMEOUT_S = 20.0
POLICY_TAKEOFF_TIMEOUT_S = 20.0


def log(text: str) -> None:
    print(f"[bench engine] {text}", file=sys.stderr, flush=True)


def bench(name: str, value: float, unit: str) -> None:
    print(format_bench_line(name, value, unit), flush=True)


def print_load(when: str) -> None:
    """The machine's load beside the numbers: the benchmark shares 2 cores with whatever else runs."""
    one, five, fifteen = os.getloadavg()
    print(
        f"load {when}: loadavg {one:.2f} {five:.2f} {fifteen:.2f} (1/5/15 min), nproc {os.cpu_count()}",
        flush=True,
    )


def _episodes_csv(path: Path) -> list[list[str]]:
    with (path / "episodes.csv").open(newline="") as f:
        return list(csv.reader(f))


class EngineBench:
    def __init__(
        self,
        seeds: str,
        episodes: int,
        work: Path,
        policy: Path | None = None,
        policy_timeout_s: float = 20.0,
        privileged_episodes: int = 48,
    ) -> None:
        self.seeds = seeds
        self.episodes = episodes
        self.privileged_episodes = privileged_episodes
        self.work = work
        self.policy = policy
        self.policy_timeout_s = policy_timeout_s
        self.root = repo_root()
        self.ros_records_per_s: float | None = None
        self.ros_dir: Path | None = None

    # The ROS baseline.
    def part_ros(self) -> None:
        from quad_il.collection.launch_run import run_collect

        out = self.work / "ros"
        log(
            f"collect.launch lockstep, 1 worker, {DEPTH_EXPERT}: seeds {self.seeds}, {self.episodes} episodes"
        )
        run = run_collect(
            out,
            self.work / "ros.log",
            timeout_s=max(600.0, 120.0 * self.episodes),
            seeds=self.seeds,
            episodes=self.episodes,
            time_mode="lockstep",
            output="log",
            planner_config=self.root / DEPTH_EXPERT,
        )
        manifest = out / "manifest.yaml"
        if run.returncode != 0 or not manifest.is_file() or "status: complete" not in manifest.read_text():
            tail = "\n".join(run.log.splitlines()[-30:])
            raise RuntimeError(f"collect.launch into {out} failed (exit {run.returncode}):\n{tail}")
        summary = yaml.safe_load((out / "collect_summary.yaml").read_text())
        records = len(dataset_records(out))
        if not summary.get("complete") or summary.get("episodes") != self.episodes or records == 0:
            tail = "\n".join(run.log.splitlines()[-30:])
            raise RuntimeError(
                f"collect.launch into {out} flew {summary.get('episodes')} of {self.episodes} episodes "
                f"({records} records, complete: {summary.get('complete')}):\n{tail}"
            )
        manager_wall_s = float(summary["wall_s"])
        log(
            f"collect.launch: {records} records, {summary['sim_s']:.1f} s sim; {run.wall_s:.1f} s wall for "
            f"the launch, {manager_wall_s:.1f} s in the episode manager"
        )
        self.ros_records_per_s = records / run.wall_s
        self.ros_dir = out
        bench("engine_ros_records_per_s", self.ros_records_per_s, "records/s")
        bench("engine_ros_manager_records_per_s", records / manager_wall_s, "records/s")

    # The engine's experts.
    def _engine_collect(
        self, name: str, planner_config: str, episodes: int, workers: int = 1
    ) -> tuple[Path, float]:
        from quad_il.engine.collect import collect

        out = self.work / name
        log(f"engine collect, {workers} worker(s), {planner_config}: seeds {self.seeds}, {episodes} episodes")
        t0 = time.monotonic()
        r = collect(out, self.seeds, episodes, workers=workers, planner_config=planner_config, progress=False)
        wall_s = time.monotonic() - t0
        if not r.complete:
            raise RuntimeError(f"engine collection into {out} did not complete: {r}")
        log(f"engine {name}: {r.samples} records, {r.sim_s:.1f} s sim in {wall_s:.1f} s wall, {r.outcomes}")
        return out, r.samples / wall_s

    def _ratio(self, name: str, value: float) -> None:
        if self.ros_records_per_s is None:
            log(f"{name}: no ROS baseline in this run (part 'ros' not run or failed): no ratio")
            return
        bench(name, value / self.ros_records_per_s, "x")

    def part_expert(self) -> None:
        out, rps = self._engine_collect("expert", DEPTH_EXPERT, self.episodes)
        bench("engine_expert_records_per_s", rps, "records/s")
        self._ratio("engine_expert_speedup", rps)
        # The same keys on 2 worker threads of the process: the same dataset (written in key order).
        out2, rps2 = self._engine_collect("expert_2", DEPTH_EXPERT, self.episodes, workers=2)
        bench("engine_expert_records_per_s_2workers", rps2, "records/s")
        self._ratio("engine_expert_speedup_2workers", rps2)
        eng = dataset_records(out)
        same_workers = records_digest(dataset_records(out2)) == records_digest(eng)
        if not same_workers:
            log("parity: the 2-worker engine run's records differ from the 1-worker run's")
        if self.ros_dir is None:
            log("engine_parity_identical: no ROS dataset in this run: not measured")
            return
        ros = dataset_records(self.ros_dir)
        same_records = records_digest(ros) == records_digest(eng)
        same_csv = _episodes_csv(self.ros_dir) == _episodes_csv(out)
        log(
            f"parity: ROS {len(ros)} records sha256 {records_digest(ros)[:16]}, engine {len(eng)} records "
            f"sha256 {records_digest(eng)[:16]}; episodes.csv {'equal' if same_csv else 'DIFFERENT'}"
        )
        if not same_records:
            log("parity: record differences:\n  " + "\n  ".join(compare_records(ros, eng)))
        bench("engine_parity_identical", int(same_records and same_csv and same_workers), "bool")

    def part_privileged(self) -> None:
        _, rps = self._engine_collect("privileged", PRIVILEGED_EXPERT, self.privileged_episodes)
        bench("engine_privileged_records_per_s", rps, "records/s")
        self._ratio("engine_privileged_speedup", rps)
        _, rps2 = self._engine_collect("privileged_2", PRIVILEGED_EXPERT, self.privileged_episodes, workers=2)
        bench("engine_privileged_records_per_s_2workers", rps2, "records/s")

    # The batched policy.
    def part_policy(self) -> None:
        from quad_il.engine import native
        from quad_il.inference.random_policy import export_random_policy
        from quad_il.learning.config import load_config
        from quad_il.tools import config_overlay

        cfg = load_config([self.root / "config" / "train.yaml"])
        if self.policy is not None:
            policy_file = self.policy
            what = f"the policy {policy_file}"
        else:
            policy_file = export_random_policy(
                self.work / "random_policy.ts",
                cfg.model,
                cfg.data.shards.num_ctrl_pts,
                cfg.data.shards.horizon_s,
                seed=0,
                forward_net=True,
            )
            what = (
                f"a random {cfg.model.variant} {cfg.model.input_height}x{cfg.model.input_width} policy with "
                "forward_net"
            )
        policy_yaml = config_overlay.resolve(self.root / "config" / "policy.yaml")
        num_threads = int(yaml.safe_load(Path(policy_yaml).read_text())["num_threads"])
        # The engine's evaluation and DAgger rounds set the config's threads the same way.
        native().configure_torch_threads(num_threads)
        log(f"policy: {what}, {num_threads} torch thread(s), {self.policy_timeout_s:g} s sim per episode")
        rtf, passes, decisions, recovery, speculated = self._fly_policy(policy_file, "shield")
        print(
            f"policy batch (shield): {passes} forward passes, {decisions} batched decisions, "
            f"{decisions / max(passes, 1):.2f} decisions per pass (batch of {POLICY_BATCH}); "
            f"{speculated} decisions with their turned goals in the round's pass (the previous one was "
            f"refused), {recovery} recovery passes (each: every turned goal of one refused decision)",
            flush=True,
        )
        bench("engine_policy_rtf_batch8", rtf, "x")
        bench("engine_policy_decisions_per_pass", decisions / max(passes, 1), "decisions")
        # The same episodes at the safety tier (no recovery, final approach or keeping), for comparison: on a
        # refused decision the shield's recovery asks the network again for its turned goals (one pass).
        rtf_safety, *_ = self._fly_policy(policy_file, "safety")
        bench("engine_policy_rtf_batch8_safety_tier", rtf_safety, "x")

    def _fly_policy(self, policy_file: Path, tier: str) -> tuple[float, int, int, int, int]:
        """Flies the POLICY_BATCH evaluation episodes in one PolicyVec with config/policy.yaml at `tier`;
        returns (sim seconds summed over the episodes / wall seconds of run_torch, forward passes, batched
        decisions, recovery passes, decisions whose turned goals were in the round's pass)."""
        from quad_il.collection.episodes import StartGoalConfig, plan_eval_episodes
        from quad_il.engine import native
        from quad_il.evaluation.tiers import render_tier_config

        e = native()
        tier_yaml = self.work / f"policy_{tier}.yaml"
        tier_yaml.write_text(render_tier_config(self.root / "config" / "policy.yaml", tier))
        configs = e.load_configs(
            *(str(self.root / "config" / f"{n}.yaml") for n in ("sim", "planner", "tracker", "vehicle"))
        )
        torch_policy = e.TorchPolicy(str(policy_file))
        gen = yaml.safe_load((self.root / "config" / "sim.yaml").read_text())["world"]["generator"]
        start_goal = StartGoalConfig(
            bounds_min_xy_m=tuple(gen["bounds_min_m"][:2]), bounds_max_xy_m=tuple(gen["bounds_max_m"][:2])
        )
        specs = plan_eval_episodes(POLICY_SEEDS, POLICY_BATCH, start_goal)
        vec = e.PolicyVec(
            configs, e.load_policy_config(str(tier_yaml)), torch_policy.meta, POLICY_BATCH, False
        )
        results: dict[int, dict] = {}
        t0 = time.monotonic()
        vec.run_torch(
            torch_policy,
            [(s.index, s.seed, s.start_world, s.start_yaw_rad, s.goal_world) for s in specs],
            POLICY_TAKEOFF_TIMEOUT_S,
            self.policy_timeout_s,
            lambda k, result, _labels: results.__setitem__(k, result),
        )
        wall_s = time.monotonic() - t0
        if len(results) != len(specs):
            raise RuntimeError(f"run_torch ({tier} tier) returned {len(results)} of {len(specs)} episodes")
        sim_s = sum(float(r["sim_s"]) for r in results.values())
        outcomes: dict[str, int] = {}
        counts: dict[str, int] = {}
        for r in results.values():
            outcomes[r["outcome"]] = outcomes.get(r["outcome"], 0) + 1
            for k, n in r["counts"].items():
                counts[k] = counts.get(k, 0) + int(n)
        log(
            f"policy, {tier} tier: {POLICY_BATCH} episodes (world seeds "
            f"{POLICY_SEEDS[0]}-{POLICY_SEEDS[-1]}) in one PolicyVec: {sim_s:.1f} s sim in {wall_s:.1f} s "
            f"wall; outcomes {outcomes}; decision verdicts {counts}"
        )
        return (
            sim_s / wall_s,
            int(vec.forward_passes),
            int(vec.batched_decisions),
            int(vec.recovery_passes),
            int(vec.speculated_decisions),
        )

    # Ray.
    def part_ray(self) -> None:
        from quad_il.engine.ray_backend import bench_records_per_s

        rps = {}
        for actors, name in (
            (1, "ray_collect_records_per_s_1actor"),
            (2, "ray_collect_records_per_s_2actors"),
        ):
            log(
                f"Ray backend, {actors} actor(s), {PRIVILEGED_EXPERT}: seeds {self.seeds}, "
                f"{self.privileged_episodes} episodes"
            )
            rps[actors] = bench_records_per_s(actors, self.privileged_episodes, self.seeds, PRIVILEGED_EXPERT)
            bench(name, rps[actors], "records/s")
        bench("ray_collect_speedup_2actors", rps[2] / rps[1], "x")


def _parts(text: str) -> list[str]:
    parts = [p.strip() for p in text.split(",") if p.strip()]
    for p in parts:
        if p not in PARTS:
            raise argparse.ArgumentTypeError(f"unknown part {p!r} (parts: {', '.join(PARTS)})")
    return parts


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m quad_il.engine_bench", formatter_class=HelpFormatter, description=__doc__
    )
    ap.add_argument("--seeds", default="1-6", help="world seeds of the collection parts (ROS, engine, Ray)")
    ap.add_argument("--episodes", type=int, default=6, help="episodes of the collection parts")
    ap.add_argument(
        "--privileged-episodes", type=int, default=48, help="episodes of the privileged and Ray parts"
    )
    ap.add_argument("--parts", type=_parts, default=list(PARTS), help="comma-separated parts to run")
    ap.add_argument(
        "--policy", type=Path, default=None, help="exported policy.ts of the policy part (default: random)"
    )
    ap.add_argument(
        "--policy-episode-timeout-s",
        type=float,
        default=POLICY_EPISODE_TIMEOUT_S,
        help="sim-time limit of each policy episode",
    )
    ap.add_argument("--workdir", type=Path, default=None, help="keep the datasets here (default: a temp dir)")
    args = ap.parse_args(argv)
    if args.episodes < 1:
        ap.error(f"--episodes {args.episodes}: must be >= 1")
    if args.privileged_episodes < 1:
        ap.error(f"--privileged-episodes {args.privileged_episodes}: must be >= 1")
    work = args.workdir or Path(tempfile.mkdtemp(prefix="bench_engine_"))
    work.mkdir(parents=True, exist_ok=True)
    b = EngineBench(
        args.seeds, args.episodes, work, args.policy, args.policy_episode_timeout_s, args.privileged_episodes
    )
    bench("engine_bench_episodes", args.episodes, "episodes")
    failed = []
    t_all = time.monotonic()
    try:
        for part in args.parts:
            run: Callable[[], None] = getattr(b, f"part_{part}")
            print_load(f"before {part}")
            t0 = time.monotonic()
            try:
                run()
            except Exception:  # noqa: BLE001 - every other part still runs; the exit status says it failed
                log(f"part {part} failed:\n{traceback.format_exc()}")
                failed.append(part)
            log(f"part {part}: {time.monotonic() - t0:.1f} s")
        print_load("at the end")
    finally:
        if args.workdir is None:
            shutil.rmtree(work, ignore_errors=True)
    log(f"all parts: {time.monotonic() - t_all:.1f} s" + (f"; failed: {', '.join(failed)}" if failed else ""))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
