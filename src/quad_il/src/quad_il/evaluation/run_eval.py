"""`make eval`: the closed-loop evaluation (issue 8). The same held-out seeded worlds and start/goal pairs are
flown by each controller (expert, Python policy, C++ policy); then the Markdown report, plots and BENCH lines.

    python -m quad_il.evaluation.run_eval --policy runs/default/policy.ts
        [--set dev|dev_dense|test|test_dense] [--seeds 9000-9019 --episodes 20 --density 12.5]
        [--tier bare|safety|shield] [--force-new]
        [--controllers expert,py,cpp] [--out results/eval] [--sim-config config/sim.yaml]
        [--policy-config config/policy.yaml] [--episode-timeout-s 60]
        [--min-distance-m 20 --max-distance-m 30] [--snapshots 8,15] [--episode-mode relaunch|reset]
        [--setup-retries 1] [--report-only] [--backend engine|ros] [--workers 2]

Episodes come from an evaluation set of config/eval_sets.yaml (--set; development sets for choices, test
sets only to report) or from --seeds/--episodes/--density. The policy nodes fly one tier (--tier;
evaluation/tiers.py): `bare` the network alone, `safety` with the depth and limit refusals, `shield`
(default) with every hand-written behaviour of the node config. OUT/pin.json pins the policy, node config,
simulator config and commit: resuming into OUT with any of them different is an error naming it
(--force-new moves the old run aside).

--backend engine (the default) flies every episode in-process on the rollout engine
(quad_il.evaluation.engine_backend: the expert, and the exported policy through LibTorch and the C++ decider,
episodes deciding together in one batched forward pass, the policy's episodes dealt to --workers threads);
--backend ros flies them through ROS as follows.
Per controller on ROS: a private ROS master with `roslaunch quad_il infer.launch controller:=<c>` (simulator
in lockstep with the controller and the runner as depth consumers, tracker, controller), then `python -m
quad_il.evaluation.runner` flies every episode through the simulator's reset service; results are appended
to OUT/<controller>.jsonl (an interrupted run resumes after the last finished episode). A controller whose
node is not built is reported as unavailable. With
--snapshots, rviz snapshots (evaluation/snapshot.py) are taken at those sim times of each controller's run.
BENCH lines: eval_expert_{success,collision,timeout}_rate and eval_<py|cpp>_<tier>_{success,collision,
timeout}_rate (ratios in [0, 1]).
"""

from __future__ import annotations

import argparse
import copy
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import yaml

from quad_il.collection.episodes import StartGoalConfig, parse_seed_ranges
from quad_il.evaluation.episodes import (
    GROUND_Z_M,
    plan_eval_episodes,
    read_episodes,
    read_results,
    write_episodes,
)
from quad_il.evaluation.pin import RunPin, cpu_signature, differences, merge, read_pin, write_pin
from quad_il.evaluation.sets import EvalSetError, get_eval_set, world_density
from quad_il.evaluation.tiers import DEFAULT_TIER, TIERS, TierError, render_tier_config
from quad_il.tools.binaries import BinaryNotFound, find_binary
from quad_il.tools.cli import HelpFormatter
from quad_il.tools.ports import free_port
from quad_il.tools.provenance import git_commit, sha256_bytes, sha256_file
from quad_il.tools.repo import repo_root

ROOT = repo_root()
CONTROLLERS = ("expert", "py", "cpp")
# The policy nodes' config when none is given: the recovery at 10 Hz, the final approach and the plan kept
# (docs/inference.md, "Keeping the plan"; docs/RESULTS.md).
DEFAULT_POLICY_CONFIG = ROOT / "config" / "policy.yaml"
DEFAULT_SETS = ROOT / "config" / "eval_sets.yaml"
PLANNER_CONFIG = ROOT / "config" / "planner.yaml"  # the expert's (launch/planner.launch default)
DEFAULT_SEEDS, DEFAULT_EPISODES = "9000-9019", 20  # without --set
TIER_CONFIG = "policy_config.yaml"  # OUT/<this>: the tier's complete node config, what the policy nodes read
# The FrameAck consumer of each controller (config/policy.yaml lockstep_consumer; planner.launch's default).
CONSUMER = {"expert": "fast_planner", "py": "policy", "cpp": "policy"}
RUNNER_CONSUMER = "eval_runner"  # the episode runner's own FrameAck consumer name
NODE = {
    "expert": ("fast_planner", "fast_planner_node"),
    "py": ("quad_il", "policy_node.py"),
    "cpp": ("quad_policy", "policy_node"),
}


