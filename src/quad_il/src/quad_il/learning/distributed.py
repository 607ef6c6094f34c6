"""Distributed data-parallel training (PyTorch DDP) for the trainer: environment, process group, collectives.

A run started by `torchrun --nproc_per_node=N train_on_cpp_datasets.py ...` (docs/scaling.md) has one process
per rank; `init_distributed` reads the environment torchrun sets (WORLD_SIZE, RANK, LOCAL_RANK,
LOCAL_WORLD_SIZE, MASTER_ADDR, MASTER_PORT), checks it and the configuration, and joins the process group
(gloo on CPU, nccl when CUDA is available, or as `dist.backend` says). Without those variables, or with a
world size of 1, it returns the single-process context, whose collectives are no-ops: the trainer then runs
exactly the single-process code (same numbers as before DDP existed).

How the work is divided (trainer.py): `optim.batch_size` is the GLOBAL batch. Each rank takes
batch_size / world_size samples per step from `GlobalBatchDistributedSampler`, a DistributedSampler whose
epoch permutation is the single-process loader's (numpy PCG64 seeded with (run.seed, epoch)) and whose
rank slices are strided, so the union of the ranks' k-th batches is exactly the single-process k-th batch.
DDP averages the gradients (= the gradient of the global batch's mean loss). By default BatchNorm uses each
process's statistics (plain DDP); with `dist.sync_batchnorm: true`, `CrossProcessBatchNorm2d` normalises
with the statistics of the global batch, and a DDP step is the single-process step up to floating-point
summation order and dropout masks (tested), at about twice the compute per CPU step (its normalisation is
not one fused kernel as nn.BatchNorm2d's).
"""

from __future__ import annotations

import datetime
import os
import pickle
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np
import torch
import torch.distributed as dist
from numpy.typing import NDArray
from torch import Tensor, nn
from torch.utils.data.distributed import DistributedSampler

from quad_il.learning.config import ConfigError, TrainConfig

T = TypeVar("T")
ENV_VARS = ("WORLD_SIZE", "RANK", "LOCAL_RANK", "LOCAL_WORLD_SIZE", "MASTER_ADDR", "MASTER_PORT")
_HOW = (
    "start the training with torchrun (docs/scaling.md), which sets them all, or by hand set RANK, "
    "WORLD_SIZE, LOCAL_RANK, LOCAL_WORLD_SIZE, MASTER_ADDR and MASTER_PORT consistently in every process"
)


class DistributedSetupError(ValueError):
    """The distributed environment or backend is unusable; the message names the variable or option."""


@dataclass(frozen=True)
class DistEnv:
    world_size: int
    rank: int
    local_rank: int
    local_world_size: int
    master_addr: str
    master_port: int


def _int_var(environ: Mapping[str, str], name: str) -> int | None:
    raw = environ.get(name)
    if raw is None or raw == "":
        return None
    try:
        return int(raw)
    except ValueError:
        raise DistributedSetupError(f"environment variable {name}={raw!r} is not an integer") from None


def read_dist_env(environ: Mapping[str, str]) -> DistEnv | None:
    """The launcher's environment, checked for consistency; None when no rank variable is set."""
    world = _int_var(environ, "WORLD_SIZE")
    rank = _int_var(environ, "RANK")
    local_rank = _int_var(environ, "LOCAL_RANK")
    local_world = _int_var(environ, "LOCAL_WORLD_SIZE")
    if world is None and rank is None and local_rank is None:
        return None
    if world is None:
        raise DistributedSetupError(f"WORLD_SIZE is not set but RANK/LOCAL_RANK are: {_HOW}")
    if rank is None:
        raise DistributedSetupError(f"RANK is not set but WORLD_SIZE={world} is: {_HOW}")
    if world < 1:
        raise DistributedSetupError(f"WORLD_SIZE={world} must be >= 1")
    if not 0 <= rank < world:
        raise DistributedSetupError(f"RANK={rank} is not in [0, WORLD_SIZE={world})")
    if world == 1:
        return DistEnv(1, 0, 0, 1, environ.get("MASTER_ADDR", ""), 0)
    if local_rank is None:
        raise DistributedSetupError(f"LOCAL_RANK is not set (WORLD_SIZE={world}, RANK={rank}): {_HOW}")
    if local_world is None:
        local_world = world
        if local_rank >= world:
            raise DistributedSetupError(f"LOCAL_RANK={local_rank} is not in [0, WORLD_SIZE={world})")
    if not 1 <= local_world <= world:
        raise DistributedSetupError(f"LOCAL_WORLD_SIZE={local_world} is not in [1, WORLD_SIZE={world}]")
    if not 0 <= local_rank < local_world:
        raise DistributedSetupError(f"LOCAL_RANK={local_rank} is not in [0, LOCAL_WORLD_SIZE={local_world})")
    if local_rank > rank:
        raise DistributedSetupError(f"LOCAL_RANK={local_rank} is larger than RANK={rank}")
    addr = environ.get("MASTER_ADDR", "")
    if not addr:
        raise DistributedSetupError(f"MASTER_ADDR is not set (WORLD_SIZE={world}): {_HOW}")
    port = _int_var(environ, "MASTER_PORT")
    if port is None:
        raise DistributedSetupError(f"MASTER_PORT is not set (WORLD_SIZE={world}): {_HOW}")
    if not 1 <= port <= 65535:
        raise DistributedSetupError(f"MASTER_PORT={port} is not a TCP port (1..65535)")
    return DistEnv(world, rank, local_rank, local_world, addr, port)


