"""Training checkpoints on disk: written atomically, read without running code (issue 30).

A checkpoint (`checkpoints/last.pt`, `checkpoints/best.pt` of a run directory, trainer.py) is one dict of
plain values, written with `torch.save`:

    format          CHECKPOINT_FORMAT (str)
    epoch, global_step, best_epoch, num_ctrl_pts, world_size    int
    best_val_loss, horizon_s                                     float (inf before any validation)
    model           the policy's state dict (str -> tensor)
    optimizer       torch.optim state dict (tensors, floats, bools, tuples, None)
    scheduler       LRScheduler state dict (ints, floats, bools, lists) or None
    config          the resolved TrainConfig as JSON values (`model_dump(mode="json")`)
    rng             {"torch": ByteTensor, "numpy": {...}, "python": [...]}: the global generators' states as
                    tensors, ints and lists (format /2; format /1 had only "torch_rng_state")

Reading: `torch.load(..., weights_only=True)`, torch's restricted unpickler, which builds only tensors,
storages and plain containers and scalars, and refuses any other global (`os.system` in a crafted file, a
class with a `__reduce__`) BEFORE calling it. Nothing is registered with
`torch.serialization.add_safe_globals`: no dataclass, pydantic model, numpy array or `random` state object is
stored (each is converted to the plain values above), so the default allow-list is enough. Format /1 files
(before issue 30) held the same plain values and stay readable.

Writing: to `<name>.partial` in the same directory, flushed and fsync'ed, then renamed over `<name>` and the
directory fsync'ed. A process killed (SIGKILL, power loss) at any point leaves either the previous complete
file or the new complete file under `<name>`, never a torn one; a torn `<name>.partial` may remain and is
overwritten by the next save.
"""

from __future__ import annotations

import os
import pickle
import random
import re
from pathlib import Path
from typing import Any

import numpy as np
import torch

CHECKPOINT_FORMAT = "quad_il.learning.checkpoint/2"
# Formats this version reads: /1 lacks the numpy and Python RNG states (neither generator is used in training;
# the batch order and the mirror masks are functions of (run.seed, epoch)), so it resumes identically.
READABLE_FORMATS = ("quad_il.learning.checkpoint/1", CHECKPOINT_FORMAT)

_GLOBAL = re.compile(r"GLOBAL\s+([\w.]+)")


class CheckpointError(ValueError):
    """A checkpoint file that cannot be used: missing, truncated, corrupt, not a quad_il training checkpoint,
    or refused because it holds objects whose loading could run code. The message names the file."""


def save_checkpoint(ckpt: dict[str, Any], path: str | Path) -> None:
    """Write `ckpt` to `path` atomically (temporary file, fsync, rename, directory fsync)."""
    out = Path(path)
    tmp = out.with_name(out.name + ".partial")
    with open(tmp, "wb") as f:
        torch.save(ckpt, f)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, out)
    # The rename itself is durable only once the directory entry is on disk.
    fd = os.open(out.parent, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def read_checkpoint_file(path: str | Path, what: str = "checkpoint") -> Any:
    """The object in a torch file, loaded with weights_only=True (tensors and plain values only, on CPU).

    Raises CheckpointError naming the file (and `what` it was read as) when it is missing, unreadable, or
    holds anything else; the refused object is never constructed."""
    p = Path(path)
    if not p.is_file():
        raise CheckpointError(f"{what} {p}: no such file")
    try:
        return torch.load(p, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as e:
        found = _GLOBAL.search(str(e))
        if found:
            raise CheckpointError(
                f"{what} {p}: refused: it holds a Python object ({found.group(1)}) that is not a tensor or a "
                "plain value, and loading it could run code. quad_il training writes only tensors and plain "
                "values: this file was written by something else or altered"
            ) from None
        raise CheckpointError(
            f"{what} {p}: cannot read it as a training checkpoint (not a torch file, or corrupt: "
            f"{_first_line(e)})"
        ) from None
    except Exception as e:  # anything else a damaged file makes torch's reader raise
        raise CheckpointError(
            f"{what} {p}: cannot read it as a training checkpoint (truncated, corrupt or unreadable: "
            f"{_first_line(e) or type(e).__name__})"
        ) from None


def read_training_checkpoint(path: str | Path, what: str = "checkpoint") -> dict[str, Any]:
    """A quad_il training checkpoint (a dict of a READABLE_FORMATS format), safely loaded."""
    ckpt = read_checkpoint_file(path, what)
    if not isinstance(ckpt, dict) or "format" not in ckpt:
        raise CheckpointError(f"{what} {path}: not a quad_il training checkpoint")
    if ckpt["format"] not in READABLE_FORMATS:
        raise CheckpointError(
            f"{what} {path}: checkpoint format {ckpt['format']!r} is not one this version reads "
            f"({', '.join(READABLE_FORMATS)})"
        )
    missing = [k for k in ("epoch", "model", "config", "num_ctrl_pts", "horizon_s") if k not in ckpt]
    if missing:
        raise CheckpointError(f"{what} {path}: incomplete training checkpoint (no {', '.join(missing)})")
    return ckpt


def _first_line(e: BaseException) -> str:
    """The informative line of torch's error (its weights_only messages start with a generic paragraph)."""
    lines = [ln.strip() for ln in str(e).splitlines() if ln.strip()]
    for ln in lines:
        if not ln.startswith(("Weights only load failed", "Please file an issue", "Check the documentation")):
            return ln
    return lines[0] if lines else ""


# ------------------------------------------------------------------------------------------------ RNG states
def rng_state() -> dict[str, Any]:
    """The global torch, numpy and Python generators' states as tensors, ints and lists."""
    # numpy's legacy global generator is the one a library calling np.random.* would draw from.
    np_state = np.random.get_state(legacy=False)  # noqa: NPY002
    if np_state["bit_generator"] != "MT19937":
        raise RuntimeError(f"numpy's global generator is {np_state['bit_generator']}, expected MT19937")
    py_version, py_internal, py_gauss = random.getstate()
    return {
        "torch": torch.get_rng_state(),
        "numpy": {
            "key": torch.from_numpy(np_state["state"]["key"].astype(np.int64)),
            "pos": int(np_state["state"]["pos"]),
            "has_gauss": int(np_state["has_gauss"]),
            "gauss": float(np_state["gauss"]),
        },
        "python": [int(py_version), [int(x) for x in py_internal], py_gauss],
    }


def set_rng_state(state: dict[str, Any]) -> None:
    """Restore what `rng_state` returned."""
    torch.set_rng_state(state["torch"])
    n = state["numpy"]
    np.random.set_state(  # noqa: NPY002
        {
            "bit_generator": "MT19937",
            "state": {"key": n["key"].numpy().astype(np.uint32), "pos": int(n["pos"])},
            "has_gauss": int(n["has_gauss"]),
            "gauss": float(n["gauss"]),
        }
    )
    version, internal, gauss = state["python"]
    random.setstate((int(version), tuple(int(x) for x in internal), gauss))
