"""Checkpoints are read with torch.load(weights_only=True) (issue 30): a file carrying a pickled payload that
would run code is refused by every loader of the project with a CheckpointError naming the file, and the code
never runs; a real training checkpoint holds only tensors and plain values, loads that way and resumes."""

from __future__ import annotations

import os
import pickle
import random
import shlex
import shutil
import sys
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch
from test_learning_training import tiny_config

from quad_il.learning.checkpoint import (
    CHECKPOINT_FORMAT,
    CheckpointError,
    read_checkpoint_file,
    read_training_checkpoint,
    rng_state,
    save_checkpoint,
    set_rng_state,
)
from quad_il.learning.config import ModelConfig
from quad_il.learning.evaluation import load_policy
from quad_il.learning.model import build_policy
from quad_il.learning.soup import SoupError, average_checkpoints
from quad_il.learning.synthetic import write_synthetic_npz
from quad_il.learning.trainer import Trainer, load_initial_weights, load_policy_checkpoint

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "training_only" / "train_on_cpp_datasets.py"


class RunsCode:
    """Unpickled by an unrestricted unpickler, this calls os.system, which creates the marker file."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple[Callable[[str], int], tuple[str]]:
        return (os.system, (f"touch {shlex.quote(str(self.marker))}",))


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A finished 1-epoch run and a 2-epoch run of the same configuration."""
    tmp = tmp_path_factory.mktemp("safe")
    data = write_synthetic_npz(tmp / "d.npz", num_episodes=4, samples_per_episode=6, height=40, width=48)
    one = Trainer(tiny_config(data, tmp / "runs", "one", "optim.epochs=1")).fit().run_dir
    two = Trainer(tiny_config(data, tmp / "runs", "two", "optim.epochs=2")).fit().run_dir
    return {"data": data, "one": one, "two": two, "tmp": tmp}


def _write_payload(path: Path, marker: Path, template: Path, legacy: bool = False) -> Path:
    """A checkpoint that looks like a real one (same format and keys) whose weights are the payload."""
    ckpt = read_training_checkpoint(template)
    ckpt["model"] = {"net.weight": RunsCode(marker)}
    del ckpt["optimizer"], ckpt["rng"]  # no tensors: the payload file's pickle can be checked alone
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save(ckpt, path, _use_new_zipfile_serialization=not legacy)
    return path


def test_the_payload_runs_code_when_unpickled_without_restriction(
    run: dict[str, Path], tmp_path: Path
) -> None:
    """Guards the test itself: the file's pickle, read by plain `pickle`, does run the code."""
    marker = tmp_path / "ran"
    evil = _write_payload(tmp_path / "evil.pt", marker, run["one"] / "checkpoints" / "last.pt")
    with zipfile.ZipFile(evil) as z:
        name = next(n for n in z.namelist() if n.endswith("/data.pkl"))
        assert not marker.exists()
        pickle.loads(z.read(name))
    assert marker.exists()


def _resume(run: dict[str, Path], tmp: Path, replace: str, *extra: str) -> Callable[[Path], object]:
    """Loader: resume a copy of the 1-epoch run whose checkpoints/<replace> is the file under test."""

    def load(evil: Path) -> object:
        copy = tmp / "resume" / "one"
        shutil.copytree(run["one"], copy)
        shutil.copyfile(evil, copy / "checkpoints" / replace)
        cfg = tiny_config(run["data"], tmp / "resume", "one", "optim.epochs=1", *extra)
        return Trainer(cfg, resume=True).fit()

    return load


def _script_resume(run: dict[str, Path], tmp: Path) -> Callable[[Path], object]:
    """Loader: `train_on_cpp_datasets.py --resume` of a copy whose last.pt is the file (exit status)."""

    def load(evil: Path) -> object:
        copy = tmp / "script" / "one"
        shutil.copytree(run["one"], copy)
        shutil.copyfile(evil, copy / "checkpoints" / "last.pt")
        sys.path.insert(0, str(SCRIPT.parent))
        try:
            script = __import__(SCRIPT.stem)
        finally:
            sys.path.pop(0)
        return script.main(["--config", str(copy / "config.yaml"), "--out", str(tmp / "script"), "--resume"])

    return load


