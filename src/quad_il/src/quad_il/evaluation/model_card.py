"""Ship a trained policy with its model card (issue 33): the exported policy, its training configuration and a
MODEL.md that says exactly how it was made and what it reaches.

    python -m quad_il.evaluation.model_card --run runs/X --out models/quad_il_policy \
        [--eval results/test_bare --eval results/expert_test ...] [--no-hash-data] [--max-mb 25]

OUT receives policy.ts (copied from the run), train_config.yaml (the run's resolved configuration) and
MODEL.md:
- the training lineage: the run and, through `run.init_weights`, every run it was fine-tuned from, each with
  its exact command, commit, start time, training wall time, epochs and best validation loss; when the oldest
  run started from a checkpoint rebuilt from a shipped policy file (quad_il.learning.unfreeze), that file's
  hash and its own card's lineage, as the checkpoint recorded them;
- every dataset each run trained on: its path, samples, the command that collected it (the dataset manifest's
  run_info: launch, seeds, episodes, learner policy and planner config) and a content hash (sha256 over its
  shard files in name order; --no-hash-data skips it);
- the closed-loop results of every --eval directory (run_eval outputs): per controller the evaluation set,
  density, tier, success / collision / timeout with 95 % Wilson intervals, and the policy's success as a share
  of the expert's on the same set. A policy row must have been flown with exactly the shipped file (the eval's
  pin holds its sha256).

Exit status 2 naming the file when the run directory is incomplete, the policy is larger than --max-mb, or an
evaluation was flown with another policy or is incomplete.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shlex
import shutil
import subprocess
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import yaml

from quad_il.evaluation.compare import CompareError, load_run
from quad_il.evaluation.pin import read_pin
from quad_il.evaluation.stats import format_rate
from quad_il.tools.cli import HelpFormatter
from quad_il.tools.provenance import sha256_file

RUN_FILES = (
    "policy.ts",
    "config.yaml",
    "run_info.json",
    "summary.json",
    "metrics.csv",
    "dataset_manifest.json",
)
CONTROLLERS = ("expert", "cpp", "py")


class ModelCardError(ValueError):
    """The card cannot be written; the message names the file and what is wrong."""


@dataclass(frozen=True)
class EvalRow:
    eval_dir: Path
    controller: str
    eval_set: str
    density: float | None
    tier: str
    episodes: int
    counts: dict[str, int]


def _read_json(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise ModelCardError(f"{path}: cannot read: {e}") from None


def _check_run(run: Path) -> None:
    missing = [f for f in RUN_FILES if not (run / f).is_file()]
    if missing:
        raise ModelCardError(f"{run}: not a finished training run (missing {', '.join(missing)})")


def lineage(run: Path) -> list[Path]:
    """The run and every run it was fine-tuned from (run.init_weights), the oldest first."""
    chain: list[Path] = []
    while True:
        _check_run(run)
        if run.resolve() in [c.resolve() for c in chain]:
            raise ModelCardError(f"{run}: run.init_weights leads back to itself")
        chain.append(run)
        cfg = yaml.safe_load((run / "config.yaml").read_text()) or {}
        init = (cfg.get("run") or {}).get("init_weights")
        if not init:
            return chain[::-1]
        ckpt = Path(init)
        parent_is_run = ckpt.parent.name == "checkpoints" and all(
            (ckpt.parent.parent / f).is_file() for f in RUN_FILES
        )
        # Only a checkpoint outside a finished run is read (torch.load costs seconds per ancestor).
        if not parent_is_run and unfrozen_origin(ckpt) is not None:
            return chain[::-1]  # started from a shipped policy file: its card tells the rest
        if ckpt.parent.name != "checkpoints":
            raise ModelCardError(
                f"{run / 'config.yaml'}: run.init_weights {init} is not a training run's checkpoint "
                "(<run>/checkpoints/*.pt): its lineage cannot be described"
            )
        run = ckpt.parent.parent


def unfrozen_origin(ckpt: Path) -> dict | None:
    """The `unfrozen_from` record of a checkpoint rebuilt from an exported policy (quad_il.learning.unfreeze),
    or None for any other checkpoint or a missing or unreadable file."""
    if not ckpt.is_file():
        return None
    from quad_il.learning.checkpoint import CheckpointError, read_checkpoint_file

    try:
        obj = read_checkpoint_file(ckpt, "run.init_weights")
    except CheckpointError:
        return None
    origin = obj.get("unfrozen_from") if isinstance(obj, dict) else None
    return origin if isinstance(origin, dict) else None


def _commit_naming(sha256: str) -> str:
    """The oldest commit whose change to a MODEL.md adds or removes `sha256` (the commit that shipped that
    file), or "" when git cannot tell (no repository, no such commit)."""
    if len(sha256) != 64:
        return ""
    try:
        res = subprocess.run(
            ["git", "log", "--format=%h", f"-S{sha256}", "--", "*MODEL.md"],
            capture_output=True,
            text=True,
            check=False,
            timeout=60,
        )
    except (OSError, subprocess.SubprocessError):
        return ""
    commits = res.stdout.split() if res.returncode == 0 else []
    return commits[-1] if commits else ""


def _origin_section(first_run: Path) -> list[str]:
    """The card's section for the shipped policy the oldest run started from (empty when none)."""
    cfg = yaml.safe_load((first_run / "config.yaml").read_text()) or {}
    init = (cfg.get("run") or {}).get("init_weights")
    origin = unfrozen_origin(Path(init)) if init else None
    if origin is None:
        return []
    shipped_in = _commit_naming(str(origin.get("sha256", "")))
    out = [
        f"### The shipped policy `{first_run}` started from",
        "",
        f"`{origin.get('policy_file')}`, sha256 `{origin.get('sha256')}`"
        + (f" (shipped in commit `{shipped_in}`)" if shipped_in else "")
        + ", rebuilt as the training checkpoint "
        f"`{init}` (`{origin.get('command', 'python -m quad_il.learning.unfreeze')}`; BatchNorm statistics "
        f"from `{origin.get('calib') or 'none'}`). Its own card:",
        "",
    ]
    earlier = str(origin.get("model_card") or "").strip()
    if not earlier:
        return out + ["(not recorded: the file's directory held no MODEL.md naming its hash)", ""]
    # one heading level down, so that the earlier card's runs nest under this section
    return out + [("#" + ln if ln.startswith("#") else ln) for ln in earlier.splitlines()] + [""]


