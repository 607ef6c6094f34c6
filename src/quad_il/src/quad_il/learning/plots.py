"""Figures: loss curves of a run, comparisons between runs (thesis Figures 4.2-4.5), and the thesis's 12-panel
expert-vs-learned B-spline figure (Figure 4.6). Matplotlib with the non-interactive Agg backend.
"""

from __future__ import annotations

import csv
from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

from quad_il.data.bspline import basis_matrix, uniform_knots  # noqa: E402


def uniform_cubic_bspline(ctrl: NDArray[np.floating], samples_per_segment: int = 10) -> NDArray[np.float64]:
    """Points of the dataset's uniform cubic B-spline with control points ctrl (K, 3), K >= 4."""
    c = np.asarray(ctrl, dtype=np.float64)
    if len(c) < 4:
        return c
    segments = len(c) - 3  # knots (i - 3) dt: the domain is [0, segments dt]; dt = 1 here (shape only)
    u = np.linspace(0.0, float(segments), samples_per_segment * segments + 1)
    return basis_matrix(uniform_knots(len(c), 3, 1.0), len(c), 3, u) @ c


def read_metrics_csv(path: str | Path) -> list[dict[str, float]]:
    with open(path, newline="") as f:
        return [{k: float(v) for k, v in row.items()} for row in csv.DictReader(f)]


def plot_loss_curves(rows: Sequence[Mapping[str, float]], out_png: str | Path, title: str = "") -> Path:
    """Training and validation loss per epoch (log scale), and the learning rate."""
    epochs = [r["epoch"] for r in rows]
    fig, (ax, ax_lr) = plt.subplots(2, 1, figsize=(7, 6), sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    ax.plot(epochs, [r["train_loss"] for r in rows], "o-", ms=3, label="training loss")
    ax.plot(epochs, [r["val_loss"] for r in rows], "s-", ms=3, label="validation loss")
    ax.set_yscale("log")
    ax.set_ylabel("loss")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    ax.set_title(title)
    ax_lr.plot(epochs, [r["lr"] for r in rows], "-", color="gray")
    ax_lr.set_ylabel("learning rate")
    ax_lr.set_xlabel("epoch")
    ax_lr.grid(True, alpha=0.3)
    fig.tight_layout()
    out = Path(out_png)
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out


def plot_run_comparison(
    runs: Mapping[str, Sequence[Mapping[str, float]]], out_png: str | Path, title: str = ""
) -> Path:
    """Side by side: training loss, validation loss (each run's own) and validation MSE in the world frame."""
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.5))
    panels = [
        ("train_loss", "training loss"),
        ("val_loss", "validation loss"),
        ("val_mse_world_m2", "validation MSE, world frame (m$^2$)"),
    ]
    for ax, (key, label) in zip(axes, panels, strict=True):
        for name, rows in runs.items():
            ax.plot([r["epoch"] for r in rows], [r[key] for r in rows], "-", marker="o", ms=2, label=name)
        ax.set_yscale("log")
        ax.set_xlabel("epoch")
        ax.set_title(label)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    fig.suptitle(title)
    fig.tight_layout()
    out = Path(out_png)
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out


def plot_bspline_panels(
    expert: NDArray[np.floating],
    learned: NDArray[np.floating],
    out_png: str | Path,
    titles: Sequence[str] | None = None,
    frame: str = "world",
) -> Path:
    """Up to 12 3-D panels (3 x 4): expert and learned control points and their uniform cubic B-splines."""
    e = np.asarray(expert, dtype=np.float64)
    lrn = np.asarray(learned, dtype=np.float64)
    if e.shape != lrn.shape or e.ndim != 3 or e.shape[2] != 3:
        raise ValueError(f"expected two (M, K, 3) arrays, got {e.shape} and {lrn.shape}")
    m = min(12, len(e))
    fig = plt.figure(figsize=(16, 11))
    for i in range(m):
        ax = fig.add_subplot(3, 4, i + 1, projection="3d")
        for pts, color, label in ((e[i], "tab:blue", "expert"), (lrn[i], "tab:orange", "learned")):
            curve = uniform_cubic_bspline(pts)
            ax.plot(curve[:, 0], curve[:, 1], curve[:, 2], "-", color=color, lw=2, label=f"{label} B-spline")
            ax.plot(pts[:, 0], pts[:, 1], pts[:, 2], "o--", color=color, ms=3, lw=0.7, alpha=0.7)
        both = np.concatenate([e[i], lrn[i]])
        centre = both.mean(axis=0)
        half = max(0.5, float(np.abs(both - centre).max()))
        ax.set_xlim(centre[0] - half, centre[0] + half)
        ax.set_ylim(centre[1] - half, centre[1] + half)
        ax.set_zlim(centre[2] - half, centre[2] + half)
        ax.set_xlabel("x (m)", fontsize=7)
        ax.set_ylabel("y (m)", fontsize=7)
        ax.set_zlabel("z (m)", fontsize=7)
        ax.tick_params(labelsize=6)
        ax.set_title(titles[i] if titles else f"B-spline {i + 1}", fontsize=8)
        if i == 0:
            ax.legend(fontsize=7, loc="upper left")
    fig.suptitle(f"Expert (blue) vs learned (orange) B-splines, {frame} frame; dots: control points")
    fig.tight_layout()
    out = Path(out_png)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
