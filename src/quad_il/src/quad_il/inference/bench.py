"""Python side of `make bench-inference` (scripts/bench/inference.sh): decision latency of the Python pipeline
(preprocessing + forward in torch, the bound C++ decoding, the quad_msgs/Bspline) on the frames of a
DecisionFixture, the same frames the C++ side times. Prints `BENCH infer_py_ms_median` and
`BENCH infer_py_ms_p99`; details on stderr.

    python -m quad_il.inference.bench --policy P --fixture DIR --config config/policy.yaml [--threads 1]
        [--repeat 1] [--name infer_py]
"""

from __future__ import annotations

import argparse
import math
import sys
import time

import numpy as np

from quad_il.inference.config import load_policy_config
from quad_il.inference.core import PolicyDecider
from quad_il.inference.fixture import read_fixture
from quad_il.inference.messages import bspline_message
from quad_il.inference.policy import LoadedPolicy, configure_threads


def percentile(values: list[float], q: float) -> float:
    """Nearest rank, as the C++ benchmark."""
    v = sorted(values)
    return v[min(max(math.ceil(q * len(v)) - 1, 0), len(v) - 1)]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--policy", required=True)
    ap.add_argument("--fixture", required=True)
    ap.add_argument("--config", required=True)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--name", default="infer_py")
    args = ap.parse_args(argv)
    cfg = load_policy_config(args.config)
    configure_threads(args.threads)
    policy = LoadedPolicy(args.policy)
    # As the C++ benchmark (quad_bench's policy_bench): the safety layer and refusal, no recovery or keeping.
    decider = PolicyDecider(policy.meta, cfg.safety, cfg.refusal)
    fx = read_fixture(args.fixture)
    decision, pre, fwd, safety = [], [], [], []
    traj_id = 0
    for r in range(-1, args.repeat):  # r = -1: warm-up pass, not recorded
        for i in range(len(fx)):
            p, v, q, g = fx.p_world_body[i], fx.v_world[i], fx.q_world_body[i], fx.goal_world[i]
            d, pre_ms, fwd_ms = policy.decide(
                decider, float(fx.stamp_s[i]), fx.depth_m[i], fx.camera(i), p, v, q, g
            )
            t0 = time.perf_counter()
            traj_id += 1
            msg = bspline_message(d.proposed, traj_id)
            message_ms = 1e3 * (time.perf_counter() - t0) + d.timings.decode_ms
            if not msg.pos_pts:
                raise RuntimeError("empty message")
            if r < 0:
                continue
            pre.append(pre_ms)
            fwd.append(fwd_ms)
            decision.append(pre_ms + fwd_ms + message_ms)
            safety.append(d.timings.safety_ms)
    print(
        f"[bench inference] {args.name}: {len(decision)} decisions, {args.threads} thread(s): preprocessing "
        f"median {np.median(pre):.3f} ms, forward median {np.median(fwd):.3f} ms, safety layer median "
        f"{np.median(safety):.3f} ms p99 {percentile(safety, 0.99):.3f} ms; verdicts: "
        f"{decider.accepted_count} accepted, {decider.refused_count} refused",
        file=sys.stderr,
    )
    print(f"BENCH {args.name}_ms_median {percentile(decision, 0.5):.3f} ms")
    print(f"BENCH {args.name}_ms_p99 {percentile(decision, 0.99):.3f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
