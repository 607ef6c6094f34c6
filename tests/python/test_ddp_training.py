"""Distributed data-parallel training (issue 9, Scale; docs/scaling.md).

Fast checks of the pieces (environment validation, the global-batch sampler, cross-process BatchNorm), then
real 2-process gloo runs of train_on_cpp_datasets.py under torchrun compared with the 1-process run.

Tolerance of the 1-process vs 2-process comparison: relative 1e-5 on every epoch's training and validation
loss, with SGD and no dropout. The two runs see the same global batches, DDP averages the gradients and the
BatchNorm statistics are the global batch's, so the arithmetic is the same up to floating-point summation
order (measured: <= 1e-7 relative on the losses, weights and BatchNorm buffers within 4e-6). The tolerance
is 100x that, and still 20x below what a real difference makes: with per-process BatchNorm statistics
(dist.sync_batchnorm=false) the same comparison differs by 2e-4 on the 4th epoch's validation loss and by
0.26 on running variances (the weight check below catches it too). Adam is not used here: it divides
each gradient by its own magnitude, so parameters whose gradient is rounding noise take full-size steps in
random directions; a single process with 1 or 2 threads already differs by ~3 % after 36 Adam steps
(docs/scaling.md).

This file is also the torchrun worker of those runs (`__main__` below): it records, per rank, every file
the training opens for writing, renames or saves, so the test can check that only rank 0 writes.
"""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
from torch import nn

ROOT = Path(__file__).resolve().parents[2]
SRC = ROOT / "src" / "quad_il" / "src"
SCRIPT = ROOT / "training_only" / "train_on_cpp_datasets.py"
if str(SRC) not in sys.path:
    sys.path.insert(0, str(SRC))

from quad_il.learning.checkpoint import read_training_checkpoint  # noqa: E402
from quad_il.learning.config import ConfigError, load_config  # noqa: E402
from quad_il.learning.dataset import BatchLoader  # noqa: E402
from quad_il.learning.distributed import (  # noqa: E402
    CrossProcessBatchNorm2d,
    DistributedSetupError,
    GlobalBatchDistributedSampler,
    check_batch_division,
    choose_backend,
    convert_batchnorm,
    read_dist_env,
    revert_batchnorm,
)

REL_TOL = 1e-5
GOOD_ENV = {
    "WORLD_SIZE": "2",
    "RANK": "1",
    "LOCAL_RANK": "1",
    "LOCAL_WORLD_SIZE": "2",
    "MASTER_ADDR": "127.0.0.1",
    "MASTER_PORT": "29500",
}


# ------------------------------------------------------------------------------------------- environment
def test_no_launcher_variables_means_a_single_process() -> None:
    assert read_dist_env({}) is None
    assert read_dist_env({"WORLD_SIZE": "1", "RANK": "0"}).world_size == 1  # type: ignore[union-attr]
    env = read_dist_env(GOOD_ENV)
    assert env is not None and (env.world_size, env.rank, env.local_rank, env.master_port) == (2, 1, 1, 29500)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"WORLD_SIZE": None}, r"WORLD_SIZE is not set but RANK/LOCAL_RANK are"),
        ({"RANK": None}, r"RANK is not set but WORLD_SIZE=2 is"),
        ({"RANK": "2"}, r"RANK=2 is not in \[0, WORLD_SIZE=2\)"),
        ({"WORLD_SIZE": "two"}, r"WORLD_SIZE='two' is not an integer"),
        ({"LOCAL_RANK": None}, r"LOCAL_RANK is not set"),
        ({"LOCAL_RANK": "2"}, r"LOCAL_RANK=2 is not in \[0, LOCAL_WORLD_SIZE=2\)"),
        ({"LOCAL_WORLD_SIZE": "3"}, r"LOCAL_WORLD_SIZE=3 is not in \[1, WORLD_SIZE=2\]"),
        ({"RANK": "0"}, r"LOCAL_RANK=1 is larger than RANK=0"),
        ({"MASTER_ADDR": None}, r"MASTER_ADDR is not set"),
        ({"MASTER_PORT": "70000"}, r"MASTER_PORT=70000 is not a TCP port"),
    ],
)
def test_inconsistent_launcher_variables_are_named(change: dict[str, str | None], message: str) -> None:
    env = {**GOOD_ENV, **change}
    with pytest.raises(DistributedSetupError, match=message):
        read_dist_env({k: v for k, v in env.items() if v is not None})