def choose_backend(requested: str) -> str:
    """'auto' -> nccl when CUDA and NCCL are available, else gloo; an explicit choice is checked."""
    cuda = torch.cuda.is_available()
    if requested == "auto":
        return "nccl" if cuda and dist.is_nccl_available() else "gloo"
    if requested == "nccl":
        if not cuda:
            raise DistributedSetupError("dist.backend=nccl needs CUDA, which is not available here: use gloo")
        if not dist.is_nccl_available():
            raise DistributedSetupError("dist.backend=nccl: this torch build has no NCCL: use gloo")
    elif requested == "gloo" and not dist.is_gloo_available():
        raise DistributedSetupError("dist.backend=gloo: this torch build has no gloo")
    return requested


def check_batch_division(global_batch: int, world_size: int) -> int:
    """optim.batch_size is the global batch: it must split into equal per-process batches of >= 2."""
    if global_batch % world_size:
        raise ConfigError(
            f"optim.batch_size={global_batch} (the global batch) is not divisible by the world size "
            f"{world_size}: use a multiple of {world_size}, "
            f"e.g. {world_size * max(2, global_batch // world_size)}"
        )
    per_process = global_batch // world_size
    if per_process < 2:
        raise ConfigError(
            f"optim.batch_size={global_batch} over {world_size} processes leaves {per_process} sample per "
            f"process; BatchNorm needs >= 2: use optim.batch_size >= {2 * world_size}"
        )
    return per_process


class DistContext:
    """This process's place in the run. `DistContext()` is the single process (collectives are no-ops)."""

    def __init__(
        self,
        world_size: int = 1,
        rank: int = 0,
        local_rank: int = 0,
        local_world_size: int = 1,
        backend: str = "none",
        device: torch.device | None = None,
        bn_group: Any = None,
    ) -> None:
        self.world_size = world_size
        self.rank = rank
        self.local_rank = local_rank
        self.local_world_size = local_world_size
        self.backend = backend
        self.device = device if device is not None else torch.device("cpu")
        self.bn_group = bn_group

    @property
    def enabled(self) -> bool:
        return self.world_size > 1

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    @property
    def tag(self) -> str:
        """' (rank r/W)' for messages of a distributed run, '' for a single process."""
        return f" (rank {self.rank}/{self.world_size})" if self.enabled else ""

    def describe(self) -> dict[str, Any]:
        return {
            "world_size": self.world_size,
            "backend": self.backend,
            "device": str(self.device),
            "local_world_size": self.local_world_size,
        }

    # -------------------------------------------------------------------------------------------- collectives
    def all_reduce_sum(self, values: Sequence[float | Tensor]) -> list[float]:
        """Element-wise sum over all ranks, in float64 (the values themselves for a single process)."""
        t = torch.tensor([float(v) for v in values], dtype=torch.float64)
        if self.enabled:
            t = t.to(self.device)
            dist.all_reduce(t)
        return t.cpu().tolist()

    def broadcast_object(self, obj: T) -> T:
        """Rank 0's `obj` on every rank."""
        if not self.enabled:
            return obj
        box = [obj]
        dist.broadcast_object_list(box, src=0, device=self.device if self.backend == "nccl" else None)
        return box[0]

    def all_gather_object(self, obj: Any) -> list[Any]:
        if not self.enabled:
            return [obj]
        out: list[Any] = [None] * self.world_size
        dist.all_gather_object(out, obj)
        return out

    def run_on_main(self, fn: Callable[[], T]) -> T:
        """`fn()` on rank 0 only (e.g. reading the run directory); its result, or its exception, on every
        rank, so that all ranks fail together with the same message instead of waiting for each other."""
        if not self.enabled:
            return fn()
        outcome: tuple[str, Any] = ("ok", None)
        if self.is_main:
            try:
                outcome = ("ok", fn())
            except Exception as e:  # noqa: BLE001 - re-raised on every rank below
                try:
                    pickle.dumps(e)
                    outcome = ("error", e)
                except Exception:  # noqa: BLE001
                    outcome = ("error", RuntimeError(f"{type(e).__name__}: {e}"))
        kind, value = self.broadcast_object(outcome)
        if kind == "error":
            raise value
        return value

    def barrier(self) -> None:
        if self.enabled:
            dist.barrier()

    def close(self) -> None:
        if self.enabled and dist.is_initialized():
            dist.destroy_process_group()


