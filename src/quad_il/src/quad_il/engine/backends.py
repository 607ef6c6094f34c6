"""Where engine episodes are flown: in this process (threads, each with its own worker: the C++ episode runs
without the GIL) or on Ray actors (quad_il.engine.ray_backend). Every backend takes a list of episode specs
and yields (spec, run) as episodes finish, in any order; the caller puts them back in key order.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

from quad_il.collection.episodes import EpisodeSpec
from quad_il.engine import native


@dataclass(frozen=True)
class ConfigPaths:
    """The config files of a run (collect.launch's arguments of the same names)."""

    sim: str
    planner: str
    tracker: str
    vehicle: str


@dataclass(frozen=True)
class Limits:
    """config/collect.yaml's limits of one episode (sim seconds)."""

    takeoff_timeout_s: float
    episode_timeout_s: float


def run_spec(worker, spec: EpisodeSpec, limits: Limits):
    """Flies one keyed episode on an ExpertWorker."""
    return worker.run(
        index=spec.index,
        seed=spec.seed,
        start=spec.start_world,
        start_yaw_rad=spec.start_yaw_rad,
        goal=spec.goal_world,
        takeoff_timeout_s=limits.takeoff_timeout_s,
        episode_timeout_s=limits.episode_timeout_s,
    )


class LocalBackend:
    """`workers` threads in this process, each with its own simulator, tracker and expert; a dynamic queue of
    episodes (a worker takes the next key when it is done)."""

    name = "local"

    def __init__(self, paths: ConfigPaths, workers: int = 1) -> None:
        if workers < 1:
            raise ValueError(f"workers {workers}: must be >= 1")
        self.paths = paths
        self.workers = workers

    def run(self, specs: Sequence[EpisodeSpec], limits: Limits) -> Iterator[tuple[EpisodeSpec, object]]:
        e = native()
        configs = e.load_configs(self.paths.sim, self.paths.planner, self.paths.tracker, self.paths.vehicle)
        todo: queue.Queue = queue.Queue()
        for s in specs:
            todo.put(s)
        done: queue.Queue = queue.Queue()
        stop = threading.Event()

        def work() -> None:
            try:
                worker = e.ExpertWorker(configs)
                while not stop.is_set():
                    try:
                        spec = todo.get_nowait()
                    except queue.Empty:
                        return
                    done.put((spec, run_spec(worker, spec, limits)))
            except BaseException as exc:  # noqa: BLE001 - handed to the caller's thread
                done.put((None, exc))

        threads = [threading.Thread(target=work, daemon=True) for _ in range(min(self.workers, len(specs)))]
        for t in threads:
            t.start()
        try:
            for _ in range(len(specs)):
                spec, run = done.get()
                if spec is None:
                    raise run
                yield spec, run
        finally:
            stop.set()
            for t in threads:
                t.join()
