"""Engine workers as Ray actors (issue 32, docs/engine.md "Several machines (Ray)"): the backend of
`python -m quad_il.engine.collect --backend ray`, on this machine or on a Ray cluster.

The interface is LocalBackend's (quad_il.engine.backends): `run(specs, limits)` yields (spec, run) as
episodes finish, in any order, and the driver writes them in key order, so the dataset is the local run's.
What travels:

- to each actor, once: the CONTENTS of the run's config files (ConfigBundle), which the actor writes to a
  temporary directory of its own machine before building its ExpertWorker. A resolved overlay
  (config/planner_privileged.yaml is merged into a file under the driver's /tmp) and a checkout at another
  path therefore need nothing on the other machines but this repository built at the same commit;
- per episode: its key (EpisodeSpec, a few numbers) and the limits; back: the flown quad_engine_py.EpisodeRun,
  pickled as the bytes of its records bit for bit.

Scheduling is a dynamic queue: an actor is given the next key as soon as it returns one, so fast and slow
episodes (and fast and slow machines) balance themselves. A failed episode (an exception in the actor, or the
actor's process dying: ray.exceptions.RayActorError) is flown again on a fresh actor, up to `retries` times,
then EpisodeFailedError names the episode (index, seed) and the last cause.
"""

from __future__ import annotations

import logging
import os
import re
import shutil
import socket
import tempfile
import time
from collections import deque
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import yaml

import quad_il
from quad_il.collection.episodes import EpisodeSpec
from quad_il.engine import collect, native
from quad_il.engine.backends import ConfigPaths, Limits, run_spec

_ANSI = re.compile(r"\x1b\[[0-9;]*m")
# Test hooks (RayBackend(_inject_faults=...)): what an actor does instead of flying the episode.
FAULTS = ("raise", "exit")


class EpisodeFailedError(RuntimeError):
    """An episode failed on every attempt (the first and its retries): names the episode and the last
    cause."""

    def __init__(self, spec: EpisodeSpec, attempts: int, cause: str) -> None:
        super().__init__(
            f"episode {spec.index} (world seed {spec.seed}) failed on all {attempts} attempt(s) on Ray "
            f"actors; last cause: {cause}"
        )
        self.index = spec.index
        self.seed = spec.seed
        self.attempts = attempts
        self.cause = cause


class InjectedFault(RuntimeError):
    """Raised by an actor told to fail (a test hook, RayBackend(_inject_faults=...))."""


def _ray():
    try:
        import ray
    except ImportError as exc:
        raise ImportError(
            f"the Ray backend needs the `ray` package ({exc}): it is pinned in requirements.txt; "
            "run `bash scripts/setup.sh` (or `make build`)"
        ) from None
    return ray


@dataclass(frozen=True)
class ConfigBundle:
    """The config files a worker reads, as contents: `files` maps a path relative to a bundle directory to
    the file's bytes; sim/planner/tracker/vehicle are the four configs' paths in it. The files keep their
    relative layout (paths relative to their common ancestor directory), so a relative reference inside a
    config (config/sim.yaml's `vehicle_file`, `world.file`) finds its file in the bundle too. An absolute
    reference inside a config is left as it is: that file must exist at that path on every machine."""

    files: Mapping[str, bytes]
    sim: str
    planner: str
    tracker: str
    vehicle: str

    @classmethod
    def from_paths(cls, paths: ConfigPaths) -> ConfigBundle:
        main = {k: os.path.abspath(getattr(paths, k)) for k in ("sim", "planner", "tracker", "vehicle")}
        needed = list(main.values()) + _sim_references(main["sim"])
        root = os.path.commonpath([os.path.dirname(p) for p in needed])
        files: dict[str, bytes] = {}
        for p in needed:
            try:
                files[os.path.relpath(p, root)] = Path(p).read_bytes()
            except OSError as exc:
                raise ValueError(
                    f"config file {p} cannot be read for the Ray actors ({exc.strerror})"
                ) from None
        rel = {k: os.path.relpath(v, root) for k, v in main.items()}
        return cls(files, rel["sim"], rel["planner"], rel["tracker"], rel["vehicle"])

    def write(self, directory: str | os.PathLike[str]) -> ConfigPaths:
        """Writes the files under `directory`; returns the four configs' paths there."""
        d = Path(directory)
        for rel, data in self.files.items():
            p = d / rel
            p.parent.mkdir(parents=True, exist_ok=True)
            p.write_bytes(data)
        return ConfigPaths(*(str(d / rel) for rel in (self.sim, self.planner, self.tracker, self.vehicle)))


