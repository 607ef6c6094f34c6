"""Launch-time preparation of a collection run (`roslaunch quad_il collect.launch`).

collect.launch evaluates these commands while it parses (`<param command=...>`), before any node starts, so a
bad argument stops the launch with a clear message and nothing is overwritten:

    python -m quad_il.collection.prepare output-dir DIR [--resume] [--run KEY=VALUE ...]
        checks DIR (it must not hold a dataset, unless --resume), creates it and prints its absolute path;
        --run gives the run's identity (launch arguments and config paths: quad_il.collection.resume), written
        to DIR/collect_run.yaml; with --resume, DIR is made ready to continue the run it holds (the
        unfinished episode's records cut, a killed writer's dataset recovered; quad_il.collection.resume);
    python -m quad_il.collection.prepare sim-config DIR --base sim.yaml --time-mode M [--factor F]
        --consumers a,b [--lockstep-timeout-s T]
        writes DIR/sim_config.yaml (the base simulator config with the run's time mode and lockstep consumers,
        every relative path made absolute) and prints its path;
    python -m quad_il.collection.prepare commit
        prints `git rev-parse HEAD` of the repository (with "-dirty" if tracked files changed), or "unknown".

Relative DIRs are taken relative to the repository root (QUAD_IL_ROOT, else this file's repository), not to
the current directory (roslaunch and its nodes run in different directories).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

import yaml

from quad_il.tools.cli import HelpFormatter
from quad_il.tools.repo import repo_root

TIME_MODES = {
    "lockstep": "lockstep",
    "realtime": "real_time",
    "factor": "factor",
}
SIM_CONFIG_NAME = "sim_config.yaml"


class PrepareError(ValueError):
    """A bad argument of collect.launch; the message names it."""


def resolve_output_dir(text: str, root: Path | None = None) -> Path:
    if not text or not text.strip():
        raise PrepareError("output_dir is empty: pass output_dir:=DIR")
    p = Path(text.strip()).expanduser()
    if not p.is_absolute():
        p = (root or repo_root()) / p
    return p.resolve()


def dataset_files(d: Path) -> list[str]:
    """Files in d that belong to a dataset (the writer refuses such a directory)."""
    if not d.is_dir():
        return []
    names = sorted(
        n.name
        for n in d.iterdir()
        if n.name in ("manifest.yaml", "episodes.csv") or n.name.startswith("shard_")
    )
    return names


def prepare_output_dir(
    text: str,
    root: Path | None = None,
    resume: bool = False,
    run_args: dict[str, str] | None = None,
    tool: str = "collect.launch",
) -> Path:
    """Checks and creates the output directory. run_args (the launch arguments of
    quad_il.collection.resume.run_identity) are recorded in DIR/collect_run.yaml; resume: DIR may hold the
    run to continue, which is made ready for it when run_args are given (collect.launch gives them in one
    of its calls). tool names the command in the resume's messages on stderr."""
    d = resolve_output_dir(text, root)
    if d.exists() and not d.is_dir():
        raise PrepareError(f"output_dir {d} exists and is not a directory")
    existing = dataset_files(d)
    if existing and not resume:
        raise PrepareError(
            f"output_dir {d} already holds a dataset ({', '.join(existing[:3])}"
            f"{', ...' if len(existing) > 3 else ''}); collect.launch never overwrites one: "
            "pass another output_dir:=DIR, remove it, or resume:=true to complete the run it holds"
        )
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise PrepareError(f"output_dir {d} cannot be created: {exc.strerror}") from None
    if not os.access(d, os.W_OK):
        raise PrepareError(f"output_dir {d} is not writable")
    if run_args is not None:
        from quad_il.collection import resume as resuming

        try:
            identity = resuming.run_identity(run_args)
            if resume:
                plan = resuming.plan_resume(d, identity, collect_params(run_args))
                for action in plan.actions:
                    print(f"{tool}: resume: {action}", file=sys.stderr)
            else:
                resuming.write_run_file(d, identity)
        except ValueError as exc:  # ResumeError, and bad seeds / config values
            raise PrepareError(str(exc)) from None
    return d


def collect_params(run_args: dict[str, str]) -> dict[str, object]:
    """The episode manager's parameters (episodes.manager_config) from the launch arguments."""
    return {
        "config": run_args["collect_config"],
        "seeds": run_args["seeds"],
        "episodes": run_args["episodes"],
        "max_samples": run_args["max_samples"],
        "episode_timeout_s": run_args["episode_timeout_s"],
    }


def parse_bool(name: str, text: str) -> bool:
    v = str(text).strip().lower()
    if v not in ("true", "false", "1", "0"):
        raise PrepareError(f"{name} '{text}' is not true or false")
    return v in ("true", "1")


def parse_run_args(items: list[str]) -> dict[str, str] | None:
    if not items:
        return None
    out = {}
    for item in items:
        if "=" not in item:
            raise PrepareError(f"--run '{item}': expected KEY=VALUE")
        k, v = item.split("=", 1)
        out[k] = v
    return out