class EvalError(RuntimeError):
    """The evaluation cannot run; the message says why."""


def parse_seeds(text: str) -> list[int]:
    """'9000-9003,9010' -> [9000, 9001, 9002, 9003, 9010]."""
    try:
        return parse_seed_ranges(text)
    except ValueError as exc:
        raise EvalError(str(exc)) from None


def eval_sim_config(base_path: Path, controller: str, density: float | None) -> dict:
    """The simulator config of an evaluation run: the base config in lockstep with the controller and the
    episode runner as depth consumers (reproducible under any load), the box density if given, no episode
    time limit (the runner times out), collisions end the episode."""
    cfg = yaml.safe_load(base_path.read_text())
    cfg["vehicle_file"] = str((base_path.parent / cfg["vehicle_file"]).resolve())
    if cfg["world"].get("file"):
        cfg["world"]["file"] = str((base_path.parent / cfg["world"]["file"]).resolve())
    cfg["time"]["mode"] = "lockstep"
    cfg["lockstep"]["depth_consumers"] = [CONSUMER[controller], RUNNER_CONSUMER]
    cfg["lockstep"]["wait_for_command"] = True
    # Long enough for the runner to start beside a launch that is already stepping (it is a consumer).
    cfg["lockstep"]["timeout_s"] = 20.0
    cfg["episode"]["max_duration_s"] = 0.0
    cfg["collision"]["policy"] = "freeze"
    if density is not None:
        cfg["world"]["generator"]["density_boxes_per_100m2"] = float(density)
    return cfg


def node_available(controller: str) -> str:
    """'' if the controller's node is built, else why not."""
    try:
        find_binary(*NODE[controller])
    except BinaryNotFound as e:
        return str(e)
    return ""


def _stop_group(proc: subprocess.Popen, timeout_s: float = 20.0) -> None:
    """SIGINT to the process group we started (roslaunch and its children), then SIGKILL if needed."""
    if proc.poll() is not None:
        return
    os.killpg(proc.pid, signal.SIGINT)
    try:
        proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def _launch(
    args: argparse.Namespace, controller: str, out: Path, sim_cfg: Path, tag: str
) -> tuple[subprocess.Popen, dict[str, str]]:
    port = free_port()
    env = {**os.environ, "ROS_MASTER_URI": f"http://127.0.0.1:{port}", "ROS_HOME": str(out / "ros_home")}
    cmd = [
        "roslaunch",
        "-p",
        str(port),
        "quad_il",
        "infer.launch",
        f"controller:={controller}",
        f"sim_config:={sim_cfg}",
        "output:=log",
    ]
    if controller != "expert":
        cmd.append(f"policy:={Path(args.policy).resolve()}")
        cmd.append(f"policy_config:={out / TIER_CONFIG}")
    with open(out / "logs" / f"{controller}_{tag}_launch.log", "w") as log:
        proc = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    return proc, env


def _run_runner(
    args: argparse.Namespace,
    controller: str,
    out: Path,
    env: dict[str, str],
    episodes: Path,
    tag: str,
) -> None:
    """Runs quad_il.evaluation.runner on the launch at `env`: every episode starts with a keyed reset (issue
    32), so its stamps, id and flight are those of the engine's episode of the same key."""
    cmd = [
        sys.executable,
        "-m",
        "quad_il.evaluation.runner",
        "--episodes",
        str(episodes),
        "--controller",
        controller,
        "--out",
        str(out / f"{controller}.jsonl"),
        "--episode-timeout-s",
        str(args.episode_timeout_s),
        "--lockstep-consumer",
        RUNNER_CONSUMER,
        "--controller-consumer",
        CONSUMER[controller],
    ]
    log_path = out / "logs" / f"{controller}_{tag}_runner.log"
    with open(log_path, "w") as log:
        rc = subprocess.run(
            cmd, env=env, stdout=log, stderr=subprocess.STDOUT, timeout=args.wall_timeout_s
        ).returncode
    with open(log_path) as log:
        sys.stderr.write("".join(line for line in log if line.startswith("[eval")))
    if rc != 0:
        raise EvalError(f"the {controller} runner failed (exit {rc}); see {log_path}")