SINGLE_PROCESS = DistContext()


def init_distributed(cfg: TrainConfig, environ: Mapping[str, str] | None = None) -> DistContext:
    """Check the environment and the configuration, then join the process group (world size > 1)."""
    env = read_dist_env(os.environ if environ is None else environ)
    if env is None or env.world_size == 1:
        return SINGLE_PROCESS
    check_batch_division(cfg.optim.batch_size, env.world_size)
    backend = choose_backend(cfg.dist.backend)
    if backend == "nccl":
        if env.local_rank >= torch.cuda.device_count():
            raise DistributedSetupError(
                f"LOCAL_RANK={env.local_rank} but only {torch.cuda.device_count()} CUDA device(s) on this "
                "node: start at most one process per GPU (--nproc_per_node)"
            )
        device = torch.device("cuda", env.local_rank)
        torch.cuda.set_device(device)
    else:
        device = torch.device("cpu")
    dist.init_process_group(
        backend,
        init_method="env://",
        world_size=env.world_size,
        rank=env.rank,
        timeout=datetime.timedelta(seconds=cfg.dist.timeout_s),
    )
    # A group of its own for the BatchNorm statistics, so that its collectives never interleave with DDP's
    # gradient buckets on the default group. Created on every rank in the same order, used or not.
    bn_group = dist.new_group(backend=backend)
    return DistContext(
        env.world_size, env.rank, env.local_rank, env.local_world_size, backend, device, bn_group
    )


def rank_seed(seed: int, epoch: int, rank: int) -> int:
    """Seed of a rank's torch RNG (dropout) for an epoch under DDP: distinct per rank, reproducible, and the
    same after a resumption (so no per-rank RNG state needs checkpointing)."""
    return int(np.random.default_rng([seed, epoch, rank, 0xD1D9]).integers(0, 2**63 - 1))


# ------------------------------------------------------------------------------------------------ sampling
class GlobalBatchDistributedSampler(DistributedSampler):
    """DistributedSampler over dataset indices with the single-process batch order.

    Epoch e (`set_epoch(e)`) permutes `indices` with numpy's PCG64 seeded with (seed, e), exactly like
    `BatchLoader.order`, keeps the first floor(n / global_batch) * global_batch positions (the
    single-process loader drops the last incomplete batch too) and gives rank r the positions r, r + W,
    r + 2W, ... Consecutive runs of batch_size / W of a rank's indices are its batches, and the union of
    the ranks' k-th batches is the permutation's k-th block of `global_batch`: the single-process batch.
    """

    def __init__(
        self, indices: NDArray[np.int64], num_replicas: int, rank: int, seed: int, global_batch: int
    ) -> None:
        super().__init__(
            indices, num_replicas=num_replicas, rank=rank, shuffle=True, seed=seed, drop_last=True
        )
        self.indices = np.asarray(indices, dtype=np.int64)
        self.global_batch = global_batch
        self.steps = len(self.indices) // global_batch
        if self.steps < 1:
            raise ConfigError(
                f"{len(self.indices)} training samples are fewer than the global batch "
                f"optim.batch_size={global_batch}: lower it or use more data"
            )
        self.num_samples = self.steps * global_batch // num_replicas
        self.total_size = self.steps * global_batch

    def epoch_indices(self) -> NDArray[np.int64]:
        perm = np.random.default_rng([self.seed, self.epoch]).permutation(len(self.indices))
        used = self.indices[perm[: self.total_size]]
        return used[self.rank :: self.num_replicas]

    def __iter__(self) -> Iterator[int]:
        return iter(self.epoch_indices().tolist())

    def __len__(self) -> int:
        return self.num_samples