LOADERS: dict[str, Callable[[dict[str, Path], Path], Callable[[Path], object]]] = {
    "read_checkpoint_file": lambda run, tmp: read_checkpoint_file,
    "load_policy_checkpoint": lambda run, tmp: load_policy_checkpoint,
    "evaluation.load_policy": lambda run, tmp: load_policy,
    "init_weights": lambda run, tmp: lambda p: Trainer(
        tiny_config(run["data"], tmp, "tuned", f"run.init_weights={str(p)!r}")
    ),
    "load_initial_weights": lambda run, tmp: lambda p: load_initial_weights(
        Trainer(tiny_config(run["data"], tmp, "fresh")).policy, p
    ),
    "resume_last": lambda run, tmp: _resume(run, tmp, "last.pt"),
    "best_for_export": lambda run, tmp: _resume(run, tmp, "best.pt", "log.export_torchscript=true"),
    "backbone_weights": lambda run, tmp: lambda p: build_policy(
        ModelConfig(input_height=32, input_width=32, backbone_weights=str(p)), 10, 2.0
    ),
}


@pytest.mark.parametrize("legacy", [False, True], ids=["zip", "legacy_format"])
@pytest.mark.parametrize("loader", sorted(LOADERS))
def test_every_loader_refuses_a_code_carrying_checkpoint(
    run: dict[str, Path], tmp_path: Path, loader: str, legacy: bool
) -> None:
    marker = tmp_path / "ran"
    evil = _write_payload(tmp_path / "in" / "evil.pt", marker, run["one"] / "checkpoints" / "last.pt", legacy)
    with pytest.raises(
        CheckpointError, match=r"(evil|last|best)\.pt: refused: .*posix\.system.*could run code"
    ):
        LOADERS[loader](run, tmp_path)(evil)
    assert not marker.exists(), f"{loader} ran the payload"