def _start_snapshots(
    args: argparse.Namespace, controller: str, out: Path, env: dict[str, str]
) -> subprocess.Popen | None:
    if not args.snapshots:
        return None
    label = "expert" if controller == "expert" else "learned"
    with open(out / "logs" / f"{controller}_snapshot.log", "w") as log:
        return subprocess.Popen(
            [
                sys.executable,
                "-m",
                "quad_il.evaluation.snapshot",
                "--out",
                str(out / "snapshots" / controller),
                "--times",
                args.snapshots,
                "--trajectory",
                f"planner/bspline:{label}",
                "--size",
                "960x600",
                "--timeout-s",
                str(max(600.0, 4 * args.episode_timeout_s)),
            ],
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )


def _finish_snapshots(snap: subprocess.Popen | None, controller: str) -> None:
    if snap is None:
        return
    try:
        snap.wait(120)
    except subprocess.TimeoutExpired:
        print(f"[eval] {controller}: snapshots not finished (times beyond the run?)", file=sys.stderr)
    _stop_group(snap)


def run_controller(args: argparse.Namespace, controller: str, out: Path, episodes_file: Path) -> str:
    """Flies the episodes not yet in OUT/<controller>.jsonl; returns '' or why the controller was skipped.

    Backend engine: quad_il.evaluation.engine_backend. Backend ros:

    Episode mode `relaunch` (default): one launch per episode whose simulator config holds the episode (seed,
    start, goal), so every episode starts from freshly started nodes. `reset`: one launch, the episodes
    through the simulator's reset service (kr_tracker re-anchors its reference on each new episode). In both
    the runner starts each episode with a keyed reset (its index: the engine's stamps and episode id).
    """
    if args.backend == "engine":
        from quad_il.evaluation import engine_backend

        return engine_backend.run_controller(
            controller,
            out,
            episodes_file,
            eval_sim_config(Path(args.sim_config), controller, args.density),
            args.episode_timeout_s,
            policy=args.policy,
            policy_config=out / TIER_CONFIG,
            workers=args.workers,
        )
    why = node_available(controller)
    if why:
        return why
    done = {r.index for r in read_results(out / f"{controller}.jsonl")}
    specs = [s for s in read_episodes(episodes_file) if s.index not in done]
    if not specs:
        return ""
    (out / "logs").mkdir(parents=True, exist_ok=True)
    base = eval_sim_config(Path(args.sim_config), controller, args.density)
    print(
        f"[eval] {controller}: {len(specs)} episode(s), mode {args.episode_mode}", file=sys.stderr, flush=True
    )
    if args.episode_mode == "reset":
        sim_cfg = out / f"sim_{controller}.yaml"
        sim_cfg.write_text(yaml.safe_dump(base))
        todo = out / f"{controller}_todo.json"
        write_episodes(todo, specs)
        launch, env = _launch(args, controller, out, sim_cfg, "all")
        snap = _start_snapshots(args, controller, out, env)
        try:
            _run_runner(args, controller, out, env, todo, "all")
            _finish_snapshots(snap, controller)
        finally:
            if snap is not None:
                _stop_group(snap)
            _stop_group(launch)
        return ""
    (out / f"sim_{controller}.yaml").write_text(yaml.safe_dump(base))  # the generator config (report)
    for n, spec in enumerate(specs):
        cfg = copy.deepcopy(base)
        cfg["world"]["file"] = ""
        cfg["world"]["seed"] = int(spec.seed)
        cfg["world"]["start_m"] = [spec.start_world[0], spec.start_world[1], GROUND_Z_M]
        cfg["world"]["start_yaw_deg"] = math.degrees(spec.start_yaw_rad)
        cfg["world"]["goal_m"] = list(spec.goal_world)
        tag = f"ep{spec.index:03d}"
        sim_cfg = out / "episodes" / f"sim_{controller}_{tag}.yaml"
        sim_cfg.parent.mkdir(parents=True, exist_ok=True)
        sim_cfg.write_text(yaml.safe_dump(cfg))
        todo = out / "episodes" / f"{controller}_{tag}.json"
        write_episodes(todo, [spec])
        for attempt in range(1 + args.setup_retries):
            log_tag = tag if attempt == 0 else f"{tag}_retry{attempt}"  # keeps the failed attempt's logs
            launch, env = _launch(args, controller, out, sim_cfg, log_tag)
            snap = _start_snapshots(args, controller, out, env) if n == 0 and attempt == 0 else None
            try:
                _run_runner(args, controller, out, env, todo, log_tag)
                _finish_snapshots(snap, controller)
                break
            except EvalError as e:
                # A runner that failed before recording the episode met a broken start-up (a node that did
                # not answer in wall time), not an outcome of the controller: start the episode afresh.
                recorded = any(r.index == spec.index for r in read_results(out / f"{controller}.jsonl"))
                if recorded or attempt == args.setup_retries:
                    raise
                print(
                    f"[eval] {controller} episode {spec.index}: {e}; relaunching it "
                    f"(attempt {attempt + 2} of {1 + args.setup_retries})",
                    file=sys.stderr,
                    flush=True,
                )
            finally:
                if snap is not None:
                    _stop_group(snap)
                _stop_group(launch)
    return ""


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(formatter_class=HelpFormatter, description=__doc__.split("\n\n")[0])
    ap.add_argument("--policy", default="", help="exported policy (policy.ts) for the py and cpp controllers")
    ap.add_argument(
        "--set",
        default="",
        help="an evaluation set of --sets-file (dev, dev_dense, dev_wide, test, test_dense): seeds, "
        "episodes, density",
    )
    ap.add_argument(
        "--sets-file", default=str(DEFAULT_SETS), help="the evaluation sets (config/eval_sets.yaml)"
    )
    ap.add_argument(
        "--seeds", default=None, help=f"world seeds, e.g. 9000-9019,9100 (without --set: {DEFAULT_SEEDS})"
    )
    ap.add_argument("--episodes", type=int, default=None, help=f"without --set: {DEFAULT_EPISODES}")
    ap.add_argument(
        "--density", type=float, default=None, help="boxes per 100 m^2 (default: the sim config's)"
    )
    ap.add_argument(
        "--tier",
        default=DEFAULT_TIER,
        choices=TIERS,
        help="bare: the network alone; safety: + depth and limit refusals; shield: the node config as it is",
    )
    ap.add_argument(
        "--force-new",
        action="store_true",
        help="OUT holds a run flown with something else: move it aside (OUT.old-<time>) and start over",
    )
    ap.add_argument(
        "--controllers",
        default=None,
        help="comma-separated controllers flown (default: expert,cpp on the engine, expert,py,cpp on ros)",
    )
    ap.add_argument("--out", default=str(ROOT / "results" / "eval"), help="output directory")
    ap.add_argument("--sim-config", default=str(ROOT / "config" / "sim.yaml"), help="simulator config")
    ap.add_argument(
        "--policy-config",
        default=str(DEFAULT_POLICY_CONFIG),
        help="policy node config the tier applies to",
    )
    ap.add_argument("--episode-timeout-s", type=float, default=60.0, help="sim time per episode")
    ap.add_argument("--wall-timeout-s", type=float, default=7200.0, help="wall time per controller")
    ap.add_argument(
        "--setup-retries",
        type=int,
        default=1,
        help="relaunch mode: times an episode is started afresh when its nodes fail to start up",
    )
    ap.add_argument("--min-distance-m", type=float, default=20.0, help="least start-goal distance")
    ap.add_argument("--max-distance-m", type=float, default=30.0, help="largest start-goal distance")
    ap.add_argument(
        "--snapshots", default="", help="comma-separated sim times of rviz snapshots per controller"
    )
    ap.add_argument(
        "--episode-mode",
        choices=["relaunch", "reset"],
        default="relaunch",
        help="relaunch: nodes started afresh per episode; reset: one launch, the simulator's reset service",
    )
    ap.add_argument(
        "--report-only", action="store_true", help="only (re)write the report of existing results"
    )
    ap.add_argument(
        "--backend",
        choices=["engine", "ros"],
        default="engine",
        help="engine: in-process (quad_il.evaluation.engine_backend); ros: the nodes through roslaunch",
    )
    ap.add_argument(
        "--workers",
        type=int,
        default=2,
        help="engine backend: threads flying the policy's episodes (results do not depend on it)",
    )
    args = ap.parse_args(argv)
    if args.workers < 1:
        ap.error(f"--workers {args.workers}: must be >= 1")
    from quad_il.evaluation.report import write_report

    # SIGTERM unwinds like Ctrl-C: the finally blocks stop the launches we started (in their own sessions).
    def _on_sigterm(signum: int, frame: object) -> None:
        raise KeyboardInterrupt(f"signal {signum}")

    previous = signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        return _run(args, write_report)
    finally:
        signal.signal(signal.SIGTERM, previous)


