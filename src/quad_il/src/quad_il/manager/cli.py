"""Command line of imitation_learning_manager.py: `imitation_learning_manager.py CONFIG.yaml [options]`.

Exit codes: 0 run complete; 1 a stage failed (see run_dir/state.json and the round's logs); 2 bad
configuration or the run cannot proceed (lock held, config changed, missing policy); 128 + N stopped by signal
N (130 for SIGINT, 143 for SIGTERM), the interrupted stage resumes on the next invocation.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence
from pathlib import Path

from quad_il.manager.config import ConfigError, load_config
from quad_il.manager.runner import ManagerError, PipelineRunner
from quad_il.manager.state import StateError
from quad_il.tools.cli import HelpFormatter


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        formatter_class=HelpFormatter,
        prog="imitation_learning_manager.py",
        description="Run the interactive imitation-learning pipeline (rounds of collect, train, eval) from "
        "one YAML file; resumes an interrupted run from its last completed round.",
    )
    p.add_argument("config", type=Path, help="manager YAML (see config/il_manager.yaml)")
    p.add_argument(
        "--allow-config-change",
        action="store_true",
        help="resume even though the config differs from the one the run started with (the old one is kept)",
    )
    p.add_argument(
        "--redo-from",
        type=int,
        metavar="ROUND",
        help="discard rounds ROUND, ROUND+1, ... of an existing run (their directories are moved aside as "
        "round_NNN.discarded-<time>, never deleted) and run them again; the rounds before are kept",
    )
    p.add_argument("--check", action="store_true", help="validate the config and exit")
    p.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="[il_manager] %(asctime)s %(levelname)s %(message)s",
        stream=sys.stderr,
    )
    try:
        cfg, text = load_config(args.config)
    except ConfigError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if args.check:
        print(
            f"{args.config}: ok ({cfg.algorithm.name}, {cfg.rounds.count} rounds, run_dir {cfg.run.run_dir})"
        )
        return 0
    try:
        return PipelineRunner(cfg, text, args.config, args.allow_config_change, args.redo_from).run()
    except (ManagerError, StateError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
