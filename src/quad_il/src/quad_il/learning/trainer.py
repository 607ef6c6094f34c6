"""Behaviour-cloning training loop (thesis section 3.9) with reproducible, resumable run directories.

Run directory `<run.out_dir>/<run.name>/`:
    config.yaml            resolved configuration (what was trained)
    run_info.json          seed, software commit (+ dirty flag), versions, command line, resumptions
    dataset_manifest.json  sources (size, sha256, collector manifest), split episodes and world seeds
    metrics.csv            one row per epoch (CSV_COLUMNS)
    tensorboard/           the same scalars for TensorBoard
    checkpoints/last.pt    everything needed to resume (model, optimiser, scheduler, RNG, epoch)
    checkpoints/best.pt    the epoch with the lowest validation loss
                           (both: plain values and tensors only, written atomically, read with
                           weights_only=True: checkpoint.py)
    policy.ts              TorchScript export of best.pt, with preprocessing (export.py)
    loss_curves.png        training/validation loss and learning rate per epoch
    summary.json           best epoch and losses, export check

Determinism: the global torch RNG is seeded with run.seed before the network is built, the thread count is
fixed, `torch.use_deterministic_algorithms` is on, and the batch order of epoch e is a function of (seed, e).
Two runs with the same configuration and data give identical losses; a resumed run continues the same curve,
and a run killed at any moment (SIGKILL, even while a checkpoint is written) and resumed with --resume ends
with bit-identical weights (tests/python/test_training_kill_resume.py): it restarts from the last completed
epoch's checkpoint (model, optimiser, scheduler, RNG states, epoch and step); the batch order needs no saved
state. A run killed before its first checkpoint is started over by --resume.

Distributed data parallel (`dist` a DistContext from distributed.init_distributed, world size > 1; see
distributed.py and docs/scaling.md): every rank loads the data and builds the same seeded network; each
takes its share of every global batch (optim.batch_size) in the single-process order; DDP averages the
gradients; the loss sums are all-reduced, so the logged training and validation losses are the global ones;
only rank 0 reads and writes the run directory (config, CSV, TensorBoard, checkpoints, plots, export) and
broadcasts what the others need (resolved configuration, resumed checkpoint). With `DistContext()` (the
default) none of this runs: the single-process code path is unchanged.
"""

from __future__ import annotations

import csv
import json
import math
import os
import random
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray
from torch import Tensor, nn
from tqdm import tqdm

from quad_il.learning import metrics
from quad_il.learning.checkpoint import (
    CHECKPOINT_FORMAT,
    read_training_checkpoint,
    rng_state,
    save_checkpoint,
    set_rng_state,
)
from quad_il.learning.config import (
    RESUME_MUTABLE_KEYS,
    ConfigError,
    ModelConfig,
    TrainConfig,
    config_differences,
    dump_config,
    load_config,
)
from quad_il.learning.dataset import (
    Batch,
    BatchLoader,
    PreparedData,
    ShardOptions,
    Split,
    load_dataset,
    split_by_episode,
)
from quad_il.learning.distributed import (
    SINGLE_PROCESS,
    DistContext,
    GlobalBatchDistributedSampler,
    check_batch_division,
    convert_batchnorm,
    rank_seed,
    revert_batchnorm,
)
from quad_il.learning.export import export_torchscript, policy_metadata
from quad_il.learning.losses import batch_loss, eil_per_sample, per_sample_loss, wta_per_sample
from quad_il.learning.model import Policy, build_policy
from quad_il.learning.preprocessing import DepthPreprocessor, mirror_about_heading
from quad_il.learning.runinfo import dataset_manifest, software_info
from quad_il.learning.schedulers import build_scheduler

CSV_COLUMNS = [
    "epoch",
    "global_step",
    "lr",
    "train_loss",
    "val_loss",
    "val_mse_world_m2",
    "val_cosine_world",
    "epoch_wall_s",
]
PolicyFactory = Callable[[ModelConfig, int, float], Policy]


class NonFiniteLossError(RuntimeError):
    """The loss became NaN or Inf; the message names the epoch, step and the batch's samples."""


class RunDirError(RuntimeError):
    """The run directory cannot be used as asked (exists without --resume, or nothing to resume)."""


@dataclass(frozen=True)
class EpochRecord:
    epoch: int
    global_step: int
    lr: float
    train_loss: float
    val_loss: float
    val_mse_world_m2: float
    val_cosine_world: float
    epoch_wall_s: float

    def row(self) -> dict[str, Any]:
        return {c: getattr(self, c) for c in CSV_COLUMNS}


@dataclass(frozen=True)
class TrainResult:
    run_dir: Path
    history: list[EpochRecord]
    best_epoch: int
    best_val_loss: float
    policy_path: Path | None