def resolve_episodes(args: argparse.Namespace, sim_base: dict) -> None:
    """Sets args.seeds, args.episodes and args.density from --set or the defaults; EvalError on a conflict."""
    if args.set:
        given = [f"--{k}" for k in ("seeds", "episodes", "density") if getattr(args, k) is not None]
        if given:
            raise EvalError(
                f"--set {args.set} fixes the seeds, episodes and density; do not also give {', '.join(given)}"
            )
        try:
            eval_set = get_eval_set(args.sets_file, args.set)
        except EvalSetError as e:
            raise EvalError(str(e)) from None
        args.seeds, args.episodes = eval_set.seeds, eval_set.episodes
        args.density = world_density(eval_set, sim_base)
        return
    args.seeds = DEFAULT_SEEDS if args.seeds is None else args.seeds
    args.episodes = DEFAULT_EPISODES if args.episodes is None else args.episodes


def make_pin(args: argparse.Namespace, policy_controllers: bool, tier_text: str) -> RunPin:
    sim = Path(args.sim_config)
    vehicle = (sim.parent / yaml.safe_load(sim.read_text())["vehicle_file"]).resolve()
    commit = git_commit(ROOT)
    return RunPin(
        tier=args.tier if policy_controllers else "",
        eval_set=args.set,
        policy_sha256=sha256_file(args.policy) if policy_controllers else "",
        policy_path=str(Path(args.policy).resolve()) if policy_controllers else "",
        policy_config_sha256=sha256_bytes(tier_text.encode()) if policy_controllers else "",
        policy_config_base=str(Path(args.policy_config).resolve()) if policy_controllers else "",
        sim_config_sha256=sha256_file(sim),
        sim_config_path=str(sim.resolve()),
        vehicle_sha256=sha256_file(vehicle),
        planner_config_sha256=sha256_file(PLANNER_CONFIG),
        density=args.density,
        commit=commit["commit"],
        dirty=commit["dirty"],
        backend=args.backend,
        cpu=cpu_signature(),
    )


