#!/usr/bin/env python3
"""Plots a closed-loop run written by `tracker_eval step|fig8 --csv FILE`: x, y, z against their references
over time (the thesis's PID-response figure, Fig. 4.1), as a PNG.

Usage: plot_step_response.py RUN.csv OUT.png [--title TEXT]
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (the backend must be chosen first)

REQUIRED_COLUMNS = ("t_s", "x_m", "y_m", "z_m", "x_ref_m", "y_ref_m", "z_ref_m")


class RunFormatError(ValueError):
    """The CSV is not a tracker_eval run."""


def load_run(path: Path) -> dict[str, np.ndarray]:
    """Reads a tracker_eval CSV into one float array per column; checks the columns and the values."""
    with path.open(newline="") as f:
        reader = csv.DictReader(f)
        header = reader.fieldnames or []
        missing = [c for c in REQUIRED_COLUMNS if c not in header]
        if missing:
            raise RunFormatError(f"{path}: missing column(s) {', '.join(missing)}")
        rows = list(reader)
    if not rows:
        raise RunFormatError(f"{path}: no samples")
    run: dict[str, np.ndarray] = {}
    for name in header:
        try:
            values = np.array([float(r[name]) for r in rows], dtype=np.float64)
        except ValueError as e:
            raise RunFormatError(f"{path}: column {name} has a non-numeric value ({e})") from e
        if not np.all(np.isfinite(values)):
            raise RunFormatError(f"{path}: column {name} has non-finite values")
        run[name] = values
    if np.any(np.diff(run["t_s"]) <= 0.0):
        raise RunFormatError(f"{path}: time is not strictly increasing")
    return run


def plot_run(run: dict[str, np.ndarray], out_png: Path, title: str = "") -> None:
    """Three stacked panels (x, y, z): the flown position and the reference, against time."""
    fig, axes = plt.subplots(3, 1, figsize=(8.0, 7.5), sharex=True)
    for ax, axis in zip(axes, ("x", "y", "z"), strict=True):
        ax.plot(run["t_s"], run[f"{axis}_ref_m"], "--", color="tab:gray", label=f"{axis} reference")
        ax.plot(run["t_s"], run[f"{axis}_m"], color="tab:blue", label=f"{axis} flown")
        ax.set_ylabel(f"{axis} [m]")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="lower right")
    axes[-1].set_xlabel("time [s]")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, dpi=100)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("csv", type=Path)
    parser.add_argument("png", type=Path)
    parser.add_argument("--title", default="")
    args = parser.parse_args(argv)
    plot_run(load_run(args.csv), args.png, args.title)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
