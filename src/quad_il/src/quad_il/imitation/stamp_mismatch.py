"""Observation/action timestamp mismatch of the Python collector vs the C++ collector (thesis section 4,
figures 4.4/4.5), at idle and with the CPU loaded.

    python -m quad_il.imitation.stamp_mismatch run --out DIR [--episodes 2] [--episode-timeout-s 15]
        [--load-procs 3] [--port 11571]
    python -m quad_il.imitation.stamp_mismatch report --out DIR
    python -m quad_il.imitation.stamp_mismatch train-compare --out DIR [--conditions idle] [--epochs 5]

`run` flies, for each condition (idle; loaded = --load-procs busy-loop processes started and killed by PID),
one real-time simulation (not lockstep: the timing then depends on the machine, as on a robot) with the expert
in labeller mode flying through the Python collector (BC: every frame planned, labelled and flown), both
collectors recording the same plans:

- the C++ collector embedded in fast_planner records each plan with the depth frame's stamp and the stamp of
  the odometry the plan started from (the newest in the planner's queue not after the frame);
- the Python collector (rospy, imitation_collector.py) records, per frame it pairs, the odometry it attached
  to the observation (the newest received not after the frame, waiting for it up to ~odom_wait_s) and, in its
  timing log, the newest odometry it had received at that moment: what a collector that takes "the latest
  message" of each topic (the thesis's Python collector) would have paired.

mismatch = depth stamp - odometry stamp (ms; negative: the odometry is newer than the image). `report` writes
DIR/stamp_mismatch.md (a table per condition and collector: records, median, p90, p99 and max of |mismatch|,
share above one odometry period) and DIR/stamp_mismatch.png (histograms), and prints BENCH-style lines.

`train-compare` (the second half of the thesis's comparison) trains the same network on an equal number of
records from each collector (the same flights; the episode of the last flown world held out), then evaluates
both policies on the held-out episode as recorded by each collector (quad_il.learning.evaluation),
writing DIR/<condition>/train_compare.md.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from quad_il.tools.cli import HelpFormatter
from quad_il.tools.repo import repo_path

ODOM_PERIOD_MS = 5.0

LAUNCH = """<launch>
  <include file="$(find quad_il)/launch/il_sim.launch">
    <arg name="work_dir" value="{work}/sim" />
    <arg name="seeds" value="1,2,3" />
    <arg name="episodes" value="{episodes}" />
    <arg name="learner" value="false" />
    <arg name="time_mode" value="realtime" />
    <arg name="episode_timeout_s" value="{timeout}" />
  </include>
  <include file="$(find quad_il)/launch/il_expert.launch">
    <arg name="output" value="log" />
    <arg name="collector_output_dir" value="{work}/cpp" />
  </include>
  <node pkg="quad_il" type="imitation_collector.py" name="imitation_collector" output="screen"
        required="true">
    <param name="round_config" value="{work}/algorithm.yaml" />
    <param name="output_dir" value="{work}/py" />
    <param name="episodes" value="{episodes}" />
    <param name="timing_log" value="{work}/py_timing.csv" />
  </node>