def move_aside(out: Path) -> Path:
    """Renames OUT to OUT.old-<UTC time> (nothing is deleted) and returns the new name."""
    stamp = time.strftime("%Y%m%d-%H%M%S", time.gmtime())
    dest = out.with_name(f"{out.name}.old-{stamp}")
    n = 1
    while dest.exists():
        dest = out.with_name(f"{out.name}.old-{stamp}-{n}")
        n += 1
    out.rename(dest)
    return dest


def pin_run(out: Path, pin: RunPin, force_new: bool) -> RunPin:
    """Checks OUT's pin against this invocation's (or moves the old run aside with force_new); writes it."""
    old = read_pin(out)
    if old is None and any(out.glob("*.jsonl")):
        if not force_new:
            raise EvalError(
                f"{out} holds results without a pin (made before runs were pinned): their policy and "
                "configs are unknown; use --force-new (moves them aside) or another --out"
            )
    if old is not None:
        flown = any(read_results(out / f"{c}.jsonl") for c in ("py", "cpp"))
        diffs = differences(old, pin, flown)
        if diffs and not force_new:
            raise EvalError(
                f"{out} was flown with something else, so its results cannot be resumed: "
                + "; ".join(diffs)
                + ". Use --force-new (moves the old run aside) or another --out"
            )
        if not diffs and not force_new:
            pin = merge(old, pin)
    if force_new and (old is not None or any(out.iterdir())):
        print(f"[eval] --force-new: the earlier run moved to {move_aside(out)}", file=sys.stderr)
        out.mkdir(parents=True)
    write_pin(out, pin)
    return pin


