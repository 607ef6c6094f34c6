"""The closed-loop evaluation's report: OUT/report.md with what the run was pinned to (hashes, tier, set,
commit), the per-controller table with a 95 % Wilson interval beside every rate, plots (outcome bars with
their intervals, decision latency histograms, top-down trajectory overlays) and the rviz snapshots, and the
BENCH lines on stdout: eval_expert_{success,collision,timeout}_rate and eval_<py|cpp>_<tier>_{...}_rate."""

from __future__ import annotations

import math
import subprocess
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation

from quad_il.collection.episodes import EpisodeSpec
from quad_il.evaluation.episodes import EpisodeResult, read_results
from quad_il.evaluation.metrics import ControllerSummary, summarise
from quad_il.evaluation.pin import RunPin
from quad_il.evaluation.stats import format_rate, wilson_interval
from quad_il.tools.binaries import BinaryNotFound, find_binary

COLOURS = {"expert": "tab:blue", "py": "tab:green", "cpp": "tab:orange"}
NAMES = {"expert": "expert (fast_planner)", "py": "policy, Python", "cpp": "policy, C++ (LibTorch)"}


RATES = (("goal_reached", "success"), ("collision", "collision"), ("timeout", "timeout"))


def bench_name(controller: str, tier: str) -> str:
    """eval_expert (the expert has no tier) or eval_<controller>_<tier>."""
    return "eval_expert" if controller == "expert" else f"eval_{controller}_{tier}"


def bench_lines(summaries: dict[str, ControllerSummary], tier: str) -> list[str]:
    lines = []
    for c, s in summaries.items():
        for outcome, word in RATES:
            lines.append(f"BENCH {bench_name(c, tier)}_{word}_rate {s.count(outcome) / s.episodes:.4f} ratio")
    return lines


def _reproducible(s: ControllerSummary) -> str:
    if s.lockstep_timeouts is None:
        return "unknown (no lockstep count)"
    if s.lockstep_timeouts:
        return f"**no** ({s.lockstep_timeouts} lockstep timeouts)"
    return "yes"


def pin_lines(pin: RunPin | None) -> list[str]:
    """The report's account of what the run was flown with."""
    if pin is None:
        return ["Not pinned (a run made before pin.json existed): its policy and configs are unknown.", ""]
    dirty = " (with uncommitted changes: not reproducible from the commit alone)" if pin.dirty else ""
    rows = [
        ("tier", f"`{pin.tier}`" if pin.tier else "- (expert only)"),
        (
            "evaluation set",
            f"`{pin.eval_set}` (config/eval_sets.yaml)" if pin.eval_set else "- (seeds given)",
        ),
        ("policy", f"`{pin.policy_path}` sha256 `{pin.policy_sha256}`" if pin.policy_sha256 else "-"),
        (
            "policy node config",
            f"tier `{pin.tier}` of `{pin.policy_config_base}`, as flown: `policy_config.yaml` sha256 "
            f"`{pin.policy_config_sha256}`"
            if pin.policy_config_sha256
            else "-",
        ),
        ("simulator config", f"`{pin.sim_config_path}` sha256 `{pin.sim_config_sha256}`"),
        ("vehicle", f"sha256 `{pin.vehicle_sha256}`"),
        ("expert planner config", f"sha256 `{pin.planner_config_sha256}`"),
        ("box density", "the simulator config's" if pin.density is None else f"{pin.density:g} per 100 m^2"),
        ("commit", f"`{pin.commit}`{dirty}"),
        ("CPU", pin.cpu or "- (not recorded)"),
    ]
    return ["| pinned | value |", "|---|---|", *[f"| {k} | {v} |" for k, v in rows], ""]


TIER_WORDS = {
    "bare": "the network alone: only a non-finite output is refused, then the vehicle brakes",
    "safety": "the network with the safety layer: depth and limit checks refuse, a refusal brakes",
    "shield": "the network with every hand-written behaviour of the node config: safety, recovery, final "
    "approach, keeping the plan",
}


def _seed_ranges(seeds: list[int]) -> str:
    """[1, 2, 3, 7] -> '1-3, 7'."""
    parts: list[list[int]] = []
    for x in seeds:
        if parts and parts[-1][1] == x - 1:
            parts[-1][1] = x
        else:
            parts.append([x, x])
    return ", ".join(f"{a}" if a == b else f"{a}-{b}" for a, b in parts)


def _fmt(v: float, digits: int = 2, pct: bool = False) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    return f"{100 * v:.0f} %" if pct else f"{v:.{digits}f}"


