"""The rollout engine's Ray backend (issue 32, quad_il.engine.ray_backend; docs/engine.md "Several machines
(Ray)"). On a local Ray instance with 2 CPUs (one for the module):
- a Ray collection of 3 short episodes (2 actors) has the records of a local one-worker run of the same keys,
  bit for bit, and leaves the test's Ray instance up with no actor left;
- an episode whose first attempt fails (an exception in the actor; the actor's process exiting) is flown
  again on a fresh actor and the run still equals the local one;
- an episode failing on every attempt stops the run with an error naming it (index, seed, cause), the
  episodes before it stay written, and --resume completes the run to the local one;
- more workers than the cluster's CPUs are refused; a backend that started Ray itself stops it, also after
  a failure; the config bundle an actor writes loads as the original files (relative references kept).

About 60 s in all on this 2-core machine (Ray's start about 10 s, twice; each Ray collection 6-14 s).
"""

from __future__ import annotations

import csv
import os
import subprocess
from pathlib import Path

import pytest

ray = pytest.importorskip(
    "ray",
    reason="the `ray` package is not installed (requirements.txt pins ray==2.40.0: run "
    "`bash scripts/setup.sh`); the Ray backend cannot be tested without it",
)

from quad_il.collection.compare import compare_records, dataset_records  # noqa: E402
from quad_il.collection.episodes import manager_config, plan_episode  # noqa: E402
from quad_il.engine import collect as engine_collect  # noqa: E402
from quad_il.engine import native, ray_backend  # noqa: E402
from quad_il.engine.backends import ConfigPaths, Limits  # noqa: E402
from quad_il.tools import config_overlay  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
# Three short episodes (3 s of sim time after the take-off each) of the privileged expert: the fastest
# keys that still record several plans per episode.
RUN = {
    "seeds": "1,2,3",
    "episodes": 3,
    "planner_config": "config/planner_privileged.yaml",
    "episode_timeout_s": 3.0,
    "progress": False,
}
CPUS = 2


def _paths() -> ConfigPaths:
    """The run's config files as collect() gives them to the backend (the planner overlay merged)."""
    return ConfigPaths(
        str(ROOT / "config" / "sim.yaml"),
        str(config_overlay.resolve(ROOT / RUN["planner_config"])),
        str(ROOT / "config" / "tracker.yaml"),
        str(ROOT / "config" / "vehicle.yaml"),
    )


def _specs_and_limits(indices: list[int]) -> tuple[list, Limits]:
    cfg = manager_config(
        str(ROOT / "config" / "collect.yaml"),
        {"seeds": RUN["seeds"], "episodes": RUN["episodes"], "episode_timeout_s": RUN["episode_timeout_s"]},
    )
    return [plan_episode(cfg, i) for i in indices], Limits(cfg.takeoff_timeout_s, cfg.episode_timeout_s)


def test_a_backend_that_starts_ray_itself_shuts_it_down_also_after_a_failure():
    # Runs before the module's Ray instance exists (file order): the backend starts its own, local one.
    assert not ray.is_initialized(), "run this test before the ones sharing the module's Ray instance"
    specs, limits = _specs_and_limits([0])
    backend = ray_backend.RayBackend(_paths(), workers=1, retries=0, _inject_faults={0: ["raise"]})
    with pytest.raises(ray_backend.EpisodeFailedError, match=r"episode 0 \(world seed 1\) failed on all 1"):
        list(backend.run(specs, limits))
    assert not ray.is_initialized()


@pytest.fixture(scope="module")
def ray_local():
    """One local Ray instance (2 CPUs) for every test here; the backend must not shut it down."""
    assert not ray.is_initialized(), "a Ray instance is already running in this test process"
    ray.init(num_cpus=CPUS, include_dashboard=False, runtime_env=ray_backend.local_runtime_env())
    yield ray
    ray.shutdown()


@pytest.fixture(scope="module")
def local_run(tmp_path_factory) -> Path:
    """The reference: the same keys on the local backend, one worker."""
    out = tmp_path_factory.mktemp("local") / "data"
    r = engine_collect.collect(out, backend="local", workers=1, **RUN)
    assert r.complete and r.episodes == 3 and r.samples > 0
    return out