def configure_determinism(seed: int, num_threads: int, deterministic: bool) -> None:
    # Training draws only from torch's global generator and from generators seeded with (run.seed, epoch);
    # Python's and numpy's global ones are seeded too (and checkpointed) for any library that uses them.
    random.seed(seed)
    np.random.seed(seed % 2**32)  # noqa: NPY002
    torch.manual_seed(seed)
    torch.set_num_threads(num_threads)
    torch.use_deterministic_algorithms(deterministic)


def run_dir_of(cfg: TrainConfig) -> Path:
    return Path(cfg.run.out_dir) / cfg.run.name


def _read_csv(path: Path) -> list[dict[str, str]]:
    if not path.is_file():
        return []
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    tmp = path.with_name(path.name + ".partial")
    with open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=CSV_COLUMNS)
        w.writeheader()
        for r in rows:
            w.writerow({k: r[k] for k in CSV_COLUMNS})
    tmp.replace(path)


def _record_from_row(r: dict[str, str]) -> EpochRecord:
    return EpochRecord(
        int(r["epoch"]),
        int(r["global_step"]),
        *(float(r[k]) for k in CSV_COLUMNS[2:]),  # type: ignore[arg-type]
    )


class DistributedBatchLoader(BatchLoader):
    """This rank's share of every global batch: `GlobalBatchDistributedSampler` (set_epoch per epoch) gives
    the rank's indices; consecutive runs of the per-process batch size are its batches."""

    def __init__(
        self,
        data: PreparedData,
        targets: Tensor,
        sampler: GlobalBatchDistributedSampler,
        per_process_batch: int,
        num_workers: int,
    ) -> None:
        super().__init__(data, targets, sampler.indices, per_process_batch, False, 0, False, num_workers)
        self.sampler = sampler

    def __len__(self) -> int:
        return self.sampler.steps

    def order(self, epoch: int) -> np.ndarray:
        self.sampler.set_epoch(epoch)
        return self.sampler.epoch_indices()


class _PreparedForward(nn.Module):
    """DDP hooks `forward` only: this makes the training forward (`forward_prepared`) the wrapped one."""

    def __init__(self, policy: Policy) -> None:
        super().__init__()
        self.policy = policy

    def forward(self, x: Tensor, p: Tensor, v: Tensor, q: Tensor, goal: Tensor) -> Tensor:
        return self.policy.forward_prepared(x, p, v, q, goal)


