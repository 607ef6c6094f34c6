"""Benchmark of the collector parts that need no simulator (scripts/bench/collector.sh).

1. Per-record cost of DatasetWriter::Record on the caller's thread: write_synthetic_dataset submits
   320x240 records at a planner-like rate (default 100 per second of wall time, fsync on, 64 MB shards) and
   times every call; median and p99 in microseconds.
2. The thesis's shards-vs-npz trade-off on that dataset: samples per second to get the training arrays from
   the shards (memory map, CRC check of every record, depth decoding, B-spline resampling: what training
   reading shards directly does) and from the postprocessed .npz (np.load of every array); sizes on disk;
   sizes in memory are printed to stderr.

Prints `BENCH <name> <value> <unit>` lines on stdout; progress on stderr.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from quad_il.data.postprocess import NPZ_ARRAYS, FixedSizeArrays, postprocess_datasets
from quad_il.data.shards import open_dataset
from quad_il.data.synthetic import find_collector_tool, write_synthetic_dataset
from quad_il.tools.bench_check import format_bench_line
from quad_il.tools.cli import HelpFormatter

MB = 1e6


def _timed(fn: Callable[[], object], repeats: int) -> tuple[float, object]:
    """Median wall time of `repeats` calls and the last result."""
    times = []
    result: object = None
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), result


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(formatter_class=HelpFormatter, description=__doc__.splitlines()[0])
    ap.add_argument("--records", type=int, default=1000, help="synthetic records written")
    ap.add_argument("--width", type=int, default=320, help="depth image width (px)")
    ap.add_argument("--height", type=int, default=240, help="depth image height (px)")
    ap.add_argument("--rate-hz", type=float, default=100.0, help="submission rate of the record-cost run")
    ap.add_argument("--repeats", type=int, default=3, help="load timings: median of this many runs")
    ap.add_argument("--workdir", type=Path, default=None, help="keep the datasets here (default: a temp dir)")
    args = ap.parse_args(argv)

    find_collector_tool("write_synthetic_dataset")  # fail early with the build hint
    work = args.workdir or Path(tempfile.mkdtemp(prefix="bench_collector_"))
    work.mkdir(parents=True, exist_ok=True)
    try:
        ds_dir = work / "shards"
        timing = work / "record_timing.json"
        print(
            f"[bench collector] writing {args.records} records {args.width}x{args.height} "
            f"at {args.rate_hz} Hz to {ds_dir}",
            file=sys.stderr,
        )
        write_synthetic_dataset(
            ds_dir,
            seed=1,
            records=args.records,
            width=args.width,
            height=args.height,
            shard_size_mb=64.0,
            extra_args=[
                "--distinct-images",
                "16",
                "--rate-hz",
                str(args.rate_hz),
                "--timing-json",
                str(timing),
            ],
            fsync=True,
        )
        t = json.loads(timing.read_text())
        print(
            f"[bench collector] Record(): median {t['record_us_median']:.1f} us, "
            f"p90 {t['record_us_p90']:.1f}, p99 {t['record_us_p99']:.1f}, max {t['record_us_max']:.1f} "
            f"over {t['calls']} calls; "
            f"blocked {t['blocked_calls']}, dropped {t['dropped']}",
            file=sys.stderr,
        )
        print(format_bench_line("collector_record_us_median", t["record_us_median"], "us"))
        print(format_bench_line("collector_record_us_p99", t["record_us_p99"], "us"))

        npz = work / "dataset.npz"
        print("[bench collector] postprocessing to npz", file=sys.stderr)
        postprocess_datasets([ds_dir]).save(npz)
        n = len(open_dataset(ds_dir))

        shard_s, arrays = _timed(lambda: postprocess_datasets([ds_dir]), args.repeats)
        npz_s, loaded = _timed(lambda: FixedSizeArrays.load(npz), args.repeats)
        if not isinstance(arrays, FixedSizeArrays) or not isinstance(loaded, FixedSizeArrays):
            raise TypeError("unexpected result type")
        disk_shards = sum(p.stat().st_size for p in ds_dir.glob("shard_*")) / MB
        disk_npz = npz.stat().st_size / MB
        mem_npz = sum(getattr(loaded, name).nbytes for name in NPZ_ARRAYS) / MB
        print(
            f"[bench collector] {n} samples: shards -> arrays {shard_s:.3f} s, npz load {npz_s:.3f} s; "
            f"disk: shards {disk_shards:.1f} MB, npz {disk_npz:.1f} MB; memory: shards are mapped "
            f"(0 MB copied, {disk_shards:.1f} MB of page cache), training arrays {mem_npz:.1f} MB either way",
            file=sys.stderr,
        )
        print(format_bench_line("collector_load_shards_sps", n / shard_s, "samples/s"))
        print(format_bench_line("collector_load_npz_sps", n / npz_s, "samples/s"))
        print(format_bench_line("collector_disk_mb_shards", disk_shards, "MB"))
        print(format_bench_line("collector_disk_mb_npz", disk_npz, "MB"))
    finally:
        if args.workdir is None:
            shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
