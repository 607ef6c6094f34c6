"""Benchmark of a real collection run (scripts/bench/collector.sh, after quad_il.data.bench).

Runs `roslaunch quad_il collect.launch` in lockstep as fast as possible (default: seeds 1,2, 2 episodes of
config/collect.yaml) into a temporary directory and prints
  collector_rtf               sim seconds per wall second while the episode manager runs (resets, tracker
                              restarts and take-offs included; process start-up excluded)
  collector_records_per_s     records written per wall second over the same span
  collector_max_stamp_gap_ms  max |odometry stamp - depth stamp| over every record
as `BENCH <name> <value> <unit>` lines; progress and the whole run's numbers on stderr.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path

import yaml

from quad_il.collection.compare import dataset_records, stamp_gaps_s
from quad_il.collection.launch_run import run_collect
from quad_il.tools.bench_check import format_bench_line
from quad_il.tools.cli import HelpFormatter


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(formatter_class=HelpFormatter, description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="1,2", help="world seeds")
    ap.add_argument("--episodes", type=int, default=2, help="episodes flown")
    ap.add_argument("--timeout-s", type=float, default=400.0, help="wall-time limit of the run")
    ap.add_argument("--workdir", type=Path, default=None, help="keep the dataset here (default: a temp dir)")
    args = ap.parse_args(argv)

    work = args.workdir or Path(tempfile.mkdtemp(prefix="bench_collect_"))
    work.mkdir(parents=True, exist_ok=True)
    out = work / "dataset"
    try:
        print(
            f"[bench collector] collect.launch lockstep: seeds {args.seeds}, {args.episodes} episodes "
            f"-> {out}",
            file=sys.stderr,
        )
        run = run_collect(
            out,
            work / "collect.log",
            timeout_s=args.timeout_s,
            seeds=args.seeds,
            episodes=args.episodes,
            time_mode="lockstep",
            output="log",
        )
        summary_path = out / "collect_summary.yaml"
        if not summary_path.is_file() or "status: complete" not in (out / "manifest.yaml").read_text():
            tail = "\n".join(run.log.splitlines()[-30:])
            print(f"[bench collector] the collection run failed:\n{tail}", file=sys.stderr)
            return 1
        summary = yaml.safe_load(summary_path.read_text())
        recs = dataset_records(out)
        gaps = stamp_gaps_s(recs)
        wall = float(summary["wall_s"])
        size_mb = sum(p.stat().st_size for p in out.glob("shard_*")) / 1e6
        for line in run.log.splitlines():
            if line.startswith("[collect]"):
                print(f"[bench collector] {line}", file=sys.stderr)
        print(
            f"[bench collector] {len(recs)} records ({size_mb:.1f} MB) in {summary['sim_s']:.1f} s sim, "
            f"{wall:.1f} s wall in the episode manager, {run.wall_s:.1f} s for the whole launch",
            file=sys.stderr,
        )
        print(format_bench_line("collector_rtf", float(summary["real_time_factor"]), "x"))
        print(format_bench_line("collector_records_per_s", len(recs) / wall, "records/s"))
        print(
            format_bench_line(
                "collector_max_stamp_gap_ms", float(gaps.max()) * 1e3 if len(gaps) else 0.0, "ms"
            )
        )
    finally:
        if args.workdir is None:
            shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
