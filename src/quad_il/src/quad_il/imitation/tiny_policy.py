"""Launch-time helpers of the imitation rostests (tests/rostest/il_*.test): write a small randomly initialised
policy and a round config, print the path (no newline: roslaunch uses the output as a parameter's value).

    python -m quad_il.imitation.tiny_policy policy DIR [--size 32] [--seed 0]
    python -m quad_il.imitation.tiny_policy round-config DIR --algorithm dagger [--beta 0.0] [--round 1]

The policy is the default configuration's network (config/train.yaml's model) at a small input size, exported
with quad_il.inference.random_policy (as training exports): it need not fly well, only produce plans.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from pathlib import Path

import yaml

from quad_il.tools.cli import HelpFormatter
from quad_il.tools.repo import repo_path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(formatter_class=HelpFormatter, prog="quad_il.imitation.tiny_policy")
    sub = ap.add_subparsers(dest="cmd", required=True)
    a = sub.add_parser("policy", formatter_class=HelpFormatter)
    a.add_argument("dir", help="output directory")
    a.add_argument("--size", type=int, default=32, help="input height and width (px)")
    a.add_argument("--seed", type=int, default=0, help="weight initialisation seed")
    b = sub.add_parser("round-config", formatter_class=HelpFormatter)
    b.add_argument("dir", help="output directory")
    b.add_argument("--algorithm", default="dagger", help="algorithm name")
    b.add_argument("--beta", type=float, default=0.0, help="DAgger's constant beta")
    b.add_argument("--round", type=int, default=1, help="round index")
    b.add_argument("--seed", type=int, default=0, help="round seed")
    args = ap.parse_args(argv)
    d = Path(args.dir)
    d.mkdir(parents=True, exist_ok=True)
    if args.cmd == "policy":
        from quad_il.inference.random_policy import export_random_policy
        from quad_il.learning.config import load_config

        cfg = load_config(
            [str(repo_path("config", "train.yaml"))],
            [f"model.input_height={args.size}", f"model.input_width={args.size}"],
        )
        with contextlib.redirect_stdout(sys.stderr):
            out = export_random_policy(
                d / "policy.ts", cfg.model, cfg.data.shards.num_ctrl_pts, cfg.data.shards.horizon_s, args.seed
            )
    else:
        algorithm: dict = {"name": args.algorithm}
        if args.algorithm == "dagger":
            algorithm["beta"] = {"kind": "constant", "beta0": args.beta}
        out = d / "algorithm.yaml"
        out.write_text(
            yaml.safe_dump(
                {"algorithm": algorithm, "round_index": args.round, "seed": args.seed, "beta": args.beta}
            )
        )
    sys.stdout.write(str(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