# --------------------------------------------------------------------------------------------- batchnorm
class _AllReduceSum(torch.autograd.Function):
    """Differentiable sum over ranks: y = sum_r x_r on every rank, so dL/dx_r = sum over ranks of dL_r/dy."""

    @staticmethod
    def forward(ctx: Any, x: Tensor, group: Any) -> Tensor:  # type: ignore[override]
        ctx.group = group
        y = x.clone(memory_format=torch.contiguous_format)
        dist.all_reduce(y, group=group)
        return y

    @staticmethod
    def backward(ctx: Any, grad: Tensor) -> tuple[Tensor, None]:  # type: ignore[override]
        g = grad.clone(memory_format=torch.contiguous_format)
        dist.all_reduce(g, group=ctx.group)
        return g, None


def all_reduce_sum_autograd(x: Tensor, group: Any) -> Tensor:
    return _AllReduceSum.apply(x, group)  # type: ignore[no-any-return]


class CrossProcessBatchNorm2d(nn.BatchNorm2d):
    """BatchNorm2d whose training-mode statistics are those of the global batch (all ranks' samples).

    Same parameters, buffers and state-dict keys as nn.BatchNorm2d (modules are converted in place by
    switching their class); evaluation mode is nn.BatchNorm2d's. The sums go through a differentiable
    all-reduce, so the gradient flows through the statistics of every rank, as in the single-process batch.
    One small all-reduce per layer and pass (per-channel sum and sum of squares in float64, and the
    count). torch's SyncBatchNorm does this for GPUs only;
    this one works on CPU (gloo) too.
    """

    process_group: Any = None

    def forward(self, x: Tensor) -> Tensor:
        if not self.training or self.process_group is None:
            return super().forward(x)
        c = x.shape[1]
        # One all-reduce per layer and pass: sum, sum of squares and count, accumulated in float64 so that
        # E[x^2] - E[x]^2 loses nothing that matters at float32.
        xd = x.double()
        local = torch.cat(
            [xd.sum(dim=(0, 2, 3)), (xd * xd).sum(dim=(0, 2, 3)), xd.new_full((1,), float(x.numel() // c))]
        )
        stats = all_reduce_sum_autograd(local, self.process_group)
        count = stats[2 * c]
        mean64 = stats[:c] / count
        var = (stats[c : 2 * c] / count - mean64 * mean64).clamp_min(0.0).to(x.dtype)
        mean = mean64.to(x.dtype)
        centred = x - mean.view(1, c, 1, 1)
        y = centred * torch.rsqrt(var + self.eps).view(1, c, 1, 1)
        if self.affine:
            y = y * self.weight.view(1, c, 1, 1) + self.bias.view(1, c, 1, 1)
        if self.track_running_stats and self.running_mean is not None and self.running_var is not None:
            with torch.no_grad():
                assert self.num_batches_tracked is not None
                self.num_batches_tracked.add_(1)
                m = 1.0 / float(self.num_batches_tracked) if self.momentum is None else float(self.momentum)
                n = float(count)
                unbiased = var.detach() * (n / max(n - 1.0, 1.0))
                self.running_mean.mul_(1.0 - m).add_(mean.detach(), alpha=m)
                self.running_var.mul_(1.0 - m).add_(unbiased, alpha=m)
        return y


def convert_batchnorm(module: nn.Module, group: Any) -> int:
    """Every nn.BatchNorm2d in `module` -> CrossProcessBatchNorm2d on `group`, in place; returns the count."""
    n = 0
    for m in module.modules():
        if type(m) is nn.BatchNorm2d:
            m.__class__ = CrossProcessBatchNorm2d
            m.process_group = group
            n += 1
    return n


def revert_batchnorm(module: nn.Module) -> None:
    """Undo `convert_batchnorm` (before TorchScript export)."""
    for m in module.modules():
        if type(m) is CrossProcessBatchNorm2d:
            del m.process_group
            m.__class__ = nn.BatchNorm2d
