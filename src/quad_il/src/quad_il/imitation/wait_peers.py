"""Launch prefix that starts a command once enough peers are registered with the ROS master.

    python -P src/quad_il/src/quad_il/imitation/wait_peers.py --publishers sim/frame_ack=4 \
        --subscribers camera/depth/image=3 [--timeout-s 120] -- COMMAND ARGS...

Relative topic names resolve in the namespace of the command (ROS_NAMESPACE, which roslaunch sets for a node
in a namespace and hands to its launch-prefix), as the command's own relative names do.

il_sim.launch starts the lockstep simulator through it: quad_sim waits for *one* depth consumer before its
first frame, so with several consumers (labeller, policy, collector, episode manager) a late one would miss
the first frame and the simulator would wait for its acknowledgement until the lockstep timeout. Waiting for
every consumer's registration (their acknowledgement publishers and depth subscriptions) before the simulator
even starts leaves them the simulator's start-up to connect. Run as a script (not `-m`: it needs only
rosgraph, not the package's dependencies) with `-P` (this directory's types.py must not shadow the standard
library's). On timeout the command starts anyway (with a warning): the lockstep timeout still bounds the
damage.
"""

from __future__ import annotations

import argparse
import os
import sys
import time


def resolve_topic(topic: str, namespace: str) -> str:
    """A global name unchanged; a relative one joined to `namespace` ('/' or '/a/b')."""
    if topic.startswith("/"):
        return topic
    return namespace.rstrip("/") + "/" + topic


def parse_counts(items: list[str], flag: str, namespace: str = "/") -> dict[str, int]:
    out: dict[str, int] = {}
    for item in items:
        topic, sep, n = item.partition("=")
        if not sep or not topic.strip("/") or topic.startswith("~"):
            raise ValueError(f"{flag} {item!r}: expected topic=COUNT (a global or relative topic name)")
        try:
            out[resolve_topic(topic, namespace)] = int(n)
        except ValueError:
            raise ValueError(f"{flag} {item!r}: COUNT must be an integer") from None
    return out


def missing_peers(
    state: list[list[tuple[str, list[str]]]], publishers: dict[str, int], subscribers: dict[str, int]
) -> list[str]:
    """What is still missing in a master's getSystemState() answer (publishers, subscribers, services)."""
    pubs = {t: len(nodes) for t, nodes in state[0]}
    subs = {t: len(nodes) for t, nodes in state[1]}
    out = [f"{n - pubs.get(t, 0)} publisher(s) of {t}" for t, n in publishers.items() if pubs.get(t, 0) < n]
    out += [
        f"{n - subs.get(t, 0)} subscriber(s) of {t}" for t, n in subscribers.items() if subs.get(t, 0) < n
    ]
    return out


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if "--" not in argv and not {"-h", "--help"} & set(argv):
        print("wait_peers: usage: ... -- COMMAND [ARGS...]", file=sys.stderr)
        return 2
    i = argv.index("--") if "--" in argv else len(argv)  # no `--`: only --help gets here
    ap = argparse.ArgumentParser(
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
        prog="quad_il.imitation.wait_peers",
        description=__doc__.splitlines()[0],
    )
    ap.add_argument("--publishers", action="append", default=[], help="TOPIC=N: wait for N publishers")
    ap.add_argument("--subscribers", action="append", default=[], help="TOPIC=N: wait for N subscribers")
    ap.add_argument("--timeout-s", type=float, default=120.0, help="wall time before starting anyway")
    args = ap.parse_args(argv[:i])
    command = argv[i + 1 :]
    if not command:
        print("wait_peers: no command after --", file=sys.stderr)
        return 2
    namespace = os.environ.get("ROS_NAMESPACE", "") or "/"
    if not namespace.startswith("/"):
        namespace = "/" + namespace
    try:
        pubs = parse_counts(args.publishers, "--publishers", namespace)
        subs = parse_counts(args.subscribers, "--subscribers", namespace)
    except ValueError as e:
        print(f"wait_peers: {e}", file=sys.stderr)
        return 2
    import rosgraph

    master = rosgraph.Master("/quad_il_wait_peers")
    deadline = time.monotonic() + args.timeout_s
    missing = ["the master"]
    while time.monotonic() < deadline:
        try:
            missing = missing_peers(master.getSystemState(), pubs, subs)
        except OSError:
            missing = ["the master"]
        if not missing:
            break
        time.sleep(0.1)
    else:
        print(f"wait_peers: starting anyway after {args.timeout_s:g} s; missing {missing}", file=sys.stderr)
    os.execvp(command[0], command)
    return 0  # not reached


if __name__ == "__main__":
    sys.exit(main())
