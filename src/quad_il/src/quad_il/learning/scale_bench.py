"""`make bench-scale`, training part: training throughput with 1 process and with N DDP processes.

Both runs train the default configuration (config/train.yaml: MobileNetV3-Small at 96x96, Adam, MSE,
global batch 32, dropout 0.2, per-process BatchNorm statistics under DDP: dist.sync_batchnorm false) on
the same synthetic dataset in the collector's `.npz` layout (synthetic.py), one after the other in this
command, with the machine's cores divided among the processes (1 process x 2 threads vs 2 processes x 1
thread here). Prints

    BENCH train_sps_1proc    global samples per second of the training epochs after a warm-up epoch
    BENCH train_sps_2procs   (wall time between barriers around each epoch's training loop: forward,
                             loss, backward with DDP's gradient all-reduce, Adam, scheduler, batches)

and, as plain lines, each run's validation loss after the last epoch and their relative difference (the
runs draw different dropout masks and sum in a different order, so they agree within the floating-point
spread of Adam training, not bit for bit; docs/scaling.md).

    python -m quad_il.learning.scale_bench [--procs 1 2] [--epochs 3] [--set key=value ...]
    python -m quad_il.learning.scale_bench worker --result R.json --set ...   (one run; under torchrun)
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from quad_il.tools.bench_check import format_bench_line
from quad_il.tools.cli import HelpFormatter
from quad_il.tools.repo import repo_path

DEFAULT_CONFIG = repo_path("config", "train.yaml")
BENCH_NAMES = {1: "train_sps_1proc", 2: "train_sps_2procs"}


def _log(msg: str) -> None:
    print(f"[bench-scale] {msg}", file=sys.stderr, flush=True)


def worker(argv: list[str]) -> int:
    """One training run (a single process, or one rank under torchrun): time each epoch's training loop."""
    from quad_il.learning.config import load_config
    from quad_il.learning.distributed import init_distributed
    from quad_il.learning.trainer import Trainer

    ap = argparse.ArgumentParser(formatter_class=HelpFormatter, prog="scale_bench worker")
    ap.add_argument("--config", default=str(DEFAULT_CONFIG), help="training config")
    ap.add_argument("--result", required=True, help="JSON file the timings are written to")
    ap.add_argument("--set", action="append", default=[], help="config override KEY=VALUE; repeat")
    args = ap.parse_args(argv)
    cfg = load_config([args.config] if Path(args.config).is_file() else [], args.set)
    ctx = init_distributed(cfg)
    try:
        trainer = Trainer(cfg, dist=ctx, argv=["scale_bench"])
        train_s: list[float] = []
        history = []
        for epoch in range(1, cfg.optim.epochs + 1):
            ctx.barrier()
            t0 = time.perf_counter()
            train_loss = trainer._train_epoch(epoch)
            ctx.barrier()
            train_s.append(time.perf_counter() - t0)
            val_loss, val_mse, _ = trainer._validate(epoch)
            history.append(
                {"epoch": epoch, "train_loss": train_loss, "val_loss": val_loss, "val_mse": val_mse}
            )
            if ctx.is_main:
                _log(
                    f"{ctx.world_size} process(es): epoch {epoch}: training {train_s[-1]:.1f} s, "
                    f"train loss {train_loss:.5g}, val loss {val_loss:.5g}"
                )
        samples_per_epoch = len(trainer.train_loader) * cfg.optim.batch_size
        timed = train_s[1:] if len(train_s) > 1 else train_s
        result = {
            "world_size": ctx.world_size,
            "threads_per_process": cfg.run.num_threads,
            "global_batch": cfg.optim.batch_size,
            "samples_per_epoch": samples_per_epoch,
            "train_s": train_s,
            "samples_per_s": samples_per_epoch * len(timed) / sum(timed),
            "history": history,
            "sync_batchnorm": cfg.dist.sync_batchnorm,
        }
        if ctx.is_main:
            Path(args.result).write_text(json.dumps(result, indent=1))
    finally:
        ctx.close()
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["worker"]:
        return worker(argv[1:])
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("--config", default=str(DEFAULT_CONFIG), help="training config")
    ap.add_argument(
        "--procs",
        type=int,
        nargs="+",
        default=[1, 2],
        choices=sorted(BENCH_NAMES),
        help="process counts measured",
    )
    ap.add_argument("--epochs", type=int, default=6, help="1 warm-up epoch + the timed ones")
    ap.add_argument("--episodes", type=int, default=24, help="synthetic episodes")
    ap.add_argument("--samples-per-episode", type=int, default=32, help="samples per synthetic episode")
    ap.add_argument("--height", type=int, default=120, help="depth image height (px)")
    ap.add_argument("--width", type=int, default=160, help="depth image width (px)")
    ap.add_argument("--cpus", type=int, default=os.cpu_count() or 1, help="threads shared by the processes")
    ap.add_argument("--set", action="append", default=[], help="config override for both runs")
    args = ap.parse_args(argv)

    results: dict[int, dict] = {}
    with tempfile.TemporaryDirectory(prefix="bench_scale_") as tmp:
        path = Path(tmp) / "synthetic.npz"
        code = (
            "import sys; from quad_il.learning.synthetic import write_synthetic_npz; "
            "write_synthetic_npz(sys.argv[1], num_episodes=int(sys.argv[2]), "
            "samples_per_episode=int(sys.argv[3]), height=int(sys.argv[4]), width=int(sys.argv[5]))"
        )
        dims = [args.episodes, args.samples_per_episode, args.height, args.width]
        subprocess.run([sys.executable, "-c", code, str(path), *map(str, dims)], check=True)
        _log(
            f"synthetic dataset: {args.episodes * args.samples_per_episode} samples of "
            f"{args.width}x{args.height} depth; {args.epochs} epochs per run (the first is warm-up)"
        )
        for n in args.procs:
            threads = max(1, args.cpus // n)
            result = Path(tmp) / f"result_{n}.json"
            overrides = [
                f"data.paths=[{str(path)!r}]",
                f"run.out_dir={tmp!r}",
                f"run.name=procs{n}",
                f"run.num_threads={threads}",
                f"optim.epochs={args.epochs}",
                "log.progress=false",
                "log.tensorboard=false",
                "log.export_torchscript=false",
                "log.plots=false",
                "data.hash_files=false",
                *args.set,
            ]
            run_args = ["worker", "--config", args.config, "--result", str(result)]
            run_args += [a for o in overrides for a in ("--set", o)]
            if n == 1:
                cmd = [sys.executable, "-m", "quad_il.learning.scale_bench", *run_args]
            else:
                cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone"]
                cmd += [f"--nproc_per_node={n}", "-m", "quad_il.learning.scale_bench", *run_args]
            _log(f"{n} process(es) x {threads} thread(s): {' '.join(cmd[:6])} ...")
            t0 = time.perf_counter()
            proc = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
            if proc.returncode != 0:
                print(proc.stderr[-4000:], file=sys.stderr)
                _log(f"the {n}-process run failed (exit {proc.returncode})")
                return 1
            results[n] = json.loads(result.read_text())
            _log(f"{n} process(es): {time.perf_counter() - t0:.0f} s in all")
    for n, r in results.items():
        print(format_bench_line(BENCH_NAMES[n], r["samples_per_s"], "samples/s"))
    for n, r in results.items():
        last = r["history"][-1]
        print(
            f"scale: {n} process(es) x {r['threads_per_process']} thread(s), global batch "
            f"{r['global_batch']}: validation loss after epoch {last['epoch']} = {last['val_loss']:.6g} "
            f"(train loss {last['train_loss']:.6g})"
        )
    if 1 in results and 2 in results:
        a, b = results[1]["history"][-1]["val_loss"], results[2]["history"][-1]["val_loss"]
        speedup = results[2]["samples_per_s"] / results[1]["samples_per_s"]
        print(f"scale: validation loss, 2 processes vs 1: relative difference {(b - a) / a:+.3%}")
        print(f"scale: training speed-up with 2 processes: {speedup:.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