def test_global_batch_must_divide_among_the_processes() -> None:
    assert check_batch_division(32, 2) == 16
    with pytest.raises(ConfigError, match=r"optim.batch_size=30 .* not divisible by the world size 4"):
        check_batch_division(30, 4)
    with pytest.raises(ConfigError, match=r"leaves 1 sample per process; BatchNorm needs >= 2"):
        check_batch_division(4, 4)


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the error on a machine without CUDA")
def test_nccl_without_cuda_is_refused_and_auto_picks_gloo() -> None:
    assert choose_backend("auto") == "gloo"
    with pytest.raises(DistributedSetupError, match=r"dist.backend=nccl needs CUDA"):
        choose_backend("nccl")


def test_script_rejects_bad_environment_and_indivisible_batch_before_joining(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    sys.path.insert(0, str(SCRIPT.parent))
    try:
        script = __import__(SCRIPT.stem)
    finally:
        sys.path.pop(0)
    args = ["--data", str(tmp_path), "--out", str(tmp_path), "--set", "optim.batch_size=8"]
    env = {**GOOD_ENV, "WORLD_SIZE": "3", "RANK": "0", "LOCAL_RANK": "0", "LOCAL_WORLD_SIZE": "3"}
    assert script.main(args, environ=env) == 2  # would block in init_process_group if not checked first
    assert (
        "optim.batch_size=8 (the global batch) is not divisible by the world size 3"
        in capsys.readouterr().err
    )
    assert script.main(args, environ={**GOOD_ENV, "RANK": "5"}) == 2
    assert "RANK=5 is not in [0, WORLD_SIZE=2)" in capsys.readouterr().err


# ---------------------------------------------------------------------------------------------- sampling
@pytest.mark.parametrize("world", [2, 4])
def test_ranks_batches_together_are_the_single_process_batches(world: int) -> None:
    indices = np.arange(3, 3 + 70, dtype=np.int64) * 2  # arbitrary dataset indices
    global_batch = 8
    per = global_batch // world
    single = BatchLoader.__new__(BatchLoader)  # only its order(): the single-process permutation
    single.indices, single.shuffle, single.seed = indices, True, 7
    for epoch in (1, 2):
        order = single.order(epoch)
        samplers = [GlobalBatchDistributedSampler(indices, world, r, 7, global_batch) for r in range(world)]
        per_rank = []
        for s in samplers:
            s.set_epoch(epoch)
            got = np.fromiter(iter(s), dtype=np.int64)
            assert len(got) == len(s) == (70 // global_batch) * per
            per_rank.append(got)
        for k in range(70 // global_batch):
            together = np.concatenate([r[k * per : (k + 1) * per] for r in per_rank])
            assert sorted(together) == sorted(order[k * global_batch : (k + 1) * global_batch])
    s = GlobalBatchDistributedSampler(indices, world, 0, 7, global_batch)
    s.set_epoch(1)
    first = list(s)
    s.set_epoch(2)
    assert list(s) != first
    with pytest.raises(ConfigError, match=r"70 training samples are fewer than the global batch"):
        GlobalBatchDistributedSampler(indices, world, 0, 7, 128)


# --------------------------------------------------------------------------------------------- batchnorm
def test_cross_process_batchnorm_equals_batchnorm_in_a_group_of_one(tmp_path: Path) -> None:
    """Forward, gradients and running statistics equal nn.BatchNorm2d's (world of 1: the all-reduce is the
    identity, so this checks the formula; the 2-process runs below check the cross-process part)."""
    import torch.distributed as dist

    assert not dist.is_initialized()
    dist.init_process_group("gloo", init_method=f"file://{tmp_path / 'store'}", rank=0, world_size=1)
    try:
        torch.manual_seed(0)
        ref = nn.Sequential(nn.Conv2d(2, 4, 3), nn.BatchNorm2d(4, eps=1e-3, momentum=0.01))
        ours = nn.Sequential(nn.Conv2d(2, 4, 3), nn.BatchNorm2d(4, eps=1e-3, momentum=0.01))
        ours.load_state_dict(ref.state_dict())
        assert convert_batchnorm(ours, dist.new_group(backend="gloo")) == 1
        assert type(ours[1]) is CrossProcessBatchNorm2d
        x = torch.randn(5, 2, 7, 6) * 3 + 1
        for _ in range(2):
            ya, yb = ref(x), ours(x)
            torch.testing.assert_close(yb, ya, rtol=1e-5, atol=1e-5)
            (ya * torch.arange(ya.numel()).view_as(ya)).sum().backward()
            (yb * torch.arange(yb.numel()).view_as(yb)).sum().backward()
        for (name, a), b in zip(ref.named_parameters(), ours.parameters(), strict=True):
            # Gradients are up to ~1e4 here; the conv bias's is analytically 0 (BatchNorm removes the mean),
            # so both are rounding noise of ~1e-3: absolute tolerance 1e-6 of the gradients' scale.
            torch.testing.assert_close(b.grad, a.grad, rtol=1e-4, atol=1e-2, msg=name)
        for key, value in ref.state_dict().items():
            torch.testing.assert_close(ours.state_dict()[key], value, rtol=1e-5, atol=1e-6, msg=key)
        revert_batchnorm(ours)
        assert type(ours[1]) is nn.BatchNorm2d and ours.eval() is not None
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            torch.jit.script(ours)  # scriptable again for the export
    finally:
        dist.destroy_process_group()


# ----------------------------------------------------------------------------------- 2-process gloo runs
COMMON = [
    "--config",
    str(ROOT / "config" / "train.yaml"),
    "--set",
    "model.input_height=32",
    "--set",
    "model.input_width=32",
    "--set",
    "optim.batch_size=8",
    "--set",
    "optim.optimizer=sgd",
    "--set",
    "optim.lr=0.01",
    "--set",
    "scheduler.name=none",
    "--set",
    "model.backbone_dropout=0",
    "--set",
    "model.output_frame=local",
    "--set",
    "model.state_frame=local",
    "--set",
    "run.num_threads=1",
    "--set",
    "log.progress=false",
    "--set",
    "log.plots=false",
    "--set",
    "data.hash_files=false",
    "--set",
    "dist.sync_batchnorm=true",
]
LOSS_COLUMNS = [
    "epoch",
    "global_step",
    "lr",
    "train_loss",
    "val_loss",
    "val_mse_world_m2",
    "val_cosine_world",
]


def _rows(run_dir: Path) -> list[dict[str, str]]:
    with open(run_dir / "metrics.csv") as f:
        return list(csv.DictReader(f))


def _torchrun(args: list[str], writes_dir: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": f"{SRC}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    cmd = [
        sys.executable,
        "-m",
        "torch.distributed.run",
        "--standalone",
        "--nproc_per_node=2",
        str(Path(__file__).resolve()),
        str(writes_dir),
        *args,
    ]
    return subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A 1-process run, a 2-process run, and a 2-process run interrupted after epoch 1 and resumed."""
    from quad_il.learning.synthetic import write_synthetic_npz

    sys.path.insert(0, str(SCRIPT.parent))
    try:
        script = __import__(SCRIPT.stem)
    finally:
        sys.path.pop(0)
    tmp = tmp_path_factory.mktemp("ddp")
    data = write_synthetic_npz(tmp / "d.npz", num_episodes=10, samples_per_episode=8, height=32, width=32)
    base = [*COMMON, "--data", str(data), "--out", str(tmp / "runs"), "--epochs", "4"]
    assert script.main([*base, "--name", "one"], environ={}) == 0
    out: dict[str, Path] = {"one": tmp / "runs" / "one", "data": data, "tmp": tmp}
    for name, extra in (
        ("two", []),
        (
            "split",
            ["--epochs", "1", "--set", "log.tensorboard=false", "--set", "log.export_torchscript=false"],
        ),
    ):
        proc = _torchrun([*base, "--name", name, *extra], tmp / f"writes_{name}")
        assert proc.returncode == 0, proc.stderr[-4000:]
        out[name] = tmp / "runs" / name
    proc = _torchrun([*base, "--name", "split", "--resume"], tmp / "writes_resume")
    assert proc.returncode == 0, proc.stderr[-4000:]
    return out


def test_two_processes_train_as_one_within_tolerance(runs: dict[str, Path]) -> None:
    one, two = _rows(runs["one"]), _rows(runs["two"])
    assert len(one) == len(two) == 4
    for a, b in zip(one, two, strict=True):
        assert (a["epoch"], a["global_step"], a["lr"]) == (b["epoch"], b["global_step"], b["lr"])
        for col in ("train_loss", "val_loss", "val_mse_world_m2"):
            assert float(b[col]) == pytest.approx(float(a[col]), rel=REL_TOL), (a["epoch"], col)
    assert float(one[-1]["val_loss"]) < float(one[0]["val_loss"])  # it did learn something
    wa = read_training_checkpoint(runs["one"] / "checkpoints" / "last.pt")["model"]
    wb = read_training_checkpoint(runs["two"] / "checkpoints" / "last.pt")["model"]
    for key, value in wa.items():
        if value.is_floating_point():
            torch.testing.assert_close(wb[key], value, rtol=1e-4, atol=1e-5, msg=key)


def test_logged_validation_loss_is_the_global_one(runs: dict[str, Path]) -> None:
    """The 2-process run's logged validation loss equals a single process evaluating rank 0's final model
    on the WHOLE validation set (each rank evaluated half of it; the sums were all-reduced)."""
    from quad_il.learning.trainer import Trainer

    run = runs["two"]
    cfg = load_config([run / "config.yaml"], [f"run.out_dir={str(runs['tmp'] / 'eval')!r}", "run.name=eval"])
    trainer = Trainer(cfg)
    trainer.policy.load_state_dict(read_training_checkpoint(run / "checkpoints" / "last.pt")["model"])
    val_loss, val_mse, val_cos = trainer._validate(4)
    last = _rows(run)[-1]
    assert float(last["val_loss"]) == pytest.approx(val_loss, rel=1e-6)
    assert float(last["val_mse_world_m2"]) == pytest.approx(val_mse, rel=1e-6)
    assert float(last["val_cosine_world"]) == pytest.approx(val_cos, rel=1e-6, abs=1e-7)


def test_only_rank_zero_writes_the_run_directory(runs: dict[str, Path]) -> None:
    for name in ("two", "split", "resume"):
        rank0 = json.loads((runs["tmp"] / f"writes_{name}" / "rank0.json").read_text())
        rank1 = json.loads((runs["tmp"] / f"writes_{name}" / "rank1.json").read_text())
        assert rank1 == [], (name, rank1)
        written = {Path(p).name for p in rank0}
        assert {"metrics.csv", "last.pt", "config.yaml", "run_info.json"} <= written, (name, written)
    rank0 = json.loads((runs["tmp"] / "writes_two" / "rank0.json").read_text())
    assert "policy.ts" in {Path(p).name for p in rank0}
    assert any("tfevents" in p for p in rank0)
    info = json.loads((runs["two"] / "run_info.json").read_text())
    assert info["world_size"] == 2
    assert info["distributed"]["per_process_batch"] == 4 and info["distributed"]["backend"] == "gloo"
    summary = json.loads((runs["two"] / "summary.json").read_text())
    assert summary["export_max_abs_diff"] <= 1e-4


def test_resume_under_ddp_continues_the_same_curve(runs: dict[str, Path]) -> None:
    straight, resumed = _rows(runs["two"]), _rows(runs["split"])
    assert [[r[c] for c in LOSS_COLUMNS] for r in resumed] == [[r[c] for c in LOSS_COLUMNS] for r in straight]
    info = json.loads((runs["split"] / "run_info.json").read_text())
    assert info["resumptions"][0]["from_epoch"] == 1 and info["resumptions"][0]["world_size"] == 2


# --------------------------------------------------------------------------------- the torchrun worker
def _worker(writes_dir: Path, argv: list[str]) -> int:
    """Run the training script, recording every path this rank writes (open for writing, rename/replace,
    mkdir, torch.save, torch.jit.save) under the run's parent directory."""
    out_dir = Path(argv[argv.index("--out") + 1]).resolve()
    written: list[str] = []
    recording = [True]

    def note(path: object) -> None:
        if recording[0] and isinstance(path, str | bytes | os.PathLike):
            p = os.fsdecode(path)
            if Path(p).resolve().is_relative_to(out_dir):
                written.append(p)

    write_flags = os.O_WRONLY | os.O_RDWR | os.O_CREAT | os.O_APPEND | os.O_TRUNC

    def hook(event: str, args: tuple) -> None:  # type: ignore[type-arg]
        if event == "open" and len(args) >= 3:
            path, mode, flags = args[0], args[1], args[2]
            if (isinstance(mode, str) and any(c in mode for c in "wax+")) or (
                mode is None and isinstance(flags, int) and flags & write_flags
            ):
                note(path)
        elif event in ("os.rename", "os.mkdir", "os.remove", "os.truncate"):
            note(args[1] if event == "os.rename" else args[0])

    sys.addaudithook(hook)
    real_save, real_jit_save = torch.save, torch.jit.save

    def save(obj, f, *a, **k):  # type: ignore[no-untyped-def]
        note(f)
        return real_save(obj, f, *a, **k)

    def jit_save(m, f, *a, **k):  # type: ignore[no-untyped-def]
        note(f)
        return real_jit_save(m, f, *a, **k)

    torch.save, torch.jit.save = save, jit_save  # type: ignore[assignment]
    sys.path.insert(0, str(SCRIPT.parent))
    script = __import__(SCRIPT.stem)
    rc = script.main(argv)
    recording[0] = False
    writes_dir.mkdir(parents=True, exist_ok=True)
    (writes_dir / f"rank{os.environ['RANK']}.json").write_text(json.dumps(sorted(set(written))))
    return rc


if __name__ == "__main__":
    sys.exit(_worker(Path(sys.argv[1]), sys.argv[2:]))
