"""The closed-loop evaluation's report: OUT/report.md with the per-controller table, plots (outcome bars,
decision latency histograms, top-down trajectory overlays) and the rviz snapshots, and the BENCH lines
eval_<controller>_success_rate, _collision_rate, _timeout_rate on stdout."""

from __future__ import annotations

import math
import os
import subprocess
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from scipy.spatial import ConvexHull

from quad_il.collection.episodes import EpisodeSpec
from quad_il.evaluation.episodes import EpisodeResult, read_results
from quad_il.evaluation.metrics import ControllerSummary, summarise
from quad_il.inference.geometry import rotation_matrix

COLOURS = {"expert": "tab:blue", "py": "tab:green", "cpp": "tab:orange"}
NAMES = {"expert": "expert (fast_planner)", "py": "policy, Python", "cpp": "policy, C++ (LibTorch)"}


def bench_lines(summaries: dict[str, ControllerSummary]) -> list[str]:
    lines = []
    for c, s in summaries.items():
        lines.append(f"BENCH eval_{c}_success_rate {s.success_rate:.4f} ratio")
        lines.append(f"BENCH eval_{c}_collision_rate {s.collision_rate:.4f} ratio")
        lines.append(f"BENCH eval_{c}_timeout_rate {s.timeout_rate:.4f} ratio")
    return lines


def _fmt(v: float, digits: int = 2, pct: bool = False) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    return f"{100 * v:.0f} %" if pct else f"{v:.{digits}f}"


def world_boxes(sim_config: Path, spec: EpisodeSpec) -> list[dict[str, Any]]:
    """The episode's world, regenerated exactly by quad_sim_world (same seed, config and clear zones as the
    simulator's reset); [] when the tool is not built."""
    tool = None
    for prefix in os.environ.get("CMAKE_PREFIX_PATH", "").split(os.pathsep):
        if prefix and (Path(prefix) / "lib" / "quad_sim" / "quad_sim_world").is_file():
            tool = Path(prefix) / "lib" / "quad_sim" / "quad_sim_world"
            break
    if tool is None or not sim_config.is_file():
        return []
    sx, sy, _ = spec.start_world
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "world.yaml"
        proc = subprocess.run(
            [
                str(tool),
                "generate",
                "--config",
                str(sim_config),
                "--seed",
                str(spec.seed),
                "--out",
                str(out),
                "--start",
                f"{sx},{sy},0.125",
                "--goal",
                ",".join(str(v) for v in spec.goal_world),
            ],
            capture_output=True,
            text=True,
        )
        if proc.returncode != 0:
            return []
        return yaml.safe_load(out.read_text())["boxes"]


def _box_footprint(box: dict[str, Any]) -> np.ndarray:
    """xy convex hull of an oriented box's corners (counter-clockwise)."""
    half = 0.5 * np.asarray(box["size_m"], dtype=np.float64)
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64)
    corners = (signs * half) @ rotation_matrix(np.asarray(box["q_xyzw"])).T + np.asarray(box["center_m"])
    pts = corners[:, :2]
    return pts[ConvexHull(pts).vertices]