def dataset_hash(path: Path) -> str:
    """sha256 over the dataset's shard files (*.qdr) in name order, or over the .npz files for npz data."""
    files = sorted(path.glob("*.qdr")) if path.is_dir() else [path]
    if path.is_dir() and not files:
        files = sorted(path.glob("*.npz"))
    if not files:
        raise ModelCardError(f"{path}: no shard (.qdr) or .npz file to hash")
    h = hashlib.sha256()
    for f in files:
        h.update(f.name.encode())
        h.update(bytes.fromhex(sha256_file(f)))
    return h.hexdigest()


def _dataset_lines(manifest: dict, hash_data: bool) -> list[str]:
    lines = []
    for src in manifest.get("per_source", []):
        p = Path(src["path"])
        shown = p.relative_to(Path.cwd()) if p.is_relative_to(Path.cwd()) else p
        info = {}
        if (p / "manifest.yaml").is_file():
            info = (yaml.safe_load((p / "manifest.yaml").read_text()) or {}).get("run_info") or {}
        made = ", ".join(
            f"{k} `{v}`" for k, v in info.items() if k in ("launch", "seeds", "episodes", "policy")
        )
        planner = info.get("planner_config")
        digest = f"sha256 `{dataset_hash(p)}`" if hash_data else "not hashed"
        lines.append(
            f"  - `{shown}`: {src['num_samples']:,} samples; {made or 'no run_info'}"
            + (f"; expert `{Path(planner).name}`" if planner else "")
            + f"; {digest}"
        )
    return lines


def _run_section(run: Path, hash_data: bool) -> list[str]:
    info = _read_json(run / "run_info.json")
    summary = _read_json(run / "summary.json")
    rows = (run / "metrics.csv").read_text().splitlines()
    header = rows[0].split(",")
    wall = sum(float(r.split(",")[header.index("epoch_wall_s")]) for r in rows[1:] if r.strip())
    sw = info.get("software", {})
    argv = info.get("argv", [])
    cmd = "python " + shlex.join(argv) if argv else "(not recorded)"
    manifest = _read_json(run / "dataset_manifest.json")
    return [
        f"### `{run}`",
        "",
        "```bash",
        cmd,
        "```",
        "",
        f"- commit `{sw.get('commit', 'unknown')}`"
        + (" (with uncommitted changes)" if sw.get("dirty") else "")
        + f", started {info.get('started', '?')}, torch {sw.get('torch', '?')}, "
        f"{sw.get('torch_threads', '?')} thread(s), {info.get('world_size', 1)} process(es)",
        f"- {summary.get('epochs')} epochs, {wall / 60:.1f} min of training (sum of the epochs' wall time); "
        f"best epoch {summary.get('best_epoch')} (validation loss "
        f"{summary.get('best_val_loss', float('nan')):.4g}); "
        f"{manifest.get('num_samples', 0):,} samples, horizon {manifest.get('horizon_s')} s, "
        f"{manifest.get('num_ctrl_pts')} control points",
        "- data:",
        *_dataset_lines(manifest, hash_data),
        "",
    ]


