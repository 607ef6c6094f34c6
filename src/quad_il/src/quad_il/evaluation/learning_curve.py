"""The learning curve of a policy recipe (issue 33): closed-loop success against the number of training
samples and against the DAgger round, one point per trained policy, read from run_eval output directories.

    python -m quad_il.evaluation.learning_curve SPEC.yaml [--out FIGURE.png] [--table FILE.md]
        [--controller cpp]

SPEC is a YAML file:

    title: Network alone (bare), dev set        # optional, the figure's title
    points:
      - name: bc_28k                     # any label, unique
        samples: 28572                   # training samples the policy was trained on (> 0)
        round: 0                         # DAgger round: 0 = behaviour cloning on the expert's data only
        series: bc                       # optional: the curve the point belongs to (default "dagger" for
                                         #   round > 0, else "bc"); a DAgger series names its round-0
                                         #   policy as a point of its own (same eval)
        eval: results/priv_h15_dev_bare  # a complete run_eval output directory (relative: to SPEC's
                                         #   directory first, then the working directory)
        recorded:                        # optional: the evaluation's counts, kept in the SPEC so that the
          episodes: 100                  #   curve survives its directory (results/ is not in the
          goal_reached: 35               #   repository); used when the directory is missing, checked
          collision: 60                  #   against it when it is there (--print-recorded prints these)
          episodes_sha256: 9c0e...       #   sha256 of the evaluation's episodes (episodes_digest)
          note: flown on machine X       #   optional free text

Each point's success is the share of the run's episodes whose outcome is goal_reached, with its 95 % Wilson
interval. Every point must have been evaluated on the same episodes (equal episodes.json, or equal
episodes_sha256 for a recorded point), so the curve compares like with like. Prints a Markdown table (also
written with --table); --out draws two panels: success against training samples (log scale, one line per
series) and against the DAgger round. Exit status 2 on a bad SPEC or an incomplete evaluation, naming the
point and what is wrong.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import yaml

from quad_il.evaluation.compare import CompareError, load_run
from quad_il.evaluation.stats import format_rate, wilson_interval
from quad_il.tools.cli import HelpFormatter

_POINT_KEYS = {"name", "samples", "round", "series", "eval", "recorded"}
_RECORDED_KEYS = {"episodes", "goal_reached", "collision", "episodes_sha256", "note"}


class LearningCurveError(ValueError):
    """A SPEC that cannot be drawn; the message names the point and the key."""


def _int_key(p: dict, key: str, where: str, minimum: int) -> int:
    v = p.get(key)
    if isinstance(v, bool) or not isinstance(v, int) or v < minimum:
        raise LearningCurveError(f"{where}: '{key}' must be an integer >= {minimum}, got {v!r}")
    return v


def _resolve(spec_dir: Path, text: str) -> Path:
    p = Path(text)
    if p.is_absolute():
        return p
    return spec_dir / p if (spec_dir / p).exists() else p  # else: relative to the working directory


@dataclass(frozen=True)
class PointSpec:
    """One point of a SPEC, checked, before its evaluation is read."""

    name: str
    samples: int
    round: int
    series: str
    eval_dir: Path
    recorded: dict | None


def episodes_digest(episodes: list) -> str:
    """sha256 of an evaluation's episodes (the EpisodeSpec list of its episodes.json), independent of the
    file's formatting."""
    rows = [dataclasses.asdict(e) for e in episodes]
    return hashlib.sha256(json.dumps(rows, sort_keys=True).encode()).hexdigest()


def _parse_recorded(r: object, where: str) -> dict:
    if not isinstance(r, dict):
        raise LearningCurveError(
            f"{where}: 'recorded' must be a mapping ({', '.join(sorted(_RECORDED_KEYS))})"
        )
    bad = set(r) - _RECORDED_KEYS
    if bad:
        raise LearningCurveError(f"{where}: recorded: unknown key(s) {sorted(bad)}")
    where = f"{where}: recorded"
    out = {
        "episodes": _int_key(r, "episodes", where, 1),
        "goal_reached": _int_key(r, "goal_reached", where, 0),
        "collision": _int_key(r, "collision", where, 0),
    }
    if out["goal_reached"] + out["collision"] > out["episodes"]:
        raise LearningCurveError(f"{where}: goal_reached + collision > episodes")
    digest = r.get("episodes_sha256")
    if not (isinstance(digest, str) and len(digest) == 64 and all(c in "0123456789abcdef" for c in digest)):
        raise LearningCurveError(f"{where}: 'episodes_sha256' must be 64 lowercase hex digits")
    out["episodes_sha256"] = digest
    return out