def plot_outcomes(path: Path, summaries: dict[str, ControllerSummary]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.5))
    kinds = [("success_rate", "goal reached"), ("collision_rate", "collision"), ("timeout_rate", "timeout")]
    x = np.arange(len(kinds))
    w = 0.8 / max(len(summaries), 1)
    for i, (c, s) in enumerate(summaries.items()):
        vals = [100 * getattr(s, k) for k, _ in kinds]
        ax.bar(x + (i - (len(summaries) - 1) / 2) * w, vals, w, label=NAMES.get(c, c), color=COLOURS.get(c))
    ax.set_xticks(x, [k for _, k in kinds])
    ax.set_ylabel("episodes (%)")
    ax.set_ylim(0, 100)
    ax.legend()
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_latency(path: Path, results: dict[str, list[EpisodeResult]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.5))
    all_ms = [x for rs in results.values() for r in rs for x in r.decision_ms if x > 0]
    if all_ms:
        bins = np.logspace(np.log10(min(all_ms)), np.log10(max(all_ms)) + 1e-9, 40)
        for c, rs in results.items():
            ms = [x for r in rs for x in r.decision_ms if x > 0]
            if ms:
                ax.hist(ms, bins=bins, alpha=0.6, label=NAMES.get(c, c), color=COLOURS.get(c))
        ax.set_xscale("log")
    ax.set_xlabel("decision latency (ms)")
    ax.set_ylabel("decisions")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_overlays(
    path: Path,
    specs: list[EpisodeSpec],
    results: dict[str, list[EpisodeResult]],
    sim_config: Path,
    max_episodes: int = 6,
) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Polygon

    shown = specs[:max_episodes]
    cols = min(3, len(shown))
    rows = math.ceil(len(shown) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(5 * cols, 5 * rows), squeeze=False)
    for ax, spec in zip(axes.flat, shown, strict=False):
        for box in world_boxes(sim_config, spec):
            ax.add_patch(Polygon(_box_footprint(box), closed=True, color="0.6", alpha=0.8, lw=0))
        for c, rs in results.items():
            for r in rs:
                if r.index == spec.index and r.trajectory:
                    t = np.asarray(r.trajectory)
                    ax.plot(t[:, 1], t[:, 2], color=COLOURS.get(c), lw=1.5, label=f"{c}: {r.outcome}")
        ax.plot(*spec.start_world[:2], "ko", ms=5)
        ax.plot(*spec.goal_world[:2], "g*", ms=12)
        lo = np.minimum(spec.start_world[:2], spec.goal_world[:2]) - 5
        hi = np.maximum(spec.start_world[:2], spec.goal_world[:2]) + 5
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_aspect("equal")
        ax.set_title(f"episode {spec.index}, world seed {spec.seed}", fontsize=9)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7, loc="best")
    for ax in list(axes.flat)[len(shown) :]:
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_report(
    out: Path,
    controllers: list[str],
    specs: list[EpisodeSpec],
    skipped: dict[str, str],
    options: dict[str, Any],
) -> Path:
    results = {c: read_results(out / f"{c}.jsonl") for c in controllers}
    results = {c: rs for c, rs in results.items() if rs}
    summaries = {c: summarise(c, rs) for c, rs in results.items()}
    sim_config = next(
        (out / f"sim_{c}.yaml" for c in controllers if (out / f"sim_{c}.yaml").is_file()),
        Path(options.get("sim_config", "")),
    )
    lines = [
        "# Closed-loop evaluation",
        "",
        f"{len(specs)} episodes on world seeds {sorted({s.seed for s in specs})}, box density "
        f"{options.get('density') or 'of the sim config'}, start/goal {options.get('min_distance_m')}-"
        f"{options.get('max_distance_m')} m apart, episode timeout {options.get('episode_timeout_s')} s (sim "
        f"time), simulator in lockstep. Policy: `{options.get('policy') or '-'}`, node config "
        f"`{options.get('policy_config') or '-'}`.",
        "",
        "| controller | episodes | success | collision | timeout | reset/take-off failed | mean time to goal "
        "(s) | mean path length (m) | min clearance (m) | median min clearance (m) | decision ms median | "
        "decision ms p99 | decisions | refusals (recovered) | steered | turning | final approach | "
        "kept (committed) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for c, s in summaries.items():
        lines.append(
            f"| {NAMES.get(c, c)} | {s.episodes} | {_fmt(s.success_rate, pct=True)} | "
            f"{_fmt(s.collision_rate, pct=True)} | {_fmt(s.timeout_rate, pct=True)} | "
            f"{_fmt(s.other_rate, pct=True)} | {_fmt(s.mean_time_to_goal_s, 1)} | "
            f"{_fmt(s.mean_path_length_m, 1)} | {_fmt(s.min_clearance_m)} | "
            f"{_fmt(s.median_min_clearance_m)} | {_fmt(s.decision_ms_median, 3)} | "
            f"{_fmt(s.decision_ms_p99, 3)} | {s.decisions} | {s.refusals} ({s.recovered}) | {s.steered} | "
            f"{s.turning} | {s.final_approach} | {s.kept} ({s.committed}) |"
        )
    for c, why in skipped.items():
        lines.append(f"| {NAMES.get(c, c)} | not run: {why} |||||||||||||||||")
    lines += [
        "",
        "Success, collision and timeout are shares of all episodes; time to goal and path length are means "
        "over the successful ones. Clearance: the minimum over the flight of the distance from the vehicle's "
        "centre to the nearest world box minus the vehicle box's circumscribed radius (a lower bound of the "
        "exact box-to-box clearance; the ground is not counted). Decision latency: policies preprocessing + "
        "forward + message (policy/decision), expert map update + plan (planner/timing). Refusals: decisions "
        "whose policy plan the safety layer refused; recovered: of those, the ones the recovery (policy "
        "config `recovery`) replaced with an accepted plan for a turned goal. Steered: accepted decisions "
        "replaced by a turned goal's plan that keeps `recovery.steer_clearance_m` from what the camera sees. "
        "Turning: refused decisions whose stopping trajectory turned the vehicle in place "
        "(`recovery.turn_after_stops`; they stay counted as refusals). Final approach: decisions that sent "
        "the trajectory straight to the goal instead (`recovery.final_approach_m`; not learned). Kept: "
        "decisions that sent nothing while the plan sent before flew on (config `keeping`); committed: of "
        "those, the ones kept because the plan was younger than `keeping.commit_s`.",
        "",
    ]
    if summaries:
        plot_outcomes(out / "outcomes.png", summaries)
        plot_latency(out / "latency.png", results)
        plot_overlays(out / "trajectories.png", specs, results, sim_config)
        lines += [
            "![outcomes](outcomes.png)",
            "",
            "![decision latency](latency.png)",
            "",
            "![top-down trajectories](trajectories.png)",
            "",
        ]
    snaps = sorted((out / "snapshots").glob("*/*.png")) if (out / "snapshots").is_dir() else []
    if snaps:
        lines += ["## rviz snapshots", ""]
        lines += [f"![{p.parent.name} {p.stem}]({p.relative_to(out)})" for p in snaps]
        lines.append("")
    bench = bench_lines(summaries)
    lines += ["## BENCH", "", "```", *bench, "```", ""]
    report = out / "report.md"
    report.write_text("\n".join(lines))
    for b in bench:
        print(b, flush=True)
    return report
