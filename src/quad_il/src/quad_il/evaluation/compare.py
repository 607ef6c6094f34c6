"""Paired comparison of two closed-loop evaluations of the same episodes (docs/inference.md, "Comparing two
evaluations").

The evaluation repeats episode for episode, so two runs that differ in one thing (policy file, policy config)
can be compared pair by pair instead of by their rates alone:

    python -m quad_il.evaluation.compare results/A results/B [--controller cpp] [--out FILE.md]

Prints (and with --out writes) a Markdown summary: the outcome counts of each run, how many episodes flew
identically (same outcome and the same 10 Hz trajectory), the episodes whose outcome differs, goals gained and
lost, and the exact two-sided McNemar test on the discordant goal pairs (the probability of a split at least
this uneven if the change did not matter). Exit status 2 when the runs hold different episodes or a results
file is missing or incomplete.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from dataclasses import dataclass
from pathlib import Path

from quad_il.evaluation.episodes import EpisodeResult, read_episodes, read_results
from quad_il.evaluation.pin import read_pin
from quad_il.evaluation.stats import mcnemar_exact_p
from quad_il.tools.cli import HelpFormatter

OUTCOME_ORDER = ("goal_reached", "collision", "timeout")


class CompareError(ValueError):
    """The two evaluations cannot be paired; the message says why."""


@dataclass(frozen=True)
class Comparison:
    controller: str
    episodes: int
    counts_a: dict[str, int]
    counts_b: dict[str, int]
    identical: int  # same outcome and the same trajectory
    changed: list[tuple[int, int, str, str]]  # (index, seed, outcome in A, outcome in B)
    goals_gained: int  # reached in B only
    goals_lost: int  # reached in A only
    mcnemar_p: float
    cpus: tuple[str, str] = ("", "")  # the runs' pinned CPUs ('' = not recorded)


def load_run(run: Path, controller: str) -> tuple[list, dict[int, EpisodeResult]]:
    """The episodes and the controller's results of one complete run_eval output directory; CompareError
    naming the file when one is missing or a result is."""
    episodes_file = run / "episodes.json"
    if not episodes_file.is_file():
        raise CompareError(f"{run}: no episodes.json (not a run_eval output directory)")
    results_file = run / f"{controller}.jsonl"
    if not results_file.is_file():
        raise CompareError(f"{run}: no {controller}.jsonl (was the {controller} controller evaluated?)")
    specs = read_episodes(episodes_file)
    results = {r.index: r for r in read_results(results_file) if r.controller == controller}
    missing = [s.index for s in specs if s.index not in results]
    if missing:
        raise CompareError(
            f"{results_file}: {len(missing)} of {len(specs)} episodes have no result (e.g. index "
            f"{missing[0]}); finish the run (run_eval resumes) before comparing"
        )
    return specs, results


def compare(run_a: str | Path, run_b: str | Path, controller: str = "cpp") -> Comparison:
    a_dir, b_dir = Path(run_a), Path(run_b)
    specs_a, a = load_run(a_dir, controller)
    specs_b, b = load_run(b_dir, controller)
    if specs_a != specs_b:
        raise CompareError(
            f"{a_dir} and {b_dir} hold different episodes (episodes.json differ): only evaluations of the "
            "same seeds, episode count and start/goal settings pair up"
        )

    def count(results: dict[int, EpisodeResult]) -> dict[str, int]:
        return {o: sum(r.outcome == o for r in results.values()) for o in OUTCOME_ORDER}

    changed = []
    identical = gained = lost = 0
    for s in specs_a:
        ra, rb = a[s.index], b[s.index]
        if ra.outcome == rb.outcome and ra.trajectory == rb.trajectory:
            identical += 1
        if ra.outcome != rb.outcome:
            changed.append((s.index, s.seed, ra.outcome, rb.outcome))
        gained += rb.outcome == "goal_reached" and ra.outcome != "goal_reached"
        lost += ra.outcome == "goal_reached" and rb.outcome != "goal_reached"
    return Comparison(
        controller,
        len(specs_a),
        count(a),
        count(b),
        identical,
        changed,
        gained,
        lost,
        mcnemar_exact_p(gained, lost),
        (_pinned_cpu(a_dir), _pinned_cpu(b_dir)),
    )


def _pinned_cpu(run: Path) -> str:
    try:
        pin = read_pin(run)
    except ValueError:
        return ""
    return pin.cpu if pin is not None else ""


def markdown(c: Comparison, name_a: str, name_b: str) -> str:
    lines = [
        f"Paired comparison, controller `{c.controller}`, {c.episodes} episodes: "
        f"A = `{name_a}`, B = `{name_b}`",
        "",
        "| run | " + " | ".join(OUTCOME_ORDER) + " |",
        "|---|" + "---|" * len(OUTCOME_ORDER),
        "| A | " + " | ".join(str(c.counts_a[o]) for o in OUTCOME_ORDER) + " |",
        "| B | " + " | ".join(str(c.counts_b[o]) for o in OUTCOME_ORDER) + " |",
        "",
        f"- Flown identically (same outcome and trajectory): {c.identical} of {c.episodes}.",
        f"- Goals gained in B: {c.goals_gained}; lost: {c.goals_lost}; exact McNemar p = {c.mcnemar_p:.3g}.",
    ]
    if all(c.cpus) and c.cpus[0] != c.cpus[1]:
        lines.append(
            f"- **Flown on different CPUs** (A: {c.cpus[0]}; B: {c.cpus[1]}): a closed loop rounds "
            "differently on another instruction set, so the episodes do not pair; only the rates compare."
        )
    if c.changed:
        lines += ["", "| episode | world seed | A | B |", "|---|---|---|---|"]
        lines += [f"| {i} | {seed} | {oa} | {ob} |" for i, seed, oa, ob in c.changed]
    else:
        lines.append("- No episode changed its outcome.")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("run_a", help="run_eval output directory (the baseline)")
    ap.add_argument("run_b", help="run_eval output directory of the same episodes (the variant)")
    ap.add_argument(
        "--controller", default="cpp", choices=("expert", "py", "cpp"), help="controller compared"
    )
    ap.add_argument(
        "--out", default="", help="also write the summary to this file (Markdown, or JSON with --json)"
    )
    ap.add_argument(
        "--json",
        action="store_true",
        help="print the comparison as one JSON object (counts, gained, lost, McNemar p, changed episodes, "
        "CPUs) for scripts, instead of Markdown",
    )
    args = ap.parse_args(argv)
    try:
        c = compare(args.run_a, args.run_b, args.controller)
    except (CompareError, ValueError, OSError) as e:
        print(f"compare: {e}", file=sys.stderr)
        return 2
    if args.json:
        obj = {"run_a": args.run_a, "run_b": args.run_b, **dataclasses.asdict(c)}
        obj["changed"] = [dict(zip(("index", "seed", "a", "b"), ch, strict=True)) for ch in c.changed]
        text = json.dumps(obj, indent=1) + "\n"
    else:
        text = markdown(c, args.run_a, args.run_b)
    print(text, end="")
    if args.out:
        Path(args.out).write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
