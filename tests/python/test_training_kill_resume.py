"""Fault test (issue 30): SIGKILL during training, then --resume, ends with the same weights as an
uninterrupted run, bit for bit (deterministic mode), and a kill while a checkpoint is written never leaves a
torn last.pt.

Every run is `training_only/train_on_cpp_datasets.py` in its own process, as a user runs it. The kills wait on
what the process prints (the start line, the progress bar of a given epoch), never on a sleep.
"""

from __future__ import annotations

import os
import queue
import re
import shutil
import signal
import subprocess
import sys
import threading
from collections.abc import Callable
from pathlib import Path

import pytest
import torch

from quad_il.learning.checkpoint import CheckpointError, read_training_checkpoint
from quad_il.learning.synthetic import write_synthetic_npz

ROOT = Path(__file__).resolve().parents[2]
SRC = ROOT / "src" / "quad_il" / "src"
SCRIPT = ROOT / "training_only" / "train_on_cpp_datasets.py"
EPOCHS = 3
# A safety net against a hung child only; every wait below ends on a printed line or the process's exit.
HANG_S = 240.0
# Settings that make every kind of state matter on resume: dropout (torch RNG), a learning rate that changes
# every step (scheduler state), Adam's moments, mirrored samples, threads preparing batches. A small network
# in the default memory layout on one thread keeps each run to seconds on a shared 2-core machine (with
# channels_last, the default, the first epoch alone takes 5-25 s here; the test also passes with it).
OVERRIDES = [
    "run.num_threads=1",
    "model.input_height=32",
    "model.input_width=32",
    "model.backbone_out=32",
    "optim.channels_last=false",
    "optim.batch_size=8",
    "scheduler.custom.first_decay_steps=7",
    "data.mirror_probability=0.5",
    "data.num_workers=1",
    "log.progress=true",
    "log.tensorboard=false",
    "log.export_torchscript=false",
    "log.plots=false",
]


def _args(data: Path, out: Path, name: str, *extra: str) -> list[str]:
    args = ["--config", str(ROOT / "config" / "train.yaml"), "--data", str(data), "--out", str(out)]
    args += ["--name", name, "--epochs", str(EPOCHS)]
    for o in OVERRIDES:
        args += ["--set", o]
    return [*args, *extra]


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": f"{SRC}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}


def _run_to_end(cmd: list[str]) -> None:
    proc = subprocess.run(cmd, env=_env(), capture_output=True, text=True, timeout=HANG_S)
    assert proc.returncode == 0, proc.stderr[-4000:]