def _run(args: argparse.Namespace, write_report: Callable[..., Path]) -> int:
    try:
        if args.controllers is None:
            args.controllers = "expert,cpp" if args.backend == "engine" else ",".join(CONTROLLERS)
        controllers = [c.strip() for c in args.controllers.split(",") if c.strip()]
        bad = [c for c in controllers if c not in CONTROLLERS]
        if bad:
            raise EvalError(f"unknown controller(s) {bad} (choose from {', '.join(CONTROLLERS)})")
        if args.setup_retries < 0:
            raise EvalError(f"--setup-retries must be >= 0, got {args.setup_retries}")
        if not Path(args.sim_config).is_file():
            raise EvalError(f"--sim-config: no such file {args.sim_config!r}")
        sim_base = yaml.safe_load(Path(args.sim_config).read_text())
        resolve_episodes(args, sim_base)
        policy_controllers = any(c != "expert" for c in controllers)
        args.policy_config = args.policy_config or str(DEFAULT_POLICY_CONFIG)
        tier_text = ""
        if policy_controllers and not args.report_only:
            if not args.policy or not Path(args.policy).is_file():
                raise EvalError(f"--policy must name an exported policy file, got {args.policy!r}")
            if not Path(args.policy_config).is_file():
                raise EvalError(f"--policy-config: no such file {args.policy_config!r}")
            # Checked here with the nodes' own strict schema: a node that dies on its config at launch
            # would otherwise show only as "no depth frame" after the runner's 30 s wait.
            try:
                tier_text = render_tier_config(args.policy_config, args.tier)
            except TierError as e:
                raise EvalError(f"--policy-config: {e}") from None
        out = Path(args.out).resolve()  # the nodes run in ROS_HOME: every path handed to them is absolute
        out.mkdir(parents=True, exist_ok=True)
        if args.report_only:
            pin = read_pin(out)
        else:
            pin = pin_run(out, make_pin(args, policy_controllers, tier_text), args.force_new)
            if tier_text:
                (out / TIER_CONFIG).write_text(tier_text)
        gen = sim_base["world"]["generator"]
        start_goal = StartGoalConfig(
            bounds_min_xy_m=tuple(gen["bounds_min_m"][:2]),
            bounds_max_xy_m=tuple(gen["bounds_max_m"][:2]),
            min_distance_m=args.min_distance_m,
            max_distance_m=args.max_distance_m,
        )
        episodes_file = out / "episodes.json"
        specs = plan_eval_episodes(parse_seeds(args.seeds), args.episodes, start_goal)
        if episodes_file.is_file() and read_episodes(episodes_file) != specs:
            raise EvalError(f"{episodes_file} holds other episodes: choose another --out or use --force-new")
        write_episodes(episodes_file, specs)
        skipped: dict[str, str] = {}
        if not args.report_only:
            for c in controllers:
                why = run_controller(args, c, out, episodes_file)
                if why:
                    print(f"[eval] {c}: skipped: {why}", file=sys.stderr)
                    skipped[c] = why
        report = write_report(out, controllers, specs, skipped, vars(args), pin)
    except (EvalError, OSError, ValueError, subprocess.TimeoutExpired) as e:
        print(f"eval: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("eval: interrupted; the launches were stopped", file=sys.stderr)
        return 130
    print(f"[eval] report: {report}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