def _absolute(path_text: str, base_dir: Path) -> str:
    if not path_text:
        return path_text
    p = Path(path_text)
    return str(p if p.is_absolute() else (base_dir / p).resolve())


def make_sim_config(
    out_dir: Path,
    base: Path,
    time_mode: str,
    factor: float = 1.0,
    consumers: list[str] | None = None,
    lockstep_timeout_s: float = 20.0,
) -> Path:
    """Writes out_dir/sim_config.yaml: `base` with the run's time mode; returns its path."""
    if time_mode not in TIME_MODES:
        raise PrepareError(f"time_mode '{time_mode}' is not one of {', '.join(TIME_MODES)}")
    if not factor > 0:
        raise PrepareError(f"time_factor {factor} must be > 0")
    if not lockstep_timeout_s > 0:
        raise PrepareError(f"lockstep_timeout_s {lockstep_timeout_s} must be > 0")
    if not base.is_file():
        raise PrepareError(f"sim_config {base} not found")
    cfg = yaml.safe_load(base.read_text())
    if not isinstance(cfg, dict) or "time" not in cfg or "lockstep" not in cfg:
        raise PrepareError(f"sim_config {base} is not a quad_sim config (no time/lockstep sections)")
    base_dir = base.resolve().parent
    cfg["vehicle_file"] = _absolute(cfg.get("vehicle_file", ""), base_dir)
    world = cfg.get("world", {})
    if isinstance(world, dict) and world.get("file"):
        world["file"] = _absolute(world["file"], base_dir)
    vm = cfg.get("voxel_map", {})
    if isinstance(vm, dict) and vm.get("octomap_file"):
        vm["octomap_file"] = _absolute(vm["octomap_file"], base_dir)
    cfg["time"]["mode"] = TIME_MODES[time_mode]
    cfg["time"]["real_time_factor"] = float(factor) if time_mode == "factor" else 1.0
    lockstep = time_mode == "lockstep"
    cfg["lockstep"]["depth_consumers"] = list(consumers or []) if lockstep else []
    cfg["lockstep"]["wait_for_command"] = lockstep
    cfg["lockstep"]["timeout_s"] = float(lockstep_timeout_s)
    out = out_dir / SIM_CONFIG_NAME
    header = (
        f"# Written by quad_il.collection.prepare for this collection run from {base.resolve()}\n"
        f"# (time mode {time_mode}); the simulator of collect.launch loads it.\n"
    )
    out.write_text(header + yaml.safe_dump(cfg, sort_keys=False))
    return out


def software_commit(root: Path | None = None) -> str:
    r = root or repo_root()
    try:
        head = subprocess.run(
            ["git", "-C", str(r), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10
        )
        if head.returncode != 0:
            return "unknown"
        dirty = subprocess.run(
            ["git", "-C", str(r), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=20,
        )
        return head.stdout.strip() + ("-dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.TimeoutExpired):
        return "unknown"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        formatter_class=HelpFormatter, prog="quad_il.collection.prepare", description=__doc__.splitlines()[0]
    )
    sub = ap.add_subparsers(dest="cmd", required=True)
    a = sub.add_parser("output-dir", formatter_class=HelpFormatter)
    a.add_argument("dir", help="output_dir as given to collect.launch")
    a.add_argument("--resume", default="false", help="true: continue the run DIR holds")
    a.add_argument("--run", action="append", default=[], metavar="KEY=VALUE", help="the run's identity")
    b = sub.add_parser("sim-config", formatter_class=HelpFormatter)
    b.add_argument("dir", help="the run's output directory")
    b.add_argument("--base", required=True, help="simulator config the run starts from")
    b.add_argument("--time-mode", required=True, help="one of " + ", ".join(TIME_MODES))
    b.add_argument("--factor", type=float, default=1.0, help="real-time factor of time mode 'factor'")
    b.add_argument("--consumers", default="", help="comma-separated lockstep depth consumers")
    b.add_argument("--lockstep-timeout-s", type=float, default=20.0, help="lockstep wait timeout (s)")
    b.add_argument("--resume", default="false", help="true: DIR may hold the run being resumed")
    sub.add_parser("commit", formatter_class=HelpFormatter)
    args = ap.parse_args(argv)
    try:
        if args.cmd == "output-dir":
            out = str(
                prepare_output_dir(
                    args.dir, resume=parse_bool("resume", args.resume), run_args=parse_run_args(args.run)
                )
            )
        elif args.cmd == "sim-config":
            d = prepare_output_dir(args.dir, resume=parse_bool("resume", args.resume))
            consumers = [c for c in args.consumers.replace(",", " ").split() if c]
            out = str(
                make_sim_config(
                    d, Path(args.base), args.time_mode, args.factor, consumers, args.lockstep_timeout_s
                )
            )
        else:
            out = software_commit()
    except PrepareError as exc:
        print(f"collect.launch: error: {exc}", file=sys.stderr)
        return 1
    # No newline: roslaunch uses the output as the parameter's value.
    sys.stdout.write(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