def _kill_when(cmd: list[str], seen: Callable[[str], bool]) -> str:
    """Start `cmd`, SIGKILL it as soon as a line of its stderr satisfies `seen`; returns that line.

    tqdm redraws its bar with carriage returns, which text mode reads as line ends: every redraw is a line."""
    proc = subprocess.Popen(cmd, env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    lines: queue.Queue[str | None] = queue.Queue()

    def pump() -> None:
        assert proc.stderr is not None
        for line in proc.stderr:
            lines.put(line)
        lines.put(None)

    threading.Thread(target=pump, daemon=True).start()
    log: list[str] = []
    try:
        while True:
            line = lines.get(timeout=HANG_S)
            if line is None:
                pytest.fail(
                    f"the run ended (exit {proc.wait()}) before the kill point:\n{''.join(log)[-3000:]}"
                )
            log.append(line)
            if seen(line):
                os.kill(proc.pid, signal.SIGKILL)
                break
    finally:
        if proc.poll() is None:  # also when the wait above failed
            os.kill(proc.pid, signal.SIGKILL)
        rc = proc.wait()
    assert rc == -signal.SIGKILL, f"exit {rc}, not killed:\n{''.join(log)[-3000:]}"
    return line


def _tensors(obj: object, prefix: str = "") -> dict[str, torch.Tensor]:
    """Every tensor in a checkpoint's nested dicts and lists, by path."""
    out: dict[str, torch.Tensor] = {}
    if isinstance(obj, torch.Tensor):
        out[prefix] = obj
    elif isinstance(obj, dict):
        for k, v in obj.items():
            out.update(_tensors(v, f"{prefix}/{k}"))
    elif isinstance(obj, list | tuple):
        for i, v in enumerate(obj):
            out.update(_tensors(v, f"{prefix}/{i}"))
    return out


def _assert_bitwise_equal(run: Path, straight: Path) -> None:
    for name in ("last.pt", "best.pt"):
        a = read_training_checkpoint(run / "checkpoints" / name)
        b = read_training_checkpoint(straight / "checkpoints" / name)
        for key in ("epoch", "global_step", "best_epoch", "best_val_loss", "scheduler"):
            assert a[key] == b[key], (name, key)
        ta = _tensors({k: a[k] for k in ("model", "optimizer", "rng")})
        tb = _tensors({k: b[k] for k in ("model", "optimizer", "rng")})
        assert ta.keys() == tb.keys() and len(ta) > 100, name
        different = [k for k in ta if ta[k].dtype != tb[k].dtype or not torch.equal(ta[k], tb[k])]
        assert not different, f"{name}: {len(different)} tensors differ, e.g. {different[:5]}"
    assert _csv_losses(run) == _csv_losses(straight)


def _csv_losses(run: Path) -> list[list[str]]:
    """metrics.csv without the wall-clock column."""
    rows = [line.split(",") for line in (run / "metrics.csv").read_text().splitlines()]
    return [r[:-1] for r in rows]


# The training script (argv[1:]), patched so that the process SIGKILLs itself in its first optimiser step.
_KILL_IN_FIRST_STEP = """
import os, runpy, signal, sys
import torch
def step(self, *args, **kwargs):
    os.kill(os.getpid(), signal.SIGKILL)
torch.optim.Adam.step = step
sys.argv = sys.argv[1:]
runpy.run_path(sys.argv[0], run_name="__main__")
"""


@pytest.fixture(scope="module")
def setup(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    tmp = tmp_path_factory.mktemp("kill")
    # 6 episodes of 8 samples: 5 or 6 training steps per epoch, so the progress bar shows steps mid-epoch.
    data = write_synthetic_npz(tmp / "d.npz", num_episodes=6, samples_per_episode=8, height=32, width=32)
    _run_to_end([sys.executable, str(SCRIPT), *_args(data, tmp / "runs", "straight")])
    return {"data": data, "runs": tmp / "runs", "straight": tmp / "runs" / "straight"}


def test_sigkill_then_resume_gives_bitwise_the_uninterrupted_weights(setup: dict[str, Path]) -> None:
    data, runs = setup["data"], setup["runs"]
    cmd = [sys.executable, str(SCRIPT), *_args(data, runs, "killed")]
    run = runs / "killed"
    # 1. Killed in its first optimiser step, before any checkpoint (the process kills itself there, so the
    # point is exact): --resume starts it over.
    proc = subprocess.run(
        [sys.executable, "-c", _KILL_IN_FIRST_STEP, *cmd[1:]],
        env=_env(),
        capture_output=True,
        text=True,
        timeout=HANG_S,
    )
    assert proc.returncode == -signal.SIGKILL, proc.stderr[-3000:]
    assert (run / "config.yaml").is_file() and not (run / "checkpoints" / "last.pt").exists()
    # 2. Resumed, killed in the middle of epoch 2 (the bar shows at least one of its steps done; should the
    # bar not be drawn mid-epoch, at the end of epoch 2).
    mid = re.compile(rf"epoch 2/{EPOCHS}:\s*\d+%.*\|\s*([1-9]\d*)/(\d+)")
    _kill_when([*cmd, "--resume"], lambda line: bool(mid.search(line)) or "[train] epoch 2/" in line)
    at_kill = read_training_checkpoint(run / "checkpoints" / "last.pt")
    assert at_kill["epoch"] in (1, 2), at_kill["epoch"]
    # 3. Resumed to the end.
    _run_to_end([*cmd, "--resume"])
    _assert_bitwise_equal(run, setup["straight"])


# The training script (argv[1:]), patched so that the process SIGKILLs itself halfway through writing a file.
_TORN_WRITE = """
import io, os, runpy, signal, sys
import torch
real_save = torch.save
def torn_save(obj, f, *args, **kwargs):
    name = os.path.basename(str(getattr(f, "name", "")))
    if isinstance(obj, dict) and obj.get("epoch") == {epoch} and name.startswith("{file}"):
        buf = io.BytesIO()
        real_save(obj, buf, *args, **kwargs)
        data = buf.getvalue()
        f.write(data[: len(data) // 2])
        f.flush()
        os.fsync(f.fileno())
        os.kill(os.getpid(), signal.SIGKILL)  # killed in the middle of writing the file
    return real_save(obj, f, *args, **kwargs)
torch.save = torn_save
sys.argv = sys.argv[1:]
runpy.run_path(sys.argv[0], run_name="__main__")
"""


@pytest.mark.parametrize(
    ("file", "epoch"),
    [("last.pt", 2), ("best.pt", EPOCHS)],
    ids=["last_mid_run", "best_of_the_final_epoch"],
)
def test_kill_while_writing_a_checkpoint_leaves_the_previous_one_whole(
    setup: dict[str, Path], file: str, epoch: int
) -> None:
    """SIGKILL in the middle of writing `file` at the end of `epoch`. best.pt is written before last.pt, so
    a kill while best.pt is written resumes from the previous epoch and rewrites it; the other way round,
    the final epoch's kill would leave a stale best.pt (its epoch is the best one: checked)."""
    data, runs = setup["data"], setup["runs"]
    assert read_training_checkpoint(setup["straight"] / "checkpoints" / "best.pt")["epoch"] == EPOCHS
    name = f"torn_{file[:-3]}"
    args = _args(data, runs, name)
    driver = [sys.executable, "-c", _TORN_WRITE.format(epoch=epoch, file=file), str(SCRIPT)]
    proc = subprocess.run([*driver, *args], env=_env(), capture_output=True, text=True, timeout=HANG_S)
    assert proc.returncode == -signal.SIGKILL, proc.stderr[-3000:]
    ckpts = runs / name / "checkpoints"
    # The torn bytes are only in the temporary file; last.pt is the previous epoch's, complete, and best.pt
    # whole too: this epoch's when the kill came after it (every epoch of this run improves), else the
    # previous one's.
    assert read_training_checkpoint(ckpts / "last.pt")["epoch"] == epoch - 1
    assert read_training_checkpoint(ckpts / "best.pt")["epoch"] == (epoch if file == "last.pt" else epoch - 1)
    torn = ckpts / f"{file}.partial"
    with pytest.raises(CheckpointError, match=rf"{re.escape(str(torn))}: cannot read it"):
        read_training_checkpoint(torn)
    _run_to_end([sys.executable, str(SCRIPT), *args, "--resume"])
    _assert_bitwise_equal(runs / name, setup["straight"])


def test_truncated_last_checkpoint_is_refused_naming_the_file(
    setup: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run = tmp_path / "runs" / "straight"
    shutil.copytree(setup["straight"], run)
    last = run / "checkpoints" / "last.pt"
    raw = last.read_bytes()
    last.write_bytes(raw[: len(raw) // 3])
    sys.path.insert(0, str(SCRIPT.parent))
    try:
        script = __import__(SCRIPT.stem)
    finally:
        sys.path.pop(0)
    args = _args(setup["data"], tmp_path / "runs", "straight", "--epochs", str(EPOCHS + 1), "--resume")
    assert script.main(args) == 2
    err = capsys.readouterr().err
    assert f"resume: checkpoint {last}: cannot read it as a training checkpoint (truncated" in err, err
