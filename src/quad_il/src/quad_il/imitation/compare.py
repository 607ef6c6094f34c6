"""Closed-loop comparison of interactive imitation-learning runs, round by round (issue 9, docs/RESULTS.md).

    python -m quad_il.imitation.compare --baseline BC=results/il_bc_eval \\
        --run DAgger=runs/dagger_cmp --run HG-DAgger=runs/hg_dagger_cmp --out results/il_comparison

A run is an `imitation_learning_manager.py` run directory: round r's `metrics/cpp.jsonl` is the evaluation of
the policy trained after round r (policy generation r + 1). A baseline is a `run_eval` output directory
(its `cpp.jsonl`): generation 0, the policy every run started from. Per (algorithm, generation): episodes,
success, collision and timeout rates; how the episodes failed (median closest approach to the goal and median
highest altitude, from the recorded trajectories and the evaluation's `episodes.json`; the share of the
policy's decisions refused by the depth check and by the acceleration limit); and from the round's data the
records and who flew them. Output:
`comparison.md` (table and the command), `comparison.json`, `comparison.png` (success and collision rate per
generation, one line per algorithm). Rounds without an evaluation yet are left out (and listed).
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

from quad_il.evaluation.episodes import EpisodeResult, read_episodes, read_results
from quad_il.evaluation.metrics import summarise
from quad_il.evaluation.stats import wilson_interval
from quad_il.inference.core import VERDICT_LABELS
from quad_il.tools.cli import HelpFormatter


class CompareError(ValueError):
    """A run or baseline directory that cannot be read as asked."""


@dataclass(frozen=True)
class GenerationRow:
    algorithm: str
    generation: int  # 0 = the starting policy; r + 1 = trained after round r
    episodes: int
    success_rate: float
    collision_rate: float
    timeout_rate: float
    median_closest_m: float  # median over episodes of the smallest distance to the goal (NaN: no goals known)
    median_highest_m: float  # median over episodes of the highest altitude flown
    refused_depth: float  # share of the policy's decisions refused by the depth check
    refused_accel: float  # ... by the acceleration limit
    records: int | None  # the round's recorded rows (None for the baseline)
    expert_steps: int | None
    learner_steps: int | None


def _summary_row(
    algorithm: str, generation: int, jsonl: Path, data_dir: Path | None, controller: str
) -> GenerationRow:
    results = read_results(jsonl)
    if not results:
        raise CompareError(f"{jsonl}: no evaluation episodes")
    s = summarise(controller, results)
    closest, highest, depth, accel = failure_modes(results, jsonl.parent / "episodes.json")
    records = expert = learner = None
    if data_dir is not None and data_dir.is_dir():
        records, expert, learner = _round_steps(data_dir)
    return GenerationRow(
        algorithm,
        generation,
        s.episodes,
        s.success_rate,
        s.collision_rate,
        s.timeout_rate,
        closest,
        highest,
        depth,
        accel,
        records,
        expert,
        learner,
    )


# A decision is a network output the safety layer judged: its verdict is counted under one of these names.
VERDICTS = VERDICT_LABELS


def _median(values: list[float]) -> float:
    finite = [x for x in values if math.isfinite(x)]
    return statistics.median(finite) if finite else math.nan


def failure_modes(results: list[EpisodeResult], episodes_json: Path) -> tuple[float, float, float, float]:
    """(median closest approach to the goal, median highest altitude, share of decisions refused by the depth
    check, share refused by the acceleration limit). Goals come from `episodes_json` (run_eval's list of
    episodes, matched by index); without it the closest approach is NaN."""
    goals = {}
    if episodes_json.is_file():
        goals = {e.index: e.goal_world for e in read_episodes(episodes_json)}
    closest, highest = [], []
    for r in results:
        if not r.trajectory:
            continue
        highest.append(max(p[3] for p in r.trajectory))
        g = goals.get(r.index)
        if g is not None:
            closest.append(min(math.dist(p[1:4], g) for p in r.trajectory))
    decisions = sum(r.counts.get(v, 0) for r in results for v in VERDICTS)
    depth = sum(r.counts.get("collision_in_depth", 0) for r in results)
    accel = sum(r.counts.get("acceleration_limit", 0) for r in results)
    share = (lambda n: n / decisions) if decisions else (lambda n: math.nan)
    return _median(closest), _median(highest), share(depth), share(accel)


def _round_steps(data_dir: Path) -> tuple[int, int, int]:
    from quad_il.imitation.dataset import read_records
    from quad_il.imitation.types import Controller

    records = expert = learner = 0
    for r in read_records(data_dir):
        records += 1
        expert += r.controller == Controller.EXPERT
        learner += r.controller == Controller.LEARNER
    return records, expert, learner


def run_rows(algorithm: str, run_dir: Path, controller: str = "cpp") -> tuple[list[GenerationRow], list[int]]:
    """Rows of every evaluated round of a manager run, and the rounds not evaluated yet."""
    rounds = sorted(run_dir.glob("round_[0-9][0-9][0-9]"))
    if not rounds:
        raise CompareError(f"{run_dir}: no round_XXX directories (not a manager run directory)")
    rows, missing = [], []
    for rd in rounds:
        r = int(rd.name.split("_")[1])
        jsonl = rd / "metrics" / f"{controller}.jsonl"
        if not read_results(jsonl):
            missing.append(r)
            continue
        rows.append(_summary_row(algorithm, r + 1, jsonl, rd / "data", controller))
    return rows, missing


def baseline_row(algorithm: str, eval_dir: Path, controller: str = "cpp") -> GenerationRow:
    jsonl = eval_dir / f"{controller}.jsonl"
    if not jsonl.is_file():
        raise CompareError(f"{eval_dir}: no {controller}.jsonl (not a run_eval output directory)")
    return _summary_row(algorithm, 0, jsonl, None, controller)


def _pct(x: float) -> str:
    return "-" if math.isnan(x) else f"{100.0 * x:.0f} %"


def _m(x: float) -> str:
    return "-" if math.isnan(x) else f"{x:.1f} m"


def write_comparison(
    out: Path, baselines: list[GenerationRow], runs: dict[str, list[GenerationRow]], command: str
) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    lines = [
        "# Interactive imitation learning: closed-loop results per round",
        "",
        f"Command: `{command}`",
        "",
        "Generation 0 is the starting policy; generation r + 1 the policy trained after round r (on the",
        "starting data plus rounds 0..r). Round records: the rows the round recorded (HG-DAgger keeps only",
        "expert-controlled steps), and who flew those steps (the expert flies a DAgger step with beta = 0",
        "only when the learner has no plan for it). Success CI: the 95 % Wilson score interval of the rate.",
        "Closest approach to the goal and highest altitude:",
        "medians over the episodes; refused: the share of the policy's decisions refused by the depth check",
        "and by the acceleration limit.",
        "",
        "| algorithm | generation | episodes | success (95 % CI) | collision | timeout "
        "| median closest approach | median highest altitude | refused: depth / accel. | round records "
        "| recorded steps flown by expert / learner |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    all_rows = list(baselines) + [r for rows in runs.values() for r in rows]
    for r in all_rows:
        steps = "-" if r.records is None else f"{r.expert_steps} / {r.learner_steps}"
        lo, hi = wilson_interval(round(r.success_rate * r.episodes), r.episodes)
        lines.append(
            f"| {r.algorithm} | {r.generation} | {r.episodes} | {_pct(r.success_rate)} "
            f"({100 * lo:.0f}-{100 * hi:.0f} %) | "
            f"{_pct(r.collision_rate)} | {_pct(r.timeout_rate)} | {_m(r.median_closest_m)} | "
            f"{_m(r.median_highest_m)} | {_pct(r.refused_depth)} / {_pct(r.refused_accel)} | "
            f"{'-' if r.records is None else r.records} | {steps} |"
        )
    lines += ["", "![success and collision rate per generation](comparison.png)", ""]
    (out / "comparison.md").write_text("\n".join(lines))
    (out / "comparison.json").write_text(json.dumps([asdict(r) for r in all_rows], indent=1))
    _plot(out / "comparison.png", baselines, runs)
    return out / "comparison.md"


def _plot(path: Path, baselines: list[GenerationRow], runs: dict[str, list[GenerationRow]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharex=True)
    for ax, key, title in [
        (axes[0], "success_rate", "success rate"),
        (axes[1], "collision_rate", "collision rate"),
    ]:
        for name, rows in runs.items():
            series = sorted(baselines + rows, key=lambda r: r.generation)
            ax.plot(
                [r.generation for r in series],
                [100.0 * getattr(r, key) for r in series],
                marker="o",
                label=name,
            )
        for b in baselines:
            ax.axhline(100.0 * getattr(b, key), color="grey", lw=0.8, ls="--")
        ax.set_title(title)
        ax.set_xlabel("policy generation (0 = start)")
        ax.set_ylabel("% of evaluation episodes")
        ax.set_ylim(-5, 105)
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _labelled(text: str, flag: str) -> tuple[str, Path]:
    name, sep, path = text.partition("=")
    if not sep or not name or not path:
        raise CompareError(f"{flag} {text!r}: expected NAME=DIRECTORY")
    return name, Path(path)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        formatter_class=HelpFormatter, prog="quad_il.imitation.compare", description=__doc__.splitlines()[0]
    )
    ap.add_argument("--run", action="append", default=[], help="NAME=manager run directory; repeat")
    ap.add_argument("--baseline", action="append", default=[], help="NAME=run_eval output directory")
    ap.add_argument("--controller", default="cpp", help="the evaluated controller")
    ap.add_argument("--out", required=True, help="output directory")
    args = ap.parse_args(argv)
    try:
        if not args.run:
            raise CompareError("give at least one --run NAME=DIRECTORY")
        baselines = [
            baseline_row(n, p, args.controller)
            for n, p in (_labelled(b, "--baseline") for b in args.baseline)
        ]
        runs: dict[str, list[GenerationRow]] = {}
        for text in args.run:
            name, path = _labelled(text, "--run")
            rows, missing = run_rows(name, path, args.controller)
            if missing:
                print(f"compare: {name}: rounds {missing} have no evaluation yet (left out)", file=sys.stderr)
            runs[name] = rows
        command = "python -m quad_il.imitation.compare " + " ".join(
            argv if argv is not None else sys.argv[1:]
        )
        report = write_comparison(Path(args.out), baselines, runs, command)
    except (CompareError, OSError, ValueError) as e:
        print(f"compare: error: {e}", file=sys.stderr)
        return 2
    print(f"compare: {report}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
