"""The command line of the episode runner (quad_il.evaluation.runner), ROS-free so that its checks and --help
are tested without a ROS master.

    python -m quad_il.evaluation.runner --episodes episodes.json --controller cpp --out cpp.jsonl
        [--episode-timeout-s 60] [--takeoff-timeout-s 20] [--vehicle-box-m 0.25,0.25,0.25]
        [--lockstep-consumer eval_runner --controller-consumer policy] [--no-reset]
"""

from __future__ import annotations

import argparse

from quad_il.tools.cli import HelpFormatter


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="python -m quad_il.evaluation.runner",
        formatter_class=HelpFormatter,
        description="Flies a list of evaluation episodes with the running controller (expert or a policy "
        "node) and appends one JSON line of results per episode.",
    )
    ap.add_argument("--episodes", required=True, help="episodes.json (evaluation.episodes.write_episodes)")
    ap.add_argument(
        "--controller", required=True, choices=["expert", "py", "cpp"], help="the running controller"
    )
    ap.add_argument("--out", required=True, help="results file (JSON lines, appended)")
    ap.add_argument("--episode-timeout-s", type=float, default=60.0, help="sim time per episode")
    ap.add_argument("--takeoff-timeout-s", type=float, default=20.0, help="sim time of the take-off")
    ap.add_argument(
        "--vehicle-box-m", default="0.25,0.25,0.25", help="vehicle box size x,y,z (m) of the clearance"
    )
    ap.add_argument(
        "--lockstep-consumer",
        default="",
        help="FrameAck consumer name of this runner, listed in the simulator's lockstep.depth_consumers: "
        "act at held frames (reproducible flights); '' acts at the newest frame",
    )
    ap.add_argument(
        "--controller-consumer",
        default="",
        help="the controller's FrameAck consumer name (with --lockstep-consumer)",
    )
    ap.add_argument(
        "--no-reset",
        action="store_true",
        help="one episode, the one the simulator runs since its start (its config holds seed, start, goal)",
    )
    return ap


def parse_args(argv: list[str]) -> argparse.Namespace:
    """The parsed options; a combination that cannot work exits 2 with argparse's message."""
    ap = build_parser()
    args = ap.parse_args(argv)
    if args.lockstep_consumer and not args.controller_consumer:
        ap.error("--lockstep-consumer needs --controller-consumer")
    return args