def _episode_rows(out: Path) -> list[tuple[str, ...]]:
    with open(out / "episodes.csv", newline="") as f:
        return [(r["index"], r["seed"], r["outcome"], r["samples"]) for r in csv.DictReader(f)]


def _assert_same_records(a: Path, b: Path) -> None:
    ra, rb = dataset_records(a), dataset_records(b)
    assert len(ra) > 0
    assert compare_records(ra, rb) == []
    assert _episode_rows(a) == _episode_rows(b)


def _wait_for_free_cpus(timeout_s: float = 60.0) -> None:
    """Until every actor the backend started is gone (their CPUs are back), or fail naming what is left."""
    import time

    deadline = time.monotonic() + timeout_s
    while ray.available_resources().get("CPU", 0.0) < CPUS:
        if time.monotonic() > deadline:
            pytest.fail(f"Ray actors left running after the run: {ray.available_resources()}")
        time.sleep(0.2)


class _Spy(ray_backend.RayBackend):
    """The RayBackend collect() makes, with injected faults, kept for inspection."""

    faults: dict = {}
    made: list = []

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, _inject_faults=self.faults, **kwargs)
        self.made.append(self)


@pytest.fixture
def spy(monkeypatch):
    def make(faults: dict) -> type:
        cls = type("Spy", (_Spy,), {"faults": faults, "made": []})
        # collect() imports RayBackend from this module when it is asked for --backend ray.
        monkeypatch.setattr(ray_backend, "RayBackend", cls)
        return cls

    return make


def test_a_ray_collection_has_the_records_of_a_local_run_of_the_same_keys(ray_local, local_run, tmp_path):
    out = tmp_path / "ray"
    r = engine_collect.collect(out, backend="ray", workers=2, **RUN)
    assert r.complete and r.episodes == 3
    _assert_same_records(out, local_run)
    summary = (out / "collect_summary.yaml").read_text()
    assert "backend: ray" in summary and "workers: 2" in summary
    # The Ray instance was the test's: still up; the backend's actors are gone.
    assert ray.is_initialized()
    _wait_for_free_cpus()


def test_failed_attempts_are_flown_again_on_fresh_actors_and_the_run_equals_the_local_one(
    ray_local, local_run, tmp_path, spy
):
    # Episode 0's first attempt raises in the actor; episode 2's first attempt kills the actor's process.
    cls = spy({0: ["raise"], 2: ["exit"]})
    out = tmp_path / "ray_retry"
    r = engine_collect.collect(out, backend="ray", workers=2, **RUN)
    assert r.complete and r.episodes == 3
    _assert_same_records(out, local_run)
    (backend,) = cls.made
    failures = {index: (attempt, cause) for index, attempt, cause in backend.failures}
    assert sorted(failures) == [0, 2]
    assert failures[0][0] == 1 and "InjectedFault" in failures[0][1]
    assert failures[2][0] == 1 and "died" in failures[2][1]
    _wait_for_free_cpus()


def test_an_episode_failing_every_attempt_stops_the_run_naming_it_and_resume_completes_it(
    ray_local, local_run, tmp_path, spy
):
    cls = spy({1: ["raise", "raise", "raise"]})  # the first attempt and both retries (retries=2)
    out = tmp_path / "ray_fail"
    # One actor: episode 0 is finished before episode 1 is given out, and episode 2 never is.
    with pytest.raises(
        ray_backend.EpisodeFailedError, match=r"episode 1 \(world seed 2\) failed on all 3"
    ) as e:
        engine_collect.collect(out, backend="ray", workers=1, **RUN)
    assert e.value.index == 1 and e.value.attempts == 3
    assert "InjectedFault" in e.value.cause and "episode 1" in e.value.cause
    assert [i for i, _, _ in cls.made[0].failures] == [1, 1, 1]
    _wait_for_free_cpus()
    # What was finished before it in key order is written and readable: episode 0 only.
    assert [row[0] for row in _episode_rows(out)] == ["0"]
    assert len(dataset_records(out)) == int(_episode_rows(out)[0][3])
    # The same command with --resume (no faults now) flies the rest: the run is the local one.
    spy({})
    r = engine_collect.collect(out, backend="ray", workers=2, resume=True, **RUN)
    assert r.complete and r.episodes == 3
    _assert_same_records(out, local_run)