</launch>
"""


def busy_loop() -> None:  # pragma: no cover - a load generator
    while True:
        pass


def run_condition(out: Path, name: str, args: argparse.Namespace, load_procs: int) -> None:
    work = out / name
    if (work / "py" / "collector_manifest.json").is_file():
        print(f"[mismatch] {name}: already done", file=sys.stderr)
        return
    work.mkdir(parents=True, exist_ok=True)
    for sub in ("cpp", "py", "sim"):
        p = work / sub
        if p.exists():
            subprocess.run(["rm", "-rf", str(p)], check=True)
    (work / "algorithm.yaml").write_text(
        "algorithm: {name: bc}\nround_index: 0\nseed: 0\nexpert_only: true\n"
    )
    launch = work / "mismatch.launch"
    launch.write_text(LAUNCH.format(work=work, episodes=args.episodes, timeout=args.episode_timeout_s))
    env = dict(os.environ, ROS_MASTER_URI=f"http://localhost:{args.port}", ROS_LOG_DIR=str(work / "roslog"))
    loads = [
        subprocess.Popen([sys.executable, "-c", "while True: pass"], start_new_session=True)
        for _ in range(load_procs)
    ]
    log = open(work / "roslaunch.log", "w")  # noqa: SIM115
    t0 = time.monotonic()
    rl = subprocess.Popen(
        ["roslaunch", "-p", str(args.port), str(launch)],
        env=env,
        stdout=log,
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )
    try:
        deadline = t0 + args.wall_timeout_s
        while rl.poll() is None and time.monotonic() < deadline:
            time.sleep(1.0)
    finally:
        if rl.poll() is None:
            os.killpg(rl.pid, signal.SIGINT)
            try:
                rl.wait(30)
            except subprocess.TimeoutExpired:
                os.killpg(rl.pid, signal.SIGKILL)
                rl.wait()
        for p in loads:
            p.kill()
            p.wait()
        log.close()
    print(
        f"[mismatch] {name}: {time.monotonic() - t0:.0f} s wall, {load_procs} load processes", file=sys.stderr
    )


def cpp_mismatch_ms(d: Path) -> np.ndarray:
    from quad_il.data.shards import open_dataset

    ds = open_dataset(d)
    parts = [
        (recs["depth_stamp_s"] - recs["odom_stamp_s"]) * 1e3
        for _, recs, _ in ds.valid_record_arrays(on_corrupt="skip")
    ]
    return np.concatenate(parts) if parts else np.zeros(0)


def py_mismatch_ms(work: Path) -> tuple[np.ndarray, np.ndarray]:
    """(attached odometry, newest received odometry) mismatches of the frames the Python collector paired."""
    from quad_il.imitation.dataset import read_round

    data = read_round(work / "py")
    paired = set() if data is None else {round(t * 1e9) for t in data.records["depth_stamp_s"].tolist()}
    used, latest = [], []
    with open(work / "py_timing.csv") as fh:
        for row in csv.DictReader(fh):
            t = float(row["depth_stamp_s"])
            if round(t * 1e9) not in paired:
                continue
            used.append((t - float(row["odom_used_stamp_s"])) * 1e3)
            latest.append((t - float(row["odom_latest_stamp_s"])) * 1e3)
    return np.array(used), np.array(latest)


def summarise(x: np.ndarray) -> dict[str, float]:
    a = np.abs(x)
    if a.size == 0:
        return {"n": 0}
    return {
        "n": int(a.size),
        "median_ms": float(np.median(a)),
        "p90_ms": float(np.percentile(a, 90)),
        "p99_ms": float(np.percentile(a, 99)),
        "max_ms": float(a.max()),
        "over_period": float(np.mean(a > ODOM_PERIOD_MS + 1e-6)),
        "negative": float(np.mean(x < -1e-6)),
    }


def report(out: Path) -> int:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    conds = [c for c in ("idle", "loaded") if (out / c / "py").is_dir()]
    if not conds:
        print(f"[mismatch] nothing measured in {out}", file=sys.stderr)
        return 1
    table: dict[str, dict[str, dict[str, float]]] = {}
    fig, axes = plt.subplots(1, len(conds), figsize=(6 * len(conds), 4), squeeze=False)
    for ax, c in zip(axes[0], conds, strict=True):
        work = out / c
        series = {"C++ collector": cpp_mismatch_ms(work / "cpp")}
        used, latest = py_mismatch_ms(work)
        series["Python collector (waits for the frame's odometry)"] = used
        series["Python, latest odometry received (naive)"] = latest
        table[c] = {k: summarise(v) for k, v in series.items()}
        allv = np.concatenate([v for v in series.values() if v.size])
        lo, hi = min(-1.0, float(allv.min())), max(10.0, float(allv.max()))
        bins = np.linspace(lo, hi, 60)
        for k, v in series.items():
            if v.size:
                ax.hist(v, bins=bins, alpha=0.5, label=f"{k} (n={v.size})")
        ax.set_yscale("log")
        ax.set_title(f"{c}: depth stamp - odometry stamp")
        ax.set_xlabel("ms")
        ax.set_ylabel("records")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "stamp_mismatch.png", dpi=120)
    lines = [
        "# Observation/action timestamp mismatch: Python vs C++ collector",
        "",
        "mismatch = depth stamp - odometry stamp of the state recorded with the label; |.| statistics in ms;",
        f"'> period': share above one odometry period ({ODOM_PERIOD_MS:g} ms); "
        "'neg': odometry newer than the image.",
        "",
        "| condition | collector | records | median | p90 | p99 | max | > period | neg |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for c, rows in table.items():
        for k, s in rows.items():
            if not s.get("n"):
                lines.append(f"| {c} | {k} | 0 | | | | | | |")
                continue
            lines.append(
                f"| {c} | {k} | {s['n']} | {s['median_ms']:.2f} | {s['p90_ms']:.2f} | {s['p99_ms']:.2f} | "
                f"{s['max_ms']:.2f} | {100 * s['over_period']:.1f} % | {100 * s['negative']:.1f} % |"
            )
    (out / "stamp_mismatch.md").write_text("\n".join(lines) + "\n")
    (out / "stamp_mismatch.json").write_text(json.dumps(table, indent=2))
    print("\n".join(lines))
    return 0


def train_compare(out: Path, cond: str, epochs: int, size: int) -> None:
    from quad_il.data.postprocess import NPZ_ARRAYS, FixedSizeArrays
    from quad_il.imitation.convert import select_records, shard_records_to_npz_arrays
    from quad_il.learning.dataset import shard_dir_arrays

    work = out / cond
    cmp_dir = work / "compare"
    cmp_dir.mkdir(exist_ok=True)
    cpp = shard_dir_arrays(work / "cpp")
    cpp_fixed = FixedSizeArrays(
        **{k: cpp[k] for k in NPZ_ARRAYS},
        num_ctrl_pts=int(cpp["num_ctrl_pts"]),
        horizon_s=float(cpp["horizon_s"]),
        format_version=int(cpp["format_version"]),
    )
    records, rounds, _ = select_records([work / "py"])
    py = shard_records_to_npz_arrays(records, rounds)
    py = dataclasses.replace(py, world_seed=np.asarray(records["world_seed"], dtype=np.uint64))
    held = int(max(set(py.episode_id.tolist()) & set(cpp_fixed.episode_id.tolist())))
    rng = np.random.default_rng(0)

    def subset(a: FixedSizeArrays, mask: np.ndarray) -> FixedSizeArrays:
        idx = np.flatnonzero(mask)
        return dataclasses.replace(a, **{k: getattr(a, k)[idx] for k in NPZ_ARRAYS})

    train = {"cpp": subset(cpp_fixed, cpp_fixed.episode_id != held), "py": subset(py, py.episode_id != held)}
    n = min(len(t) for t in train.values())
    if size:
        n = min(n, size)
    files = {}
    for name, arr in train.items():
        pick = np.zeros(len(arr), dtype=bool)
        pick[rng.choice(len(arr), n, replace=False)] = True
        files[name] = subset(arr, pick).save(cmp_dir / f"train_{name}.npz")
    heldout = {
        "cpp": subset(cpp_fixed, cpp_fixed.episode_id == held).save(cmp_dir / "heldout_cpp.npz"),
        "py": subset(py, py.episode_id == held).save(cmp_dir / "heldout_py.npz"),
    }
    # In this process, through the functions the two training_only/ commands call (issue 31).
    from quad_il.learning.evaluation import evaluate
    from quad_il.learning.train import train

    rows = []
    for name, f in files.items():
        run = cmp_dir / f"run_{name}"
        if not (run / "policy.ts").is_file():
            train(
                [repo_path("config", "train.yaml")],
                [
                    "data.paths=[" + repr(str(Path(f).resolve())) + "]",
                    f"optim.epochs={epochs}",
                    "model.input_height=32",
                    "model.input_width=32",
                    "run.num_threads=2",
                    "data.num_workers=0",
                    f"run.out_dir={str(cmp_dir)!r}",
                    f"run.name={'run_' + name!r}",
                ],
            )
        summary = json.loads((run / "summary.json").read_text())
        for hname, h in heldout.items():
            ev = cmp_dir / f"eval_{name}_on_{hname}"
            evaluate(run / "policy.ts", [h], ev)
            js = json.loads((ev / "summary.json").read_text())
            rows.append((name, hname, summary, js))
    lines = [
        f"# Training on equal-size datasets of the two collectors ({cond})",
        "",
        f"{n} training records each (the same flights), {epochs} epochs, 32 x 32 input; "
        f"held-out episode {held}.",
        "",
        "| trained on | evaluated on | best val. loss (own split) | held-out MSE (m^2, 95 % CI) | cosine |",
        "|---|---|---|---|---|",
    ]
    for name, hname, summary, js in rows:
        m = js["metrics"]
        lines.append(
            f"| {name} | {hname} | {summary['best_val_loss']:.2f} | {m['mse_world']['mean']:.2f} "
            f"+- {m['mse_world']['ci95_half_width']:.2f} | {m['cosine_world']['mean']:.3f} |"
        )
    (work / "train_compare.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        formatter_class=HelpFormatter,
        prog="quad_il.imitation.stamp_mismatch",
        description=__doc__.splitlines()[0],
    )
    ap.add_argument("cmd", choices=["run", "report", "train-compare"], help="what to do (see above)")
    ap.add_argument("--epochs", type=int, default=5, help="train-compare: training epochs")
    ap.add_argument(
        "--size", type=int, default=0, help="training records per collector (0: as many as both have)"
    )
    ap.add_argument("--out", required=True, help="work directory")
    ap.add_argument("--episodes", type=int, default=2, help="run: episodes per condition")
    ap.add_argument("--episode-timeout-s", type=float, default=15.0, help="run: sim time per episode")
    ap.add_argument(
        "--load-procs", type=int, default=3, help="run: busy-loop processes of the loaded condition"
    )
    ap.add_argument("--port", type=int, default=11571, help="run: ROS master port")
    ap.add_argument("--wall-timeout-s", type=float, default=300.0, help="run: wall time per condition")
    ap.add_argument("--conditions", default="idle,loaded", help="comma-separated conditions")
    args = ap.parse_args(argv)
    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    if args.cmd == "run":
        for c in args.conditions.split(","):
            run_condition(out, c, args, args.load_procs if c == "loaded" else 0)
    if args.cmd == "train-compare":
        for c in args.conditions.split(","):
            train_compare(out, c, args.epochs, args.size)
        return 0
    return report(out)


if __name__ == "__main__":
    sys.exit(main())