@dataclass(frozen=True)
class CurvePoint(PointSpec):
    """A point of the SPEC with its evaluation's outcome counts."""

    episodes: int
    successes: int
    collisions: int

    @property
    def rate(self) -> float:
        return self.successes / self.episodes

    @property
    def interval(self) -> tuple[float, float]:
        return wilson_interval(self.successes, self.episodes)


def parse_spec(spec_path: str | Path) -> tuple[str, list[PointSpec]]:
    """The SPEC's title and points, checked key by key (the evaluation directories are not read)."""
    spec_path = Path(spec_path)
    try:
        tree = yaml.safe_load(spec_path.read_text())
    except OSError as e:
        raise LearningCurveError(f"{spec_path}: cannot read: {e.strerror}") from None
    except yaml.YAMLError as e:
        raise LearningCurveError(f"{spec_path}: not YAML: {e}") from None
    if not isinstance(tree, dict) or not isinstance(tree.get("points"), list) or not tree["points"]:
        raise LearningCurveError(f"{spec_path}: needs a non-empty list 'points' (see --help)")
    unknown = set(tree) - {"title", "points"}
    if unknown:
        raise LearningCurveError(f"{spec_path}: unknown top-level key(s) {sorted(unknown)} (title, points)")
    points: list[PointSpec] = []
    for i, p in enumerate(tree["points"]):
        where = f"{spec_path}: points[{i}]"
        if not isinstance(p, dict):
            raise LearningCurveError(f"{where}: must be a mapping (name, samples, round, eval)")
        bad = set(p) - _POINT_KEYS
        if bad:
            raise LearningCurveError(
                f"{where}: unknown key(s) {sorted(bad)} (allowed: {', '.join(sorted(_POINT_KEYS))})"
            )
        name = p.get("name")
        if not isinstance(name, str) or not name:
            raise LearningCurveError(f"{where}: 'name' must be a non-empty string")
        where = f"{spec_path}: point {name!r}"
        if any(q.name == name for q in points):
            raise LearningCurveError(f"{where}: the name is used twice")
        samples = _int_key(p, "samples", where, 1)
        rnd = _int_key(p, "round", where, 0)
        series = p.get("series", "dagger" if rnd > 0 else "bc")
        if not isinstance(series, str) or not series:
            raise LearningCurveError(f"{where}: 'series' must be a non-empty string")
        if not isinstance(p.get("eval"), str):
            raise LearningCurveError(f"{where}: 'eval' must name a run_eval output directory")
        recorded = _parse_recorded(p["recorded"], where) if "recorded" in p else None
        points.append(PointSpec(name, samples, rnd, series, _resolve(spec_path.parent, p["eval"]), recorded))
    title = tree.get("title", "")
    return (title if isinstance(title, str) else str(title)), points


def load_points(spec_path: str | Path, controller: str = "cpp") -> tuple[str, list[CurvePoint]]:
    """The SPEC's title and its points with their outcome counts."""
    title, specs = parse_spec(spec_path)
    points: list[CurvePoint] = []
    reference: tuple[Path, str] | None = None
    for p in specs:
        where = f"{spec_path}: point {p.name!r}"
        counts = read_counts(p, controller, where)
        if reference is None:
            reference = (p.eval_dir, counts["episodes_sha256"])
        elif counts["episodes_sha256"] != reference[1]:
            raise LearningCurveError(
                f"{where}: {p.eval_dir} holds other episodes than {reference[0]} (episodes.json differ): "
                "every point must be evaluated on the same episodes"
            )
        points.append(
            CurvePoint(
                **vars(p),
                episodes=counts["episodes"],
                successes=counts["goal_reached"],
                collisions=counts["collision"],
            )
        )
    return title, points


def read_counts(p: PointSpec, controller: str, where: str) -> dict:
    """The point's counts (episodes, goal_reached, collision, episodes_sha256): from its evaluation
    directory, checked against its recorded counts if it has them; from the recorded counts alone when the
    directory is gone."""
    if p.recorded is not None and not p.eval_dir.exists():
        return p.recorded
    try:
        episodes, results = load_run(p.eval_dir, controller)
    except CompareError as e:
        raise LearningCurveError(f"{where}: {e}") from None
    outcomes = [r.outcome for r in results.values()]
    if not outcomes:
        raise LearningCurveError(f"{where}: {p.eval_dir} holds no episodes")
    counts = {
        "episodes": len(outcomes),
        "goal_reached": outcomes.count("goal_reached"),
        "collision": outcomes.count("collision"),
        "episodes_sha256": episodes_digest(episodes),
    }
    if p.recorded is not None:
        differ = [k for k in counts if counts[k] != p.recorded[k]]
        if differ:
            got = ", ".join(f"{k} {p.recorded[k]} recorded, {counts[k]} in the directory" for k in differ)
            raise LearningCurveError(f"{where}: {p.eval_dir} does not match its recorded counts ({got})")
    return counts