def test_soup_and_training_script_refuse_it_naming_the_file(
    run: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    marker = tmp_path / "ran"
    evil = _write_payload(tmp_path / "evil.pt", marker, run["one"] / "checkpoints" / "last.pt")
    with pytest.raises(SoupError, match=rf"{evil}: refused: .*posix\.system"):
        average_checkpoints([run["one"] / "checkpoints" / "last.pt", evil])
    assert _script_resume(run, tmp_path)(evil) == 2
    err = capsys.readouterr().err
    last = tmp_path / "script" / "one" / "checkpoints" / "last.pt"
    assert f"error: resume: checkpoint {last}: refused" in err, err
    assert not marker.exists()


def test_damaged_or_foreign_files_are_named_errors(run: dict[str, Path], tmp_path: Path) -> None:
    raw = (run["one"] / "checkpoints" / "last.pt").read_bytes()
    cut = tmp_path / "cut.pt"
    cut.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(CheckpointError, match=rf"checkpoint {cut}: cannot read it .*\(truncated"):
        load_policy_checkpoint(cut)
    empty = tmp_path / "empty.pt"
    empty.write_bytes(b"")
    with pytest.raises(CheckpointError, match=rf"{empty}: cannot read it"):
        load_policy_checkpoint(empty)
    text = tmp_path / "notes.pt"
    text.write_text("not a checkpoint\n")
    with pytest.raises(CheckpointError, match=rf"{text}: cannot read it as a training checkpoint"):
        load_policy_checkpoint(text)
    foreign = tmp_path / "foreign.pt"
    torch.save({"state_dict": {"w": torch.zeros(2)}}, foreign)
    with pytest.raises(CheckpointError, match=rf"{foreign}: not a quad_il training checkpoint"):
        load_policy_checkpoint(foreign)
    future = tmp_path / "future.pt"
    torch.save({**read_training_checkpoint(run["one"] / "checkpoints" / "last.pt"), "format": "x/9"}, future)
    with pytest.raises(CheckpointError, match=rf"{future}: checkpoint format 'x/9' is not one this version"):
        load_policy_checkpoint(future)
    with pytest.raises(CheckpointError, match=rf"{tmp_path / 'none.pt'}: no such file"):
        read_training_checkpoint(tmp_path / "none.pt")


# --------------------------------------------------------------------------------------------- round trip
def _plain(obj: object, where: str = "") -> list[str]:
    """Paths of values that are not tensors, plain scalars, strings or containers of them."""
    if isinstance(obj, torch.Tensor | bool | int | float | str | type(None)):
        return []
    if isinstance(obj, dict):
        bad_keys = [f"{where}/{k!r}: key" for k in obj if not isinstance(k, str | int)]
        return bad_keys + [p for k, v in obj.items() for p in _plain(v, f"{where}/{k}")]
    if isinstance(obj, list | tuple):
        return [p for i, v in enumerate(obj) for p in _plain(v, f"{where}/{i}")]
    return [f"{where}: {type(obj).__name__}"]


def test_a_training_checkpoint_is_plain_loads_safely_and_resumes(
    run: dict[str, Path], tmp_path: Path
) -> None:
    path = run["one"] / "checkpoints" / "last.pt"
    ckpt = torch.load(path, map_location="cpu", weights_only=True)
    assert ckpt["format"] == CHECKPOINT_FORMAT and ckpt["epoch"] == 1
    assert _plain(ckpt) == []
    assert set(ckpt["rng"]) == {"torch", "numpy", "python"}
    # Resumed to epoch 2, the 1-epoch run ends bit-identical to the 2-epoch run.
    copy = tmp_path / "runs" / "one"
    shutil.copytree(run["one"], copy)
    Trainer(tiny_config(run["data"], tmp_path / "runs", "one", "optim.epochs=2"), resume=True).fit()
    a, b = (
        read_training_checkpoint(copy / "checkpoints" / "last.pt"),
        read_training_checkpoint(run["two"] / "checkpoints" / "last.pt"),
    )
    assert a["epoch"] == 2 and all(torch.equal(a["model"][k], b["model"][k]) for k in b["model"])


def test_a_format_1_checkpoint_still_resumes(run: dict[str, Path], tmp_path: Path) -> None:
    """Run directories written before issue 30 (format /1: only the torch RNG state) stay resumable."""
    copy = tmp_path / "runs" / "one"
    shutil.copytree(run["one"], copy)
    ckpt = read_training_checkpoint(copy / "checkpoints" / "last.pt")
    rng = ckpt.pop("rng")
    old = {**ckpt, "format": "quad_il.learning.checkpoint/1", "torch_rng_state": rng["torch"]}
    torch.save(old, copy / "checkpoints" / "last.pt")
    Trainer(tiny_config(run["data"], tmp_path / "runs", "one", "optim.epochs=2"), resume=True).fit()
    a = read_training_checkpoint(copy / "checkpoints" / "last.pt")
    b = read_training_checkpoint(run["two"] / "checkpoints" / "last.pt")
    assert a["format"] == CHECKPOINT_FORMAT
    assert all(torch.equal(a["model"][k], b["model"][k]) for k in b["model"])


def test_rng_states_round_trip_through_a_file(tmp_path: Path) -> None:
    # The global generators are what is checkpointed, so this test uses numpy's legacy global one.
    torch.manual_seed(1)
    np.random.seed(2)  # noqa: NPY002
    random.seed(3)
    np.random.standard_normal()  # noqa: NPY002 (numpy's cached Gaussian is part of the state)
    save_checkpoint({"rng": rng_state()}, tmp_path / "rng.pt")
    expected = (torch.rand(3), np.random.standard_normal(3), random.random())  # noqa: NPY002
    set_rng_state(read_checkpoint_file(tmp_path / "rng.pt")["rng"])
    got = (torch.rand(3), np.random.standard_normal(3), random.random())  # noqa: NPY002
    assert torch.equal(got[0], expected[0]) and np.array_equal(got[1], expected[1]) and got[2] == expected[2]
    assert not (tmp_path / "rng.pt.partial").exists()
