"""`make bench-train`: training and data-loading throughput and peak memory at the default configuration.

Runs on a synthetic dataset in the collector's `.npz` layout (synthetic.py) at camera resolution (default
320x240, float16 depth), written to a temporary directory, so the benchmark needs no collected data. Prints:

    BENCH train_samples_per_s   batch size / median time of a training step (forward, loss, backward,
                                Adam step, scheduler, next batch) over an epoch after a warm-up epoch,
                                with the default config (MobileNetV3-Small at 96x96, batch 32, Adam,
                                MSE, channels_last, deterministic algorithms, 2 threads), in the real
                                training loop
    BENCH loader_samples_per_s  samples per second the data loader delivers to the training loop: batches
                                (float32 depth, state, targets) gathered from the prepared cache in the
                                seeded order with the configured worker threads, over 5 epochs. The
                                one-off preparation (read, validate, preprocess the file) is logged on
                                stderr with its own rate; it is paid once per run, not per epoch.
    BENCH train_peak_mem_mb     peak resident memory of the benchmark process (ru_maxrss): the prepared
                                dataset, the memory-mapped .npz pages it touched, the model and training
"""

from __future__ import annotations

import argparse
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import torch

from quad_il.learning.config import load_config
from quad_il.learning.dataset import Batch, BatchLoader, load_dataset
from quad_il.learning.preprocessing import DepthPreprocessor
from quad_il.learning.trainer import Trainer
from quad_il.tools.bench_check import format_bench_line
from quad_il.tools.cli import HelpFormatter
from quad_il.tools.repo import repo_path


class _TimedLoader:
    """Wraps a BatchLoader and stamps the time each batch is requested (one training step apart)."""

    def __init__(self, loader: BatchLoader) -> None:
        self.loader = loader
        self.stamps: list[float] = []

    def __len__(self) -> int:
        return len(self.loader)

    def epoch(self, epoch: int) -> Iterator[Batch]:
        for batch in self.loader.epoch(epoch):
            self.stamps.append(time.perf_counter())
            yield batch
        self.stamps.append(time.perf_counter())


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("--config", default=str(repo_path("config", "train.yaml")), help="training config")
    ap.add_argument("--episodes", type=int, default=40, help="synthetic episodes")
    ap.add_argument("--samples-per-episode", type=int, default=32, help="samples per synthetic episode")
    ap.add_argument("--height", type=int, default=240, help="depth image height (px)")
    ap.add_argument("--width", type=int, default=320, help="depth image width (px)")
    ap.add_argument("--set", action="append", default=[], help="config override, e.g. model.input_height=128")
    args = ap.parse_args(argv)

    def log(msg: str) -> None:
        print(f"[bench-train] {msg}", file=sys.stderr, flush=True)

    with tempfile.TemporaryDirectory(prefix="bench_train_") as tmp:
        path = Path(tmp) / "synthetic.npz"
        t0 = time.perf_counter()
        # Written by a child process, so that the generator's memory is not part of this process's peak.
        code = (
            "import sys; from quad_il.learning.synthetic import write_synthetic_npz; "
            "write_synthetic_npz(sys.argv[1], num_episodes=int(sys.argv[2]), "
            "samples_per_episode=int(sys.argv[3]), height=int(sys.argv[4]), width=int(sys.argv[5]))"
        )
        dims = [args.episodes, args.samples_per_episode, args.height, args.width]
        subprocess.run([sys.executable, "-c", code, str(path), *map(str, dims)], check=True)
        n = args.episodes * args.samples_per_episode
        log(
            f"synthetic dataset: {n} samples of {args.width}x{args.height} depth, "
            f"{time.perf_counter() - t0:.1f} s"
        )
        overrides = [
            f"data.paths=[{str(path)!r}]",
            f"run.out_dir={tmp!r}",
            "run.name=bench",
            "log.progress=false",
            "log.tensorboard=false",
            "log.export_torchscript=false",
            "log.plots=false",
            "data.hash_files=false",
            *args.set,
        ]
        cfg = load_config([args.config] if Path(args.config).is_file() else [], overrides)
        torch.set_num_threads(cfg.run.num_threads)
        m = cfg.model
        log(
            f"config: {m.variant} at {m.input_height}x{m.input_width}, batch {cfg.optim.batch_size}, "
            f"{cfg.run.num_threads} threads, {cfg.data.num_workers} loader workers"
        )

        # One-off preparation: file -> validated, preprocessed float16 tensors (logged, not a BENCH line).
        t0 = time.perf_counter()
        data = load_dataset([path], DepthPreprocessor(m.input_height, m.input_width, m.max_depth_m))
        t_prepare = time.perf_counter() - t0
        # The loader as training uses it: batches from the prepared cache, in the seeded order, with the
        # configured worker threads; 5 epochs.
        targets = torch.zeros(len(data), 3 * data.num_ctrl_pts)
        idx = torch.arange(len(data)).numpy()
        loader = BatchLoader(data, targets, idx, cfg.optim.batch_size, True, 0, True, cfg.data.num_workers)
        t0 = time.perf_counter()
        delivered = sum(len(b.indices) for e in range(5) for b in loader.epoch(e))
        loader_sps = delivered / (time.perf_counter() - t0)
        log(
            f"loader: one-off preparation {n / t_prepare:.0f} samples/s ({t_prepare:.1f} s), "
            f"batches from the cache {loader_sps:.0f} samples/s"
        )

        # Training: the real loop, epoch 1 as warm-up, epoch 2 timed step by step. The machine is shared, so
        # the rate is batch size / median step time (robust to other processes' bursts); the mean is logged.
        trainer = Trainer(cfg, data=data, argv=["bench"])
        trainer._train_epoch(1)
        timed = _TimedLoader(trainer.train_loader)
        trainer.train_loader = timed  # type: ignore[assignment]
        trainer._train_epoch(2)
        steps = np.diff(np.asarray(timed.stamps))
        train_sps = cfg.optim.batch_size / float(np.median(steps))
        log(
            f"training: {len(steps)} steps of {cfg.optim.batch_size}, "
            f"median {1e3 * np.median(steps):.0f} ms, "
            f"mean rate {cfg.optim.batch_size * len(steps) / steps.sum():.0f} samples/s"
        )
        peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
        log(f"loader / training rate: {loader_sps / train_sps:.0f}x (target >= 5x)")
        log(f"one-off preparation / training rate: {n / t_prepare / train_sps:.1f}x")
    print(format_bench_line("train_samples_per_s", train_sps, "samples/s"))
    print(format_bench_line("loader_samples_per_s", loader_sps, "samples/s"))
    print(format_bench_line("train_peak_mem_mb", peak_mb, "MB"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