def recorded_yaml(spec_path: str | Path, controller: str = "cpp") -> str:
    """Each point's `recorded:` mapping as read from its evaluation directory (to paste into the SPEC)."""
    _, specs = parse_spec(spec_path)
    lines = []
    for p in specs:
        c = read_counts(p, controller, f"{spec_path}: point {p.name!r}")
        lines.append(
            f"{p.name}: recorded: {{episodes: {c['episodes']}, goal_reached: {c['goal_reached']}, "
            f"collision: {c['collision']}, episodes_sha256: {c['episodes_sha256']}}}"
        )
    return "\n".join(lines) + "\n"


def table(points: list[CurvePoint]) -> str:
    rows = [
        "| point | series | DAgger round | training samples | success [95 % CI] | collision [95 % CI] "
        "| evaluation |",
        "|---|---|---|---|---|---|---|",
    ]
    for p in points:
        rows.append(
            f"| {p.name} | {p.series} | {p.round} | {p.samples:,} | {format_rate(p.successes, p.episodes)} | "
            f"{format_rate(p.collisions, p.episodes)} | `{p.eval_dir}` |"
        )
    return "\n".join(rows) + "\n"


def plot(points: list[CurvePoint], out: str | Path, title: str = "") -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_n, ax_r) = plt.subplots(1, 2, figsize=(10, 4))
    series = list(dict.fromkeys(p.series for p in points))
    for s in series:
        pts = sorted((p for p in points if p.series == s), key=lambda p: (p.samples, p.round))
        x = [p.samples for p in pts]
        y = [100 * p.rate for p in pts]
        err = [[100 * (p.rate - p.interval[0]) for p in pts], [100 * (p.interval[1] - p.rate) for p in pts]]
        ax_n.errorbar(x, y, yerr=err, marker="o", capsize=3, label=s)
        for p in pts:
            ax_n.annotate(
                p.name, (p.samples, 100 * p.rate), textcoords="offset points", xytext=(4, 4), fontsize=7
            )
    ax_n.set_xscale("log")
    ax_n.set_xlabel("training samples")
    ax_n.set_ylabel("success (%, 95 % Wilson interval)")
    ax_n.set_ylim(0, 100)
    ax_n.grid(alpha=0.3)
    ax_n.legend()
    # Against the round: every series (a DAgger series lists its round-0 start as a point of its own).
    rounds = sorted({p.round for p in points})
    for s in series:
        pts = sorted((p for p in points if p.series == s), key=lambda p: (p.round, p.samples))
        ax_r.errorbar(
            [p.round for p in pts],
            [100 * p.rate for p in pts],
            yerr=[
                [100 * (p.rate - p.interval[0]) for p in pts],
                [100 * (p.interval[1] - p.rate) for p in pts],
            ],
            marker="o",
            capsize=3,
            label=s,
        )
    ax_r.set_xticks(rounds)
    ax_r.set_xlabel("DAgger round (0 = behaviour cloning)")
    ax_r.set_ylim(0, 100)
    ax_r.grid(alpha=0.3)
    n = points[0].episodes
    fig.suptitle(f"{title} ({n} episodes per point)".strip() if title else f"{n} episodes per point")
    fig.tight_layout()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m quad_il.evaluation.learning_curve",
        formatter_class=HelpFormatter,
        description=__doc__,
    )
    ap.add_argument("spec", help="the points: a YAML file (format above)")
    ap.add_argument("--out", default=None, help="write the figure (PNG) here")
    ap.add_argument("--table", default=None, help="also write the Markdown table here")
    ap.add_argument("--controller", default="cpp", help="the controller whose results count (cpp, py)")
    ap.add_argument(
        "--print-recorded",
        action="store_true",
        help="print each point's recorded counts (for the SPEC) and exit",
    )
    a = ap.parse_args(argv)
    if a.print_recorded:
        try:
            print(recorded_yaml(a.spec, a.controller), end="")
        except LearningCurveError as e:
            print(f"learning_curve: error: {e}", file=sys.stderr)
            return 2
        return 0
    try:
        title, points = load_points(a.spec, a.controller)
    except LearningCurveError as e:
        print(f"learning_curve: error: {e}", file=sys.stderr)
        return 2
    text = table(points)
    print(text, end="")
    if a.table:
        Path(a.table).write_text(text)
    if a.out:
        print(f"figure: {plot(points, a.out, title)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