class Trainer:
    """One training run. `Trainer(cfg).fit()`; `Trainer(cfg, resume=True)` continues `run_dir_of(cfg)`.

    `dist`: this process's DistContext in a distributed run (torchrun; distributed.init_distributed).
    """

    def __init__(
        self,
        cfg: TrainConfig,
        resume: bool = False,
        data: PreparedData | None = None,
        policy_factory: PolicyFactory = build_policy,
        argv: list[str] | None = None,
        dist: DistContext = SINGLE_PROCESS,
    ) -> None:
        self.dist = dist
        self.run_dir = run_dir_of(cfg)
        self.resume = resume
        self.argv = argv if argv is not None else sys.argv
        per_process_batch = cfg.optim.batch_size
        if dist.enabled:
            per_process_batch = check_batch_division(cfg.optim.batch_size, dist.world_size)
        # Resuming a run killed before its first checkpoint starts it over (its config.yaml is checked).
        self._has_checkpoint = False
        if resume:
            cfg, self._has_checkpoint = dist.run_on_main(lambda: self._check_resumable(cfg))
        else:
            dist.run_on_main(self._check_new_run_dir)
        self.cfg = cfg
        configure_determinism(cfg.run.seed, cfg.run.num_threads, cfg.run.deterministic)
        if dist.enabled and dist.local_rank == 0:
            cpus = os.cpu_count() or 1
            if cfg.run.num_threads * dist.local_world_size > cpus:
                print(
                    f"[train] warning: run.num_threads={cfg.run.num_threads} x {dist.local_world_size} "
                    f"processes on this node > {cpus} CPUs: "
                    f"set run.num_threads={max(1, cpus // dist.local_world_size)}",
                    file=sys.stderr,
                )
        # The policy needs the dataset's K and horizon, the data only the parameter-free depth preprocessor
        # (built from the same config, identical to the policy's own): data first, then the seeded network.
        pre = DepthPreprocessor(cfg.model.input_height, cfg.model.input_width, cfg.model.max_depth_m)
        sh = cfg.data.shards
        shards = ShardOptions(sh.num_ctrl_pts, sh.horizon_s, sh.on_corrupt)
        self.data = data if data is not None else load_dataset(cfg.data.paths, pre, shards)
        torch.manual_seed(cfg.run.seed)
        self.policy = policy_factory(cfg.model, self.data.num_ctrl_pts, self.data.horizon_s)
        if cfg.run.init_weights and not self._has_checkpoint:
            load_initial_weights(self.policy, cfg.run.init_weights, cfg.model)
        if cfg.optim.channels_last:
            self.policy = self.policy.to(memory_format=torch.channels_last)
        self.split: Split = split_by_episode(
            self.data.world_seed,
            self.data.episode_id,
            cfg.data.val_fraction,
            cfg.run.seed,
            cfg.data.train_episode_fraction,
            cfg.data.split,
        )
        self.partition = torch.from_numpy(
            self.data.partition
            if self.data.partition is not None
            else np.zeros(len(self.data), dtype=np.int32)  # DEMO
        )
        if cfg.optim.loss == "eil" and self.data.partition is None:
            dist.run_on_main(
                lambda: print(
                    "[train] optim.loss=eil on data without il_partition: every row is DEMO (a regression)",
                    file=sys.stderr,
                )
            )
        with torch.no_grad():
            self.targets = self.policy.encode_target(
                self.data.ctrl_world, self.data.p_world_body, self.data.q_world_body
            ).contiguous()
            # data.mirror_probability: every sample's mirrored target, encoded once (the mirror keeps p, yaw).
            self.mirrored_targets: Tensor | None = None
            if cfg.data.mirror_probability > 0.0:
                _, q_m, _, ctrl_m = mirror_about_heading(
                    self.data.p_world_body,
                    self.data.v_world,
                    self.data.q_world_body,
                    self.data.goal_world,
                    self.data.ctrl_world,
                )
                self.mirrored_targets = self.policy.encode_target(
                    ctrl_m, self.data.p_world_body, q_m
                ).contiguous()
        o = cfg.optim
        self.val_loader: BatchLoader | None
        if not dist.enabled:
            self.train_loader = BatchLoader(
                self.data,
                self.targets,
                self.split.train_idx,
                o.batch_size,
                True,
                cfg.run.seed,
                True,
                cfg.data.num_workers,
            )
            self.val_loader = BatchLoader(
                self.data,
                self.targets,
                self.split.val_idx,
                4 * o.batch_size,
                False,
                0,
                False,
                cfg.data.num_workers,
            )
        else:
            sampler = GlobalBatchDistributedSampler(
                self.split.train_idx, dist.world_size, dist.rank, cfg.run.seed, o.batch_size
            )
            self.train_loader = DistributedBatchLoader(
                self.data, self.targets, sampler, per_process_batch, cfg.data.num_workers
            )
            # Validation: every rank evaluates a strided share; the sums are all-reduced (_validate).
            val_share = self.split.val_idx[dist.rank :: dist.world_size]
            self.val_loader = (
                BatchLoader(
                    self.data,
                    self.targets,
                    val_share,
                    4 * per_process_batch,
                    False,
                    0,
                    False,
                    cfg.data.num_workers,
                )
                if len(val_share)
                else None
            )
        self.device = dist.device
        if self.device.type != "cpu":
            self.policy = self.policy.to(self.device)
        params = self.policy.parameters()
        if o.optimizer == "adam":
            self.optimizer: torch.optim.Optimizer = torch.optim.Adam(
                params, lr=o.lr, weight_decay=o.weight_decay
            )
        elif o.optimizer == "adamw":
            self.optimizer = torch.optim.AdamW(params, lr=o.lr, weight_decay=o.weight_decay)
        else:
            self.optimizer = torch.optim.SGD(
                params, lr=o.lr, momentum=o.momentum, weight_decay=o.weight_decay
            )
        self.scheduler = build_scheduler(
            cfg.scheduler, self.optimizer, max(o.epochs * len(self.train_loader), 1)
        )
        self._ddp: nn.Module | None = None
        if dist.enabled:
            from torch.nn.parallel import DistributedDataParallel

            if cfg.dist.sync_batchnorm:
                convert_batchnorm(self.policy, dist.bn_group)
            self._ddp = DistributedDataParallel(
                _PreparedForward(self.policy),
                device_ids=[self.device] if self.device.type == "cuda" else None,
            )  # buffers (BatchNorm running statistics) are synchronised from rank 0 at every forward
        self.start_epoch = 0
        self.global_step = 0
        self.best_val_loss = math.inf
        self.best_epoch = 0
        self.history: list[EpochRecord] = []
        self._writer: Any = None  # TensorBoard SummaryWriter while fit() runs

    # ------------------------------------------------------------------------------------------------ run dir
    def _check_new_run_dir(self) -> None:
        if (self.run_dir / "checkpoints" / "last.pt").exists() or (self.run_dir / "metrics.csv").exists():
            raise RunDirError(
                f"run directory {self.run_dir} already holds a run: resume it or choose run.name"
            )

    def _check_resumable(self, cfg: TrainConfig) -> tuple[TrainConfig, bool]:
        ckpt = self.run_dir / "checkpoints" / "last.pt"
        saved_cfg_path = self.run_dir / "config.yaml"
        if not saved_cfg_path.is_file():
            raise RunDirError(f"nothing to resume in {self.run_dir} (no config.yaml)")
        saved = load_config([saved_cfg_path])
        changed = {k: v for k, v in config_differences(saved, cfg).items() if k not in RESUME_MUTABLE_KEYS}
        if changed:
            detail = ", ".join(f"{k}: {a!r} -> {b!r}" for k, a, b in ((k, *v) for k, v in changed.items()))
            raise ConfigError(
                f"cannot resume {self.run_dir} with a different configuration ({detail}); only "
                f"{sorted(RESUME_MUTABLE_KEYS)} may change"
            )
        return cfg, ckpt.is_file()

    def _write_run_files(self) -> None:
        self.run_dir.mkdir(parents=True, exist_ok=True)
        (self.run_dir / "checkpoints").mkdir(exist_ok=True)
        dump_config(self.cfg, self.run_dir / "config.yaml")
        info_path = self.run_dir / "run_info.json"
        now = time.strftime("%Y-%m-%dT%H:%M:%S%z")
        entry: dict[str, Any] = {"started": now, "argv": list(self.argv), "software": software_info()}
        entry["world_size"] = self.dist.world_size
        if self.dist.enabled:
            entry["distributed"] = {
                **self.dist.describe(),
                "global_batch": self.cfg.optim.batch_size,
                "per_process_batch": self.cfg.optim.batch_size // self.dist.world_size,
                "sync_batchnorm": self.cfg.dist.sync_batchnorm,
            }
        if self.resume and info_path.is_file():
            info = json.loads(info_path.read_text())
            info.setdefault("resumptions", []).append({**entry, "from_epoch": self.start_epoch})
        else:
            info = {"seed": self.cfg.run.seed, **entry}
        info_path.write_text(json.dumps(info, indent=1))
        manifest = dataset_manifest(self.cfg.data.paths, self.data, self.split, self.cfg.data.hash_files)
        (self.run_dir / "dataset_manifest.json").write_text(json.dumps(manifest, indent=1, default=str))

    def _checkpoint(self, epoch: int) -> dict[str, Any]:
        return {
            "format": CHECKPOINT_FORMAT,
            "epoch": epoch,
            "global_step": self.global_step,
            "model": self.policy.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "scheduler": self.scheduler.state_dict() if self.scheduler is not None else None,
            "best_val_loss": self.best_val_loss,
            "best_epoch": self.best_epoch,
            "rng": rng_state(),
            "config": self.cfg.to_dict(),
            "num_ctrl_pts": self.data.num_ctrl_pts,
            "horizon_s": self.data.horizon_s,
            "world_size": self.dist.world_size,
        }

    def _load_last(self) -> tuple[dict[str, Any], list[dict[str, str]]]:
        ckpt = read_training_checkpoint(self.run_dir / "checkpoints" / "last.pt", "resume: checkpoint")
        # Rows written after the checkpoint (a crash between the two writes) are redone identically.
        rows = [r for r in _read_csv(self.run_dir / "metrics.csv") if int(r["epoch"]) <= int(ckpt["epoch"])]
        return ckpt, rows

    def _restore(self) -> None:
        # Rank 0 reads the run directory; every rank gets the same checkpoint (no shared file system needed).
        ckpt, rows = self.dist.run_on_main(self._load_last)
        self.policy.load_state_dict(ckpt["model"])
        self.optimizer.load_state_dict(ckpt["optimizer"])
        if self.scheduler is not None:
            self.scheduler.load_state_dict(ckpt["scheduler"])
        if not self.dist.enabled:
            if "rng" in ckpt:
                set_rng_state(ckpt["rng"])
            else:  # format /1
                torch.set_rng_state(ckpt["torch_rng_state"])
        # (Under DDP each rank's RNG is reseeded per epoch from (seed, epoch, rank): nothing to restore.)
        saved_world = int(ckpt.get("world_size", 1))
        if saved_world != self.dist.world_size and self.dist.is_main:
            print(
                f"[train] note: {self.run_dir} was trained with {saved_world} process(es) and resumes with "
                f"{self.dist.world_size}: the curve continues, but not bit-identically to an "
                "uninterrupted run",
                file=sys.stderr,
            )
        self.start_epoch = int(ckpt["epoch"])
        self.global_step = int(ckpt["global_step"])
        self.best_val_loss = float(ckpt["best_val_loss"])
        self.best_epoch = int(ckpt["best_epoch"])
        self.history = [_record_from_row(r) for r in rows]

    # ----------------------------------------------------------------------------------------------- training
    def _nonfinite(self, epoch: int, batch: Batch, per_sample: Tensor, what: str) -> NonFiniteLossError:
        bad = (~torch.isfinite(per_sample)).nonzero().flatten().tolist()
        culprits = bad if bad else list(range(len(batch.indices)))
        names = ", ".join(self.data.describe(int(batch.indices[i])) for i in culprits[:10])
        return NonFiniteLossError(
            f"non-finite {what} at epoch {epoch}, step {self.global_step}: batch of dataset indices "
            f"{batch.indices.tolist()}; non-finite per-sample loss for {names}"
            f"{' ...' if len(culprits) > 10 else ''}"
        )

    def _dist_nonfinite(
        self, epoch: int, batch: Batch | None, per_sample: Tensor | None, what: str
    ) -> NonFiniteLossError:
        """The error every rank raises together: each rank's culprits, gathered."""
        local = None
        if batch is not None and per_sample is not None:
            local = str(self._nonfinite(epoch, batch, per_sample, what))
        messages = self.dist.all_gather_object(local)
        found = [f"rank {r}: {m}" for r, m in enumerate(messages) if m is not None]
        return NonFiniteLossError(
            f"non-finite {what} at epoch {epoch}, step {self.global_step} (distributed run of "
            f"{self.dist.world_size} processes): " + " | ".join(found)
        )

    def _batch_loss(self, y: Tensor, batch: Batch) -> tuple[Tensor, Tensor]:
        """(batch mean, per-sample losses) of optim.loss; EIL reads each row's partition."""
        o = self.cfg.optim
        if self.cfg.model.hypotheses > 1:
            plans, logits = self.policy.split_hypotheses(y)
            if self.cfg.model.hypotheses_first == "mean":
                # Plan 0 is the single plan's regression; the others are alternatives, winner-takes-all.
                alt, _ = wta_per_sample(
                    o.loss, plans[:, 1:], logits[:, 1:], batch.target, o.wta_relax, o.wta_confidence_weight
                )
                per = per_sample_loss(o.loss, plans[:, 0], batch.target) + alt
            else:
                per, _ = wta_per_sample(
                    o.loss, plans, logits, batch.target, o.wta_relax, o.wta_confidence_weight
                )
            return per.mean(), per
        if o.loss != "eil":
            return batch_loss(o.loss, y, batch.target)
        part = self.partition.index_select(0, torch.from_numpy(batch.indices)).to(y.device)
        per = eil_per_sample(y, batch.target, part, o.eil.threshold_b_m, o.eil.intervention_weight)
        return per.mean(), per

    def _to_device(self, batch: Batch) -> Batch:
        if self.device.type == "cpu":
            return batch
        d = self.device
        return Batch(
            batch.indices,
            batch.depth_x.to(d),
            batch.p_world_body.to(d),
            batch.v_world.to(d),
            batch.q_world_body.to(d),
            batch.goal_world.to(d),
            batch.target.to(d),
        )

    def _mirror_mask(self, epoch: int) -> NDArray[np.bool_] | None:
        """data.mirror_probability: which samples are seen in a mirror this epoch, a function of (run.seed,
        epoch, sample index) only (the same with any batch order, worker or process count)."""
        prob = self.cfg.data.mirror_probability
        if prob <= 0.0:
            return None
        return np.random.default_rng([self.cfg.run.seed, epoch, 0x4D4952]).random(len(self.data)) < prob

    def _mirrored(self, batch: Batch, mirror: NDArray[np.bool_]) -> Batch:
        """The batch with its selected samples replaced by their mirror images (mirror_about_heading): depth
        flipped left to right, velocity, attitude and goal reflected, the mirrored target."""
        sel = torch.from_numpy(mirror[batch.indices])
        if not bool(sel.any()):
            return batch
        if self.mirrored_targets is None:
            raise RuntimeError("mirrored targets are built whenever data.mirror_probability > 0")
        v_m, q_m, goal_m, _ = mirror_about_heading(
            batch.p_world_body, batch.v_world, batch.q_world_body, batch.goal_world
        )
        col = sel.view(-1, 1)
        return Batch(
            batch.indices,
            torch.where(sel.view(-1, 1, 1, 1), batch.depth_x.flip(-1), batch.depth_x),
            batch.p_world_body,
            torch.where(col, v_m, batch.v_world),
            torch.where(col, q_m, batch.q_world_body),
            torch.where(col, goal_m, batch.goal_world),
            torch.where(col, self.mirrored_targets[torch.from_numpy(batch.indices)], batch.target),
        )

    def _train_epoch(self, epoch: int) -> float:
        self.policy.train()
        o = self.cfg.optim
        total, count = 0.0, 0
        if self.dist.enabled:
            # Dropout masks: per rank and epoch (a resumed run draws the same ones).
            torch.manual_seed(rank_seed(self.cfg.run.seed, epoch, self.dist.rank))
        bar = tqdm(
            self.train_loader.epoch(epoch),
            total=len(self.train_loader),
            desc=f"epoch {epoch}/{o.epochs}",
            disable=not (self.cfg.log.progress and self.dist.is_main),
            leave=False,
            file=sys.stderr,
            dynamic_ncols=True,
        )
        forward = self._ddp if self._ddp is not None else self.policy.forward_prepared
        mirror = self._mirror_mask(epoch)
        for batch in bar:
            if mirror is not None:
                batch = self._mirrored(batch, mirror)
            batch = self._to_device(batch)
            x = batch.depth_x
            if o.channels_last:
                x = x.contiguous(memory_format=torch.channels_last)
            y = forward(x, batch.p_world_body, batch.v_world, batch.q_world_body, batch.goal_world)
            loss, per = self._batch_loss(y, batch)
            if self.dist.enabled:
                # The global batch's loss and a non-finite count, summed over ranks (one small all-reduce),
                # checked before backward so that every rank stops at the same step.
                detached = per.detach()
                s, n, bad = self.dist.all_reduce_sum(
                    [detached.sum(), len(per), (~torch.isfinite(detached)).sum()]
                )
                if bad > 0:
                    local_bad = not bool(torch.isfinite(detached).all())
                    raise self._dist_nonfinite(
                        epoch, batch if local_bad else None, detached.cpu(), "training loss"
                    )
                step_loss = s / n
            else:
                if not bool(torch.isfinite(loss)):
                    raise self._nonfinite(epoch, batch, per.detach(), "training loss")
            self.optimizer.zero_grad(set_to_none=True)
            loss.backward()
            if o.grad_clip_norm is not None:
                norm = torch.nn.utils.clip_grad_norm_(self.policy.parameters(), o.grad_clip_norm)
                if not bool(torch.isfinite(norm)):
                    raise self._nonfinite(epoch, batch, per.detach(), "gradient norm")
            self.optimizer.step()
            if self.scheduler is not None:
                self.scheduler.step()
            self.global_step += 1
            if not self.dist.enabled:
                step_loss = loss.item()
                total += float(per.detach().sum())
                count += len(per)
            else:
                total += s
                count += int(n)
            if self._writer is not None:
                self._writer.add_scalar("step/train_loss", step_loss, self.global_step)
                self._writer.add_scalar("step/lr", self.optimizer.param_groups[0]["lr"], self.global_step)
            bar.set_postfix(loss=f"{step_loss:.4g}", lr=f"{self.optimizer.param_groups[0]['lr']:.3g}")
        return total / max(count, 1)

    @torch.no_grad()
    def _validate(self, epoch: int) -> tuple[float, float, float]:
        self.policy.eval()
        loss_sum, mse_sum, cos_sum, n = 0.0, 0.0, 0.0, 0
        bad: tuple[Batch, Tensor] | None = None
        batches = self.val_loader.epoch(0) if self.val_loader is not None else iter(())
        for batch in batches:
            batch = self._to_device(batch)
            x = batch.depth_x
            if self.cfg.optim.channels_last:
                x = x.contiguous(memory_format=torch.channels_last)
            y = self.policy.forward_prepared(
                x, batch.p_world_body, batch.v_world, batch.q_world_body, batch.goal_world
            )
            _, per = self._batch_loss(y, batch)
            if not bool(torch.isfinite(per).all()):
                if not self.dist.enabled:
                    raise self._nonfinite(epoch, batch, per, "validation loss")
                bad = (batch, per.cpu())  # reported by every rank together, after the all-reduce
                break
            ctrl = self.policy.decode(self.policy.select(y), batch.p_world_body, batch.q_world_body)
            ctrl = ctrl.cpu().numpy()
            expert = self.data.ctrl_world.index_select(0, torch.from_numpy(batch.indices)).numpy()
            loss_sum += float(per.sum())
            mse_sum += float(metrics.mse(ctrl, expert).sum())
            cos_sum += float(metrics.cosine_similarity(ctrl, expert).sum())
            n += len(per)
        if self.dist.enabled:
            loss_sum, mse_sum, cos_sum, total, num_bad = self.dist.all_reduce_sum(
                [loss_sum, mse_sum, cos_sum, n, 0 if bad is None else 1]
            )
            if num_bad > 0:
                raise self._dist_nonfinite(
                    epoch, *(bad if bad is not None else (None, None)), "validation loss"
                )
            n = int(total)
        return loss_sum / n, mse_sum / n, cos_sum / n

    def fit(self) -> TrainResult:
        if self._has_checkpoint:
            self._restore()
        main = self.dist.is_main
        if main:
            self._write_run_files()
        writer = None
        if self.cfg.log.tensorboard and main:
            from torch.utils.tensorboard import SummaryWriter

            # Every scalar is logged against the optimiser step (epoch scalars at the epoch's last step), so a
            # resumed run purges exactly what it redoes: the events after the checkpoint's step.
            writer = SummaryWriter(str(self.run_dir / "tensorboard"), purge_step=self.global_step + 1)
            self._writer = writer
        csv_path = self.run_dir / "metrics.csv"
        if main:
            _write_csv(csv_path, [r.row() for r in self.history])
        epochs = self.cfg.optim.epochs
        log = print if self.cfg.log.progress and main else (lambda *a, **k: None)
        log(
            f"[train] {self.run_dir}: {len(self.split.train_idx)} training / "
            f"{len(self.split.val_idx)} validation "
            f"samples ({len(self.split.train_episodes)} / {len(self.split.val_episodes)} episodes), "
            f"epochs {self.start_epoch + 1}..{epochs}",
            file=sys.stderr,
        )
        if self.dist.enabled:
            log(
                f"[train] distributed: {self.dist.world_size} processes ({self.dist.backend}, "
                f"{self.dist.device}), global batch {self.cfg.optim.batch_size} = "
                f"{self.dist.world_size} x {self.cfg.optim.batch_size // self.dist.world_size}, "
                f"{len(self.train_loader)} steps per epoch, "
                f"BatchNorm statistics {'global' if self.cfg.dist.sync_batchnorm else 'per process'}",
                file=sys.stderr,
            )
        try:
            for epoch in range(self.start_epoch + 1, epochs + 1):
                t0 = time.perf_counter()
                lr = self.optimizer.param_groups[0]["lr"]
                train_loss = self._train_epoch(epoch)
                val_loss, val_mse, val_cos = self._validate(epoch)
                rec = EpochRecord(
                    epoch,
                    self.global_step,
                    lr,
                    train_loss,
                    val_loss,
                    val_mse,
                    val_cos,
                    time.perf_counter() - t0,
                )
                self.history.append(rec)
                improved = val_loss < self.best_val_loss
                if improved:
                    self.best_val_loss, self.best_epoch = val_loss, epoch
                if not main:
                    continue
                _write_csv(csv_path, [r.row() for r in self.history])
                if writer is not None:
                    for k in ("train_loss", "val_loss", "val_mse_world_m2", "val_cosine_world"):
                        writer.add_scalar(f"epoch/{k}", getattr(rec, k), self.global_step)
                    writer.add_scalar("epoch/epoch", epoch, self.global_step)
                    writer.flush()
                ckpt = self._checkpoint(epoch)
                # best.pt before last.pt: a kill between the two leaves last.pt at the previous epoch, which
                # then redoes this one and rewrites best.pt identically.
                if improved:
                    save_checkpoint(ckpt, self.run_dir / "checkpoints" / "best.pt")
                save_checkpoint(ckpt, self.run_dir / "checkpoints" / "last.pt")
                log(
                    f"[train] epoch {epoch}/{epochs}: train {train_loss:.5g}, val {val_loss:.5g}, "
                    f"val MSE world {val_mse:.4g} m^2, cos {val_cos:.4f}, lr {lr:.3g}, "
                    f"{rec.epoch_wall_s:.1f} s{' (best)' if improved else ''}",
                    file=sys.stderr,
                )
        finally:
            if writer is not None:
                writer.close()
            self._writer = None
        if not main:
            result = TrainResult(self.run_dir, list(self.history), self.best_epoch, self.best_val_loss, None)
        else:
            result = self._finish()
        self.dist.barrier()  # the others wait for rank 0's export before the process group closes
        return result

    def _finish(self) -> TrainResult:
        policy_path = None
        if self.dist.enabled:
            revert_batchnorm(self.policy)  # plain BatchNorm2d for TorchScript
        if self.device.type != "cpu":
            self.policy = self.policy.cpu()
        summary: dict[str, Any] = {
            "best_epoch": self.best_epoch,
            "best_val_loss": self.best_val_loss,
            "epochs": len(self.history),
            "global_step": self.global_step,
        }
        if self.history:
            summary["last"] = self.history[-1].row()
        best = self.run_dir / "checkpoints" / "best.pt"
        if self.cfg.log.export_torchscript and best.is_file():
            ckpt = read_training_checkpoint(best, "best checkpoint")
            self.policy.load_state_dict(ckpt["model"])
            policy = self.policy.to(memory_format=torch.contiguous_format)
            idx = torch.from_numpy(self.split.val_idx[:8])
            depth = self.data.depth_x.index_select(0, idx).float() * self.cfg.model.max_depth_m
            check = (
                depth[:, 0],
                self.data.p_world_body.index_select(0, idx),
                self.data.v_world.index_select(0, idx),
                self.data.q_world_body.index_select(0, idx),
                self.data.goal_world.index_select(0, idx),
            )
            meta = policy_metadata(
                policy,
                self.cfg.model.model_dump(mode="json"),
                {
                    "run": {
                        "name": self.cfg.run.name,
                        "seed": self.cfg.run.seed,
                        "best_epoch": self.best_epoch,
                        "best_val_loss": self.best_val_loss,
                        "loss": self.cfg.optim.loss,
                        "software": software_info(),
                    },
                    "dataset": {
                        "format_version": self.data.format_version,
                        "train_world_seeds": sorted({s for s, _ in self.split.train_episodes}),
                        "val_world_seeds": sorted({s for s, _ in self.split.val_episodes}),
                    },
                },
            )
            policy_path = self.run_dir / "policy.ts"
            summary["export_max_abs_diff"] = export_torchscript(policy, policy_path, meta, check)
            summary["policy"] = str(policy_path)
        if self.cfg.log.plots and self.history:
            from quad_il.learning.plots import plot_loss_curves

            plot_loss_curves(
                [r.row() for r in self.history],
                self.run_dir / "loss_curves.png",
                f"{self.cfg.run.name}: {self.cfg.optim.loss.upper()} loss, "
                f"scheduler {self.cfg.scheduler.name}",
            )
        (self.run_dir / "summary.json").write_text(json.dumps(summary, indent=1))
        return TrainResult(self.run_dir, list(self.history), self.best_epoch, self.best_val_loss, policy_path)