def _sim_references(sim_path: str) -> list[str]:
    """The files config/sim.yaml names relative to its own directory (as quad_sim's loader resolves them)."""
    try:
        tree = yaml.safe_load(Path(sim_path).read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise ValueError(f"sim config {sim_path} cannot be read: {exc}") from None
    if not isinstance(tree, dict):
        raise ValueError(f"sim config {sim_path}: not a YAML mapping")
    world = tree.get("world")
    refs = [tree.get("vehicle_file"), world.get("file") if isinstance(world, dict) else None]
    out = []
    for ref in refs:
        if isinstance(ref, str) and ref and not os.path.isabs(ref):
            out.append(os.path.normpath(os.path.join(os.path.dirname(sim_path), ref)))
    return out


CONFIG_DIR_PREFIX = "quad_il_ray_configs_"


def _remove_stale_config_dirs() -> None:
    """Removes the config directories of actors whose process is gone (one that died cannot remove its own):
    TMPDIR/quad_il_ray_configs_<pid>_* with no process <pid> on this machine."""
    for d in Path(tempfile.gettempdir()).glob(f"{CONFIG_DIR_PREFIX}*_*"):
        pid = d.name[len(CONFIG_DIR_PREFIX) :].split("_", 1)[0]
        if not pid.isdigit():
            continue
        try:
            os.kill(int(pid), 0)
        except ProcessLookupError:
            shutil.rmtree(d, ignore_errors=True)
        except OSError:
            pass  # alive (another user's process): not ours to touch


class EngineActor:
    """One engine worker in a Ray actor's process (RayBackend makes it a Ray actor with num_cpus=1): the
    bundle's files written to a temporary directory of the actor's machine, and one ExpertWorker."""

    def __init__(self, bundle: ConfigBundle) -> None:
        _remove_stale_config_dirs()
        # Kept while the actor lives: the simulator reads config/sim.yaml's world.file at a reset.
        self._dir = tempfile.mkdtemp(prefix=f"{CONFIG_DIR_PREFIX}{os.getpid()}_")
        try:
            paths = bundle.write(self._dir)
            e = native()
            configs = e.load_configs(paths.sim, paths.planner, paths.tracker, paths.vehicle)
            self._worker = e.ExpertWorker(configs)
        except BaseException:
            self.close()
            raise
        self._where = f"{socket.gethostname()} pid {os.getpid()}"

    def run(self, spec: EpisodeSpec, limits: Limits, fault: str | None = None):
        try:
            if fault == "raise":
                raise InjectedFault(f"injected failure before flying episode {spec.index} ({self._where})")
            if fault == "exit":
                os._exit(3)  # the process dies at once, as a crash would: the driver sees RayActorError
            return run_spec(self._worker, spec, limits)
        except BaseException:
            # The backend replaces an actor whose episode failed: leave nothing behind.
            self.close()
            raise

    def close(self) -> None:
        shutil.rmtree(self._dir, ignore_errors=True)


def local_runtime_env() -> dict:
    """The runtime environment of a local Ray instance's workers: the driver's own quad_il and
    quad_engine_py first on PYTHONPATH, so an actor imports exactly what the driver imports (on a cluster,
    each node's `ray start` runs in that machine's `source scripts/env.sh` instead)."""
    dirs = [str(Path(quad_il.__file__).resolve().parents[1]), str(Path(native().__file__).resolve().parent)]
    if os.environ.get("PYTHONPATH"):
        dirs.append(os.environ["PYTHONPATH"])
    return {"env_vars": {"PYTHONPATH": os.pathsep.join(dirs)}}


def init_local(num_cpus: int) -> None:
    """Starts a local Ray instance for `num_cpus` actors (no dashboard, warnings only)."""
    _ray().init(
        num_cpus=num_cpus,
        include_dashboard=False,
        logging_level=logging.WARNING,
        runtime_env=local_runtime_env(),
    )


def _cause(exc: BaseException) -> str:
    """A short text of why a Ray task failed: the actor's exception, or why the actor died."""
    ray = _ray()
    if isinstance(exc, ray.exceptions.RayTaskError) and exc.cause is not None:
        inner = exc.cause
        text = f"{type(inner).__name__}: {inner}"
    elif isinstance(exc, ray.exceptions.RayActorError):
        text = f"the actor's process died ({type(exc).__name__}: {exc})"
    else:
        text = f"{type(exc).__name__}: {exc}"
    # Ray's texts carry colour codes, tracebacks and caret lines: keep the first line, where the actor ran,
    # and the last line (a traceback's exception).
    lines = [ln.strip() for ln in _ANSI.sub("", text).splitlines() if ln.strip().strip("^~ ")]
    keep = [ln for i, ln in enumerate(lines) if i in (0, len(lines) - 1) or ln.startswith(("pid:", "ip:"))]
    return "; ".join(keep)


class RayBackend:
    """`workers` Ray actors (num_cpus=1 each), each with one ExpertWorker, fed from a dynamic queue of episode
    keys; a failed episode is retried up to `retries` times, each time on a fresh actor.

    address None: a local Ray instance with num_cpus = workers (or the instance this process already
    initialised, e.g. a test's `ray.init(num_cpus=2)`); else `ray.init(address=address)` ("auto", or
    HEAD:6379 of `ray start --head`). Whatever run() starts (actors, the Ray connection) it stops.

    _inject_faults (tests only): episode index -> faults of its successive attempts, each "raise" (the actor
    raises before flying) or "exit" (the actor's process exits), e.g. {1: ["exit"]} fails episode 1's first
    attempt only."""

    name = "ray"

    def __init__(
        self,
        paths: ConfigPaths,
        workers: int = 1,
        address: str | None = None,
        retries: int = 2,
        *,
        _inject_faults: Mapping[int, Sequence[str]] | None = None,
    ) -> None:
        if workers < 1:
            raise ValueError(f"workers {workers}: must be >= 1")
        if retries < 0:
            raise ValueError(f"retries {retries}: must be >= 0")
        faults = {int(k): tuple(v) for k, v in (_inject_faults or {}).items()}
        for index, kinds in faults.items():
            for kind in kinds:
                if kind is not None and kind not in FAULTS:
                    raise ValueError(
                        f"_inject_faults[{index}]: fault '{kind}' is not one of {', '.join(FAULTS)}"
                    )
        self.paths = paths
        self.workers = workers
        self.address = address
        self.retries = retries
        self._faults = faults
        # (index, attempt, cause) of every failed attempt of the last run(), retried or not.
        self.failures: list[tuple[int, int, str]] = []

    def _fault(self, spec: EpisodeSpec, attempt: int) -> str | None:
        kinds = self._faults.get(spec.index, ())
        return kinds[attempt] if attempt < len(kinds) else None

    def run(self, specs: Sequence[EpisodeSpec], limits: Limits) -> Iterator[tuple[EpisodeSpec, object]]:
        specs = list(specs)
        self.failures = []
        if not specs:
            return
        ray = _ray()
        # The configs are checked here first, so a bad file is reported as in a local run, not as actors
        # dying in their constructors.
        native().load_configs(self.paths.sim, self.paths.planner, self.paths.tracker, self.paths.vehicle)
        bundle = ConfigBundle.from_paths(self.paths)
        started = False
        if not ray.is_initialized():
            if self.address is None:
                init_local(self.workers)
            else:
                ray.init(address=self.address, logging_level=logging.WARNING)
            started = True
        actor_cls = ray.remote(num_cpus=1, max_restarts=0, max_task_retries=0)(EngineActor)
        bundle_ref = ray.put(bundle)  # one copy in the object store, whatever the number of actors
        live: list = []

        def fresh_actor():
            a = actor_cls.remote(bundle_ref)
            live.append(a)
            return a

        def discard(actor) -> None:
            live.remove(actor)
            ray.kill(actor, no_restart=True)

        todo = deque(specs)
        attempts = {s.index: 0 for s in specs}
        inflight: dict = {}  # ObjectRef -> (actor, spec)

        def submit(actor, spec: EpisodeSpec) -> None:
            ref = actor.run.remote(spec, limits, self._fault(spec, attempts[spec.index]))
            inflight[ref] = (actor, spec)

        try:
            cpus = ray.cluster_resources().get("CPU", 0.0)
            if self.workers > cpus:
                # An actor that can never be placed would hold its episode forever: refuse at once.
                raise ValueError(
                    f"workers {self.workers}: the Ray cluster has {cpus:g} CPUs (each actor takes 1); "
                    "use fewer workers or add machines (ray start --address=HEAD:6379)"
                )
            for _ in range(min(self.workers, len(todo))):
                submit(fresh_actor(), todo.popleft())
            while inflight:
                ready, _ = ray.wait(list(inflight), num_returns=1)
                actor, spec = inflight.pop(ready[0])
                try:
                    run = ray.get(ready[0])
                except ray.exceptions.RayError as exc:
                    attempts[spec.index] += 1
                    cause = _cause(exc)
                    self.failures.append((spec.index, attempts[spec.index], cause))
                    discard(actor)
                    if attempts[spec.index] > self.retries:
                        raise EpisodeFailedError(spec, attempts[spec.index], cause) from None
                    logging.getLogger(__name__).warning(
                        "episode %d (world seed %d) failed on attempt %d (%s); flying it again on a "
                        "fresh actor",
                        spec.index,
                        spec.seed,
                        attempts[spec.index],
                        cause,
                    )
                    submit(fresh_actor(), spec)
                    continue
                if (run.index, run.seed) != (spec.index, spec.seed):
                    raise RuntimeError(
                        f"a Ray actor returned episode ({run.index}, seed {run.seed}) for the key "
                        f"({spec.index}, seed {spec.seed})"
                    )
                # The actor takes the next key before the driver writes this episode.
                if todo:
                    submit(actor, todo.popleft())
                yield spec, run
        finally:
            self._stop(ray, live, busy=[a for a, _ in inflight.values()])
            if started:
                ray.shutdown()

    @staticmethod
    def _stop(ray, actors: list, busy: list) -> None:
        """Lets each idle actor remove its config directory, then ends every actor (a busy one at once: an
        early stop, an error or Ctrl-C in the driver does not wait for episodes nobody will write)."""
        refs = [a.close.remote() for a in actors if a not in busy]
        if refs:
            ray.wait(refs, num_returns=len(refs), timeout=10.0)
        for a in actors:
            ray.kill(a, no_restart=True)


def bench_records_per_s(actors: int, episodes: int, seeds: str, planner_config: str) -> float:
    """Records per wall second of `python -m quad_il.engine.collect --backend ray --workers ACTORS` over
    `episodes` episodes of `seeds` with `planner_config`, into a temporary directory (removed after). The
    local Ray instance (num_cpus = actors) is started before the clock starts: the time counts the actors'
    start-up, flying and writing, not Ray's own start."""
    ray = _ray()
    started = False
    if not ray.is_initialized():
        init_local(actors)
        started = True
    try:
        with tempfile.TemporaryDirectory(prefix="quad_il_ray_bench_") as d:
            t0 = time.monotonic()
            r = collect.collect(
                Path(d) / "data",
                seeds,
                episodes,
                workers=actors,
                backend="ray",
                planner_config=planner_config,
                progress=False,
            )
            wall_s = time.monotonic() - t0
    finally:
        if started:
            ray.shutdown()
    if not r.complete:
        raise RuntimeError(f"the Ray bench run did not complete ({r.episodes} of {episodes} episodes)")
    return r.samples / wall_s