def test_more_workers_than_the_cluster_has_cpus_are_refused_naming_both(ray_local):
    specs, limits = _specs_and_limits([0])
    with pytest.raises(ValueError, match=f"workers 3: the Ray cluster has {CPUS} CPUs"):
        list(ray_backend.RayBackend(_paths(), workers=3).run(specs, limits))
    assert ray.is_initialized()


def test_the_config_bundle_keeps_relative_references_and_overlays_working_elsewhere(tmp_path):
    # The privileged planner config is an overlay: merged into a file under /tmp, far from config/sim.yaml,
    # whose vehicle_file is relative to config/. The actor's copy must load as the originals do.
    planner = config_overlay.resolve(ROOT / "config" / "planner_privileged.yaml")
    paths = ConfigPaths(
        str(ROOT / "config" / "sim.yaml"),
        str(planner),
        str(ROOT / "config" / "tracker.yaml"),
        str(ROOT / "config" / "vehicle.yaml"),
    )
    bundle = ray_backend.ConfigBundle.from_paths(paths)
    assert len(bundle.files) == 4  # the vehicle file sim.yaml names is config/vehicle.yaml itself
    copy = bundle.write(tmp_path / "actor")
    for name in ("sim", "planner", "tracker", "vehicle"):
        original, written = Path(getattr(paths, name)), Path(getattr(copy, name))
        assert written.is_relative_to(tmp_path / "actor")
        assert written.read_bytes() == original.read_bytes()
    native().load_configs(copy.sim, copy.planner, copy.tracker, copy.vehicle)
    # A sim config naming its vehicle file elsewhere: that file travels too, at the same relative place.
    (tmp_path / "cfg" / "sub").mkdir(parents=True)
    sim_text = (ROOT / "config" / "sim.yaml").read_text()
    sim_text = sim_text.replace("vehicle_file: vehicle.yaml", "vehicle_file: ../v.yaml")
    assert "vehicle_file: ../v.yaml" in sim_text
    (tmp_path / "cfg" / "sub" / "sim.yaml").write_text(sim_text)
    (tmp_path / "cfg" / "v.yaml").write_bytes((ROOT / "config" / "vehicle.yaml").read_bytes())
    moved = ray_backend.ConfigBundle.from_paths(
        ConfigPaths(str(tmp_path / "cfg" / "sub" / "sim.yaml"), str(planner), paths.tracker, paths.vehicle)
    )
    assert len(moved.files) == 5
    copy2 = moved.write(tmp_path / "actor2")
    assert (Path(copy2.sim).parent.parent / "v.yaml").is_file()
    native().load_configs(copy2.sim, copy2.planner, copy2.tracker, copy2.vehicle)
    os.remove(Path(copy2.sim).parent.parent / "v.yaml")
    with pytest.raises(Exception, match="v.yaml"):
        native().load_configs(copy2.sim, copy2.planner, copy2.tracker, copy2.vehicle)


def test_an_actor_removes_the_config_directories_of_dead_actors_only(tmp_path, monkeypatch):
    monkeypatch.setattr(ray_backend.tempfile, "tempdir", str(tmp_path))
    ended = subprocess.Popen(["true"])
    ended.wait()  # reaped: no process has its pid any more
    dead = tmp_path / f"{ray_backend.CONFIG_DIR_PREFIX}{ended.pid}_x"
    alive = tmp_path / f"{ray_backend.CONFIG_DIR_PREFIX}{os.getpid()}_y"
    other = tmp_path / "quad_il_ray_configs_notapid_z"
    for d in (dead, alive, other):
        (d / "config").mkdir(parents=True)
    ray_backend._remove_stale_config_dirs()
    assert not dead.exists()
    assert alive.is_dir() and other.is_dir()


def test_bad_backend_arguments_are_refused_naming_them():
    paths = ConfigPaths("s", "p", "t", "v")
    with pytest.raises(ValueError, match="workers 0"):
        ray_backend.RayBackend(paths, workers=0)
    with pytest.raises(ValueError, match="retries -1"):
        ray_backend.RayBackend(paths, retries=-1)
    with pytest.raises(ValueError, match="fault 'segv'"):
        ray_backend.RayBackend(paths, _inject_faults={3: ["segv"]})