# Model settings that change what the weights mean without changing their shapes.
_SEMANTIC_MODEL_KEYS = (
    "state_frame",
    "output_frame",
    "output",
    "output_prior",
    "velocity_input",
    "position_scale_m",
    "velocity_scale_mps",
    "max_depth_m",
)


def load_initial_weights(policy: Policy, path: str | Path, model_cfg: ModelConfig | None = None) -> None:
    """Start from a checkpoint's network weights (run.init_weights: fine-tuning, e.g. a DAgger round from the
    behaviour-cloned policy). The checkpoint's network must have exactly this run's parameter names and
    shapes, and (with `model_cfg`) the same frames, output, prior and input scales."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"run.init_weights: no such checkpoint file {p}")
    ckpt = read_training_checkpoint(p, "run.init_weights: checkpoint")
    if model_cfg is not None:
        stored = ModelConfig.model_validate(ckpt["config"]["model"])
        differ = [
            f"model.{k}: {getattr(stored, k)} -> {getattr(model_cfg, k)}"
            for k in _SEMANTIC_MODEL_KEYS
            if getattr(stored, k) != getattr(model_cfg, k)
        ]
        if differ:
            raise ValueError(
                f"run.init_weights: {p} was trained with other model settings ({'; '.join(differ)})"
            )
    own = policy.state_dict()
    theirs = ckpt["model"]
    missing = sorted(set(own) - set(theirs))
    extra = sorted(set(theirs) - set(own))
    shapes = sorted(k for k in set(own) & set(theirs) if tuple(own[k].shape) != tuple(theirs[k].shape))
    if missing or extra or shapes:
        raise ValueError(
            f"run.init_weights: {p} does not fit this model (missing {missing[:3]}, unexpected {extra[:3]}, "
            f"other shapes {shapes[:3]}): train with the checkpoint's model settings"
        )
    policy.load_state_dict(theirs)


def load_policy_checkpoint(path: str | Path) -> tuple[Policy, dict[str, Any]]:
    """A Policy (eval mode) rebuilt from a checkpoint's stored configuration and weights.

    Raises checkpoint.CheckpointError (a ValueError) naming the file when it is not a readable, safe
    training checkpoint."""
    ckpt = read_training_checkpoint(path, "checkpoint")
    cfg = TrainConfig.model_validate(ckpt["config"])
    policy = Policy(cfg.model, int(ckpt["num_ctrl_pts"]), float(ckpt["horizon_s"]))
    policy.load_state_dict(ckpt["model"])
    return policy.eval(), ckpt