def eval_rows(eval_dir: Path, policy_sha256: str) -> list[EvalRow]:
    try:
        pin = read_pin(eval_dir)
    except ValueError as e:
        raise ModelCardError(str(e)) from None
    if pin is None:
        raise ModelCardError(f"{eval_dir}: no pin.json (not a run_eval output directory)")
    rows = []
    for c in CONTROLLERS:
        if not (eval_dir / f"{c}.jsonl").is_file():
            continue
        if c != "expert" and pin.policy_sha256 != policy_sha256:
            raise ModelCardError(
                f"{eval_dir}: flown with policy sha256 {pin.policy_sha256[:12]}..., not the shipped one "
                f"({policy_sha256[:12]}...): evaluate the shipped file"
            )
        try:
            _, results = load_run(eval_dir, c)
        except CompareError as e:
            raise ModelCardError(str(e)) from None
        counts: dict[str, int] = {}
        for r in results.values():
            counts[r.outcome] = counts.get(r.outcome, 0) + 1
        rows.append(
            EvalRow(
                eval_dir,
                c,
                pin.eval_set or "-",
                pin.density,
                pin.tier if c != "expert" else "-",
                len(results),
                counts,
            )
        )
    if not rows:
        raise ModelCardError(f"{eval_dir}: holds no controller's results (expert.jsonl, cpp.jsonl, py.jsonl)")
    return rows


def results_table(rows: list[EvalRow]) -> list[str]:
    expert = {(r.eval_set, r.density): r for r in rows if r.controller == "expert"}
    out = [
        "| set | density | controller | tier | episodes | success [95 % CI] | collision | timeout | "
        "share of the expert's success | evaluation |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in sorted(rows, key=lambda r: (r.eval_set, r.density or 0.0, r.controller != "expert", r.tier)):
        ok = r.counts.get("goal_reached", 0)
        e = expert.get((r.eval_set, r.density))
        share = "-"
        if r.controller != "expert" and e is not None and e.counts.get("goal_reached", 0):
            share = f"{100 * (ok / r.episodes) / (e.counts['goal_reached'] / e.episodes):.0f} %"
        out.append(
            f"| {r.eval_set} | {'sim config' if r.density is None else r.density} | {r.controller} | "
            f"{r.tier} | {r.episodes} | {format_rate(ok, r.episodes)} | "
            f"{format_rate(r.counts.get('collision', 0), r.episodes)} | "
            f"{format_rate(r.counts.get('timeout', 0), r.episodes)} | {share} | `{r.eval_dir}` |"
        )
    return out


def write_card(
    run: str | Path,
    out: str | Path,
    evals: Sequence[str | Path] = (),
    *,
    hash_data: bool = True,
    max_mb: float = 25.0,
) -> Path:
    run, out = Path(run), Path(out)
    chain = lineage(run)
    policy = run / "policy.ts"
    size_mb = policy.stat().st_size / 2**20
    if size_mb > max_mb:
        raise ModelCardError(
            f"{policy}: {size_mb:.1f} MB, more than the {max_mb:g} MB a shipped policy may have"
        )
    digest = sha256_file(policy)
    rows = [row for d in evals for row in eval_rows(Path(d), digest)]
    out.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(policy, out / "policy.ts")
    shutil.copyfile(run / "config.yaml", out / "train_config.yaml")
    text = [
        "# The shipped policy (models/quad_il_policy)",
        "",
        f"`policy.ts`: sha256 `{digest}`, {size_mb:.1f} MB, exported by `{run}`. Written by "
        "`python -m quad_il.evaluation.model_card` (do not edit by hand; rerun it).",
        "",
        "`make eval` and `roslaunch quad_il infer.launch` fly this file when no policy is named. Its "
        "training configuration is `train_config.yaml`.",
        "",
        "## Results",
        "",
        *(results_table(rows) if rows else ["(no evaluation given)"]),
        "",
        "Each evaluation directory holds its report.md (commands, pinned hashes, figures); success, "
        "collision and timeout are shares of its episodes with 95 % Wilson intervals.",
        "",
        "## How it was made (oldest run first; each later run starts from the one before's weights)",
        "",
    ]
    text += _origin_section(chain[0])
    for r in chain:
        text += _run_section(r, hash_data)
    (out / "MODEL.md").write_text("\n".join(text))
    return out / "MODEL.md"


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m quad_il.evaluation.model_card", formatter_class=HelpFormatter, description=__doc__
    )
    ap.add_argument("--run", required=True, help="the training run directory whose policy.ts is shipped")
    ap.add_argument("--out", default="models/quad_il_policy", help="the model directory to write")
    ap.add_argument("--eval", action="append", default=[], help="a run_eval output directory; repeat")
    ap.add_argument("--no-hash-data", action="store_true", help="do not hash the datasets' shards (faster)")
    ap.add_argument("--max-mb", type=float, default=25.0, help="largest policy file allowed (MB)")
    a = ap.parse_args(argv)
    try:
        path = write_card(a.run, a.out, a.eval, hash_data=not a.no_hash_data, max_mb=a.max_mb)
    except ModelCardError as e:
        print(f"model_card: error: {e}", file=sys.stderr)
        return 2
    print(f"[model_card] wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