def world_boxes(sim_config: Path, spec: EpisodeSpec) -> list[dict[str, Any]]:
    """The episode's world, regenerated exactly by quad_sim_world (same seed, config and clear zones as the
    simulator's reset); [] when the tool is not built."""
    try:
        tool = find_binary("quad_sim", "quad_sim_world")
    except BinaryNotFound:
        return []
    if not sim_config.is_file():
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
    corners = (signs * half) @ Rotation.from_quat(np.asarray(box["q_xyzw"])).as_matrix().T + np.asarray(
        box["center_m"]
    )
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
        ci = [wilson_interval(s.count(o), s.episodes) for o in ("goal_reached", "collision", "timeout")]
        err = np.array([[v - 100 * lo, 100 * hi - v] for v, (lo, hi) in zip(vals, ci, strict=True)]).T
        ax.bar(
            x + (i - (len(summaries) - 1) / 2) * w,
            vals,
            w,
            yerr=err,
            capsize=3,
            label=NAMES.get(c, c),
            color=COLOURS.get(c),
        )
    ax.set_xticks(x, [k for _, k in kinds])
    ax.set_ylabel("episodes (%, 95 % Wilson interval)")
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
    pin: RunPin | None = None,
) -> Path:
    results = {c: read_results(out / f"{c}.jsonl") for c in controllers}
    results = {c: rs for c, rs in results.items() if rs}
    summaries = {c: summarise(c, rs) for c, rs in results.items()}
    tier = (pin.tier if pin is not None and pin.tier else None) or options.get("tier") or "shield"
    sim_config = next(
        (out / f"sim_{c}.yaml" for c in controllers if (out / f"sim_{c}.yaml").is_file()),
        Path(options.get("sim_config", "")),
    )
    lines = [
        "# Closed-loop evaluation",
        "",
        f"{len(specs)} episodes on world seeds {_seed_ranges(sorted({s.seed for s in specs}))}, box density "
        f"{options.get('density') or 'of the sim config'}, start/goal {options.get('min_distance_m')}-"
        f"{options.get('max_distance_m')} m apart, episode timeout {options.get('episode_timeout_s')} s (sim "
        f"time), simulator in lockstep. "
        + (
            f"Policy nodes in tier **`{tier}`** ({TIER_WORDS.get(tier, tier)})."
            if any(c != "expert" for c in controllers)
            else "The expert alone (no policy, no tier)."
        ),
        "",
        *pin_lines(pin),
        "| controller | tier | episodes | success [95 % CI] | collision [95 % CI] | timeout [95 % CI] | "
        "reset/take-off failed | reproducible | mean time to goal (s) | mean path length (m) | "
        "min clearance (m) | median min clearance (m) | decision ms median | decision ms p99 | decisions | "
        "refusals (recovered) | final approach | kept (committed) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for c, s in summaries.items():
        lines.append(
            f"| {NAMES.get(c, c)} | {'-' if c == 'expert' else tier} | {s.episodes} | "
            f"{format_rate(s.count('goal_reached'), s.episodes)} | "
            f"{format_rate(s.count('collision'), s.episodes)} | "
            f"{format_rate(s.count('timeout'), s.episodes)} | "
            f"{_fmt(s.other_rate, pct=True)} | {_reproducible(s)} | {_fmt(s.mean_time_to_goal_s, 1)} | "
            f"{_fmt(s.mean_path_length_m, 1)} | {_fmt(s.min_clearance_m)} | "
            f"{_fmt(s.median_min_clearance_m)} | {_fmt(s.decision_ms_median, 3)} | "
            f"{_fmt(s.decision_ms_p99, 3)} | {s.decisions} | {s.refusals} ({s.recovered}) | "
            f"{s.final_approach} | {s.kept} ({s.committed}) |"
        )
    for c, why in skipped.items():
        lines.append(f"| {NAMES.get(c, c)} | not run: {why} |||||||||||||||||")
    lines += [
        "",
        "Success, collision and timeout are shares of all episodes, each with its 95 % Wilson score interval "
        "in brackets (scipy.stats.binomtest); time to goal and path length are means "
        "over the successful ones. Reproducible: no lockstep wait of the simulator timed out (a timeout "
        "lets sim time go on without a consumer, so the run may not repeat). Clearance: the minimum over the "
        "flight of the distance from the vehicle's "
        "centre to the nearest world box minus the vehicle box's circumscribed radius (a lower bound of the "
        "exact box-to-box clearance; the ground is not counted). Decision latency: policies preprocessing + "
        "forward + message (policy/decision), expert map update + plan (planner/timing). Refusals: decisions "
        "whose policy plan the safety layer refused; recovered: of those, the ones the recovery (policy "
        "config `recovery`) replaced with an accepted plan for a turned goal. Final approach: decisions "
        "that sent the trajectory straight to the goal instead (`recovery.final_approach_m`; not learned). "
        "Kept: decisions that sent nothing while the plan sent before flew on (config `keeping`); "
        "committed: of those, the ones kept because the plan was younger than `keeping.commit_s`.",
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
    bench = bench_lines(summaries, tier)
    lines += ["## BENCH", "", "```", *bench, "```", ""]
    report = out / "report.md"
    report.write_text("\n".join(lines))
    for b in bench:
        print(b, flush=True)
    return report
