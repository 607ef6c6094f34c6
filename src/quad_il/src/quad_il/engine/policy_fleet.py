"""A learned policy flown by several engine workers at once (DAgger rounds, the evaluation's engine backend).

Each worker is a thread with its own `PolicyVec` (its `slots` episodes batched into one forward pass per
round of decisions) and its own LibTorch module; the episodes are dealt round-robin (episode j to worker
j % workers), which keeps the workers' positions in the key order close, so a caller that writes in key
order buffers few finished episodes. The C++ loop runs without the GIL, so two workers use two cores.

An episode's outcome does not depend on the worker or its batch (the forward pass is batch-invariant:
tests/python/test_engine_policy_vec.py), so the results equal a one-worker run's, only their completion order
differs: `on_done(position, result, labels)` gets the episode's position in `specs`, and calls are serialised
(never two at once).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass


class FleetStopped(RuntimeError):
    """Raised inside a worker's callback to end its run after another worker failed or the caller stopped."""


@dataclass
class FleetStats:
    forward_passes: int = 0
    batched_decisions: int = 0

    @property
    def decisions_per_forward_pass(self) -> float:
        return self.batched_decisions / max(self.forward_passes, 1)


def fly_policy(
    e,
    configs,
    policy_path: str,
    policy_cfg,
    specs: Sequence[tuple],
    on_done: Callable[[int, dict, object], None],
    *,
    workers: int,
    slots: int,
    takeoff_timeout_s: float,
    episode_timeout_s: float,
    labeller: bool = False,
    label_stride: int = 1,
) -> FleetStats:
    """Flies `specs` (the binding's (index, seed, start, yaw, goal) tuples) with the exported policy at
    `policy_path`; returns the summed forward-pass counts. The first worker error is raised once every worker
    has stopped (a worker stops at its next finished episode)."""
    if workers < 1:
        raise ValueError(f"workers {workers}: must be >= 1")
    if slots < 1:
        raise ValueError(f"slots {slots}: must be >= 1")
    stats = FleetStats()
    if not specs:
        return stats
    workers = min(workers, len(specs))
    lock = threading.Lock()
    errors: list[BaseException] = []
    stop = threading.Event()

    crews = []  # built here, so a bad policy file or config fails before any episode flies
    for w in range(workers):
        mine = list(range(w, len(specs), workers))
        policy = e.TorchPolicy(policy_path)
        vec = e.PolicyVec(configs, policy_cfg, policy.meta, min(slots, len(mine)), labeller)
        if labeller:
            vec.set_label_stride(label_stride)
        crews.append((mine, policy, vec))

    def work(w: int) -> None:
        mine, policy, vec = crews[w]

        def done(k: int, result: dict, labels) -> None:
            with lock:
                if stop.is_set():
                    raise FleetStopped("stopped")
                on_done(mine[k], result, labels)

        try:
            vec.run_torch(policy, [specs[j] for j in mine], takeoff_timeout_s, episode_timeout_s, done)
        except BaseException as exc:  # noqa: BLE001 - handed to the caller's thread
            with lock:
                if not isinstance(exc, FleetStopped):
                    errors.append(exc)
                stop.set()

    if workers == 1:
        work(0)
    else:
        threads = [threading.Thread(target=work, args=(w,), daemon=True) for w in range(workers)]
        for t in threads:
            t.start()
        try:
            for t in threads:
                t.join()
        except BaseException:  # Ctrl-C: the workers end at their next finished episode
            stop.set()
            for t in threads:
                t.join()
            raise
    if errors:
        raise errors[0]
    for _, _, vec in crews:
        stats.forward_passes += vec.forward_passes
        stats.batched_decisions += vec.batched_decisions
    return stats
