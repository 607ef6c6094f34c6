"""The manager's round loop: collect (services + collector), train, evaluate; resumable, signal-safe.

Round r (0-based): the learner flies the policy trained in round r-1 (round 0: `rounds.initial_policy`, or no
policy at all, in which case the expert flies and the round collects a BC dataset whatever the algorithm); the
collector writes round_r/data; training reads the data of rounds 0..r ({data_dirs}) and writes
round_r/checkpoint with the policy round r+1 flies; evaluation (optional) writes round_r/metrics.

Signals: the first SIGINT/SIGTERM/SIGHUP stops the running children gracefully (SIGINT, then SIGTERM, then
SIGKILL after the configured timeouts, collector first so it finalises its data), marks the stage interrupted
and exits with 128 + signal; a second signal cuts the graceful waits short. A later invocation with the same
config resumes at the first incomplete round, skipping the stages of it already complete and moving the
outputs of the interrupted stage aside (round_XXX/attempts/).
"""

from __future__ import annotations

import dataclasses
import fcntl
import logging
import os
import signal
import socket
import sys
import time
from pathlib import Path
from types import FrameType
from typing import Any

import yaml

from quad_il.imitation.config import DAggerConfig, RoundAlgorithmConfig
from quad_il.manager.config import ManagerConfig, ServiceSection, config_digest
from quad_il.manager.state import RoundPaths, RunLayout, RunState, Status, write_json_atomic
from quad_il.manager.supervisor import (
    Child,
    ChildSpec,
    ChildStartError,
    Supervisor,
    become_subreaper,
    reap_zombies,
    sweep_descendants,
)
from quad_il.tools.ports import free_port

log = logging.getLogger("quad_il.manager")

SERVICE_ORDER = ("simulator", "tracker", "expert", "learner")


class ManagerError(RuntimeError):
    """The run cannot proceed (lock held, config changed, missing policy...); the message says why."""


@dataclasses.dataclass(frozen=True)
class StageResult:
    status: Status
    exit_code: int | None = None
    reason: str = ""


class StopRequest:
    """Signal handler state: the first signal asks for a graceful stop, further ones make it urgent."""

    def __init__(self) -> None:
        self.signum: int | None = None
        self.count = 0

    def __call__(self, signum: int, frame: FrameType | None) -> None:
        del frame
        if self.signum is None:
            self.signum = signum
        self.count += 1
        name = signal.Signals(signum).name
        if self.count == 1:
            log.warning("%s received: stopping children gracefully (again to hurry)", name)
        else:
            log.warning("%s received again: killing children without waiting", name)

    @property
    def requested(self) -> bool:
        return self.signum is not None

    @property
    def urgent(self) -> bool:
        return self.count >= 2

    def exit_code(self) -> int:
        return 128 + int(self.signum or 0)


def port_accepts(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.settimeout(0.2)
        return s.connect_ex(("127.0.0.1", port)) == 0


class PipelineRunner:
    def __init__(
        self,
        cfg: ManagerConfig,
        config_text: str,
        config_path: Path,
        allow_config_change: bool = False,
        redo_from: int | None = None,
    ) -> None:
        if redo_from is not None and not 0 <= redo_from < cfg.rounds.count:
            raise ManagerError(
                f"--redo-from {redo_from}: the config has rounds 0..{cfg.rounds.count - 1} (rounds.count "
                f"{cfg.rounds.count})"
            )
        self.cfg = cfg
        self.redo_from = redo_from
        self.config_text = config_text
        self.config_dir = config_path.resolve().parent
        self.allow_config_change = allow_config_change
        run_dir = Path(cfg.run.run_dir).expanduser()
        # Relative paths (run_dir, initial_policy, commands' cwd) resolve against the config file's directory.
        self.layout = RunLayout((run_dir if run_dir.is_absolute() else self.config_dir / run_dir).resolve())
        self.stop = StopRequest()
        self.sup = Supervisor(
            cfg.signals.sigint_timeout_s,
            cfg.signals.sigterm_timeout_s,
            cfg.signals.poll_interval_s,
            urgent=lambda: self.stop.urgent,
        )
        self.state: RunState | None = None
        self._lock_fd: int | None = None

    # ---- top level ----
    def run(self) -> int:
        self.layout.run_dir.mkdir(parents=True, exist_ok=True)
        self._acquire_lock()
        file_handler = logging.FileHandler(self.layout.log)
        file_handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(message)s"))
        logging.getLogger("quad_il.manager").addHandler(file_handler)
        previous = {s: signal.signal(s, self.stop) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
        become_subreaper()
        try:
            self.state = self._load_or_create_state()
            return self._run_rounds()
        finally:
            self.sup.stop_all(graceful=not self.stop.urgent)
            leftovers = sweep_descendants(self.cfg.signals.sigterm_timeout_s)
            if leftovers:
                log.warning("killed %d leftover descendant(s) at exit: %s", len(leftovers), leftovers)
            for s, h in previous.items():
                signal.signal(s, h)
            logging.getLogger("quad_il.manager").removeHandler(file_handler)
            file_handler.close()
            self._release_lock()

    def _run_rounds(self) -> int:
        state = self._state()
        start = state.first_incomplete_round(self.cfg.rounds.count)
        if start is None:
            log.info("all %d rounds are complete in %s", self.cfg.rounds.count, self.layout.run_dir)
            state.finished = True
            state.save(self.layout.state)
            return 0
        if start > 0 or state.rounds:
            log.info("resuming %s at round %d", self.layout.run_dir, start)
        for r in range(start, self.cfg.rounds.count):
            if state.round_complete(r):
                continue
            result = self._run_round(r)
            if result.status is not Status.COMPLETE:
                if result.status is Status.INTERRUPTED:
                    return self.stop.exit_code()
                return 1
        state.finished = True
        state.save(self.layout.state)
        log.info("run complete: %d rounds in %s", self.cfg.rounds.count, self.layout.run_dir)
        return 0

    # ---- one round ----
    def _run_round(self, r: int) -> StageResult:
        state = self._state()
        paths = self.layout.round(r)
        paths.create()
        policy = self._policy_for_round(r)
        self._write_round_algorithm(paths, r, policy)
        stages = ["collect", "train"] + (["eval"] if self.cfg.eval.enabled else [])
        for stage in stages:
            st = state.stage(r, stage)
            if st.status is Status.COMPLETE:
                continue
            if self.stop.requested:
                state.last_event = {
                    "round": r,
                    "stage": stage,
                    "status": "interrupted",
                    "reason": "not started",
                }
                state.save(self.layout.state)
                return StageResult(Status.INTERRUPTED, None, "stop requested before the stage started")
            if st.attempts > 0:
                moved = paths.archive_stage_output(stage, st.attempts)
                if moved is not None:
                    log.info("round %d: previous %s attempt's output moved to %s", r, stage, moved)
            state.begin_stage(r, stage)
            state.save(self.layout.state)
            log.info("round %d: %s (attempt %d)", r, stage, state.stage(r, stage).attempts)
            result = self._run_stage(stage, r, paths, policy)
            state.end_stage(r, stage, result.status, result.exit_code, result.reason)
            state.save(self.layout.state)
            self._write_round_summary(paths, r)
            if result.status is not Status.COMPLETE:
                log.error("round %d: %s %s: %s", r, stage, result.status.value, result.reason)
                return result
        state.complete_round(r)
        state.save(self.layout.state)
        self._write_round_summary(paths, r)
        log.info("round %d complete", r)
        return StageResult(Status.COMPLETE)

    def _policy_for_round(self, r: int) -> Path | None:
        if r == 0:
            p = self.cfg.rounds.initial_policy
            if p is None:
                return None
            path = (self.config_dir / p).resolve() if not Path(p).is_absolute() else Path(p)
            if not path.exists():
                raise ManagerError(f"rounds.initial_policy {path} does not exist")
            return path
        prev = self.layout.round(r - 1).checkpoint / self.cfg.training.policy_file
        if not prev.exists():
            raise ManagerError(
                f"round {r} needs the policy trained in round {r - 1}, but {prev} does not exist "
                f"(training.policy_file = {self.cfg.training.policy_file!r})"
            )
        return prev

    def _write_round_algorithm(self, paths: RoundPaths, r: int, policy: Path | None) -> None:
        algo = self.cfg.algorithm
        beta = None
        if isinstance(algo, DAggerConfig):
            beta = 1.0 if policy is None else algo.beta.schedule().beta(r)
        cfg = RoundAlgorithmConfig(
            algorithm=algo, round_index=r, seed=self.cfg.run.seed + r, beta=beta, expert_only=policy is None
        )
        paths.algorithm_config.write_text(yaml.safe_dump(cfg.model_dump(mode="json"), sort_keys=False))

    def _write_round_summary(self, paths: RoundPaths, r: int) -> None:
        state = self._state()
        stages = {k: v.to_json() for k, v in state.rounds.get(r, {}).items()}
        write_json_atomic(paths.summary, {"round": r, "complete": state.round_complete(r), "stages": stages})

    # ---- stages ----
    def _context(self, r: int, paths: RoundPaths, policy: Path | None, port: int) -> dict[str, str]:
        data_dirs = ",".join(str(self.layout.round(i).data) for i in range(r + 1))
        return {
            "run_dir": str(self.layout.run_dir),
            "round": str(r),
            "round_name": paths.name,
            "round_dir": str(paths.root),
            "data_dir": str(paths.data),
            "checkpoint_dir": str(paths.checkpoint),
            "metrics_dir": str(paths.metrics),
            "logs_dir": str(paths.logs),
            "data_dirs": data_dirs,
            "policy": str(policy) if policy is not None else "none",
            "algorithm_config": str(paths.algorithm_config),
            "seed": str(self.cfg.run.seed + r),
            "episodes": str(self.cfg.collector.episodes_per_round),
            "ros_port": str(port),
            "ros_master_uri": f"http://localhost:{port}",
            "python": sys.executable,
            "config_dir": str(self.config_dir),
        }

    def _spec(
        self, name: str, argv: list[str], extra_env: dict[str, str], ctx: dict[str, str], paths: RoundPaths
    ) -> ChildSpec:
        env = dict(os.environ)
        env.update(
            {
                "ROS_MASTER_URI": ctx["ros_master_uri"],
                "ROS_LOG_DIR": str(paths.logs / "ros"),
                "QUAD_IL_RUN_DIR": ctx["run_dir"],
                "QUAD_IL_ROUND": ctx["round"],
                "PYTHONUNBUFFERED": "1",
            }
        )
        env.update({k: v.format(**ctx) for k, v in extra_env.items()})
        return ChildSpec(
            name=name,
            argv=[a.format(**ctx) for a in argv],
            log_path=paths.logs / f"{name}.log",
            env=env,
            cwd=self.config_dir,
        )

    def _run_stage(self, stage: str, r: int, paths: RoundPaths, policy: Path | None) -> StageResult:
        try:
            return self._run_stage_children(stage, r, paths, policy)
        except ChildStartError as e:
            self.sup.stop_all(graceful=not self.stop.urgent)
            return StageResult(Status.FAILED, None, str(e))

    def _run_stage_children(self, stage: str, r: int, paths: RoundPaths, policy: Path | None) -> StageResult:
        if stage == "collect":
            return self._collect(r, paths, policy)
        section = self.cfg.training if stage == "train" else self.cfg.eval
        ctx = self._context(r, paths, policy, self._port())
        if section.command is None:  # validated: enabled sections have commands
            raise ManagerError(f"{stage}: no command configured")
        child = self.sup.start(self._spec(stage, list(section.command), dict(section.env), ctx, paths))
        return self._wait_task(child, section.timeout_s, services=[])

    def _port(self) -> int:
        port = self.cfg.ros.port
        return free_port() if port == "auto" else int(port)

    def _collect(self, r: int, paths: RoundPaths, policy: Path | None) -> StageResult:
        port = self._port()
        if self.cfg.ros.enabled and port_accepts(port):
            return StageResult(Status.FAILED, None, f"ros.port {port} is already in use")
        ctx = self._context(r, paths, policy, port)
        services: list[Child] = []
        if self.cfg.ros.enabled:
            roscore = self.sup.start(
                self._spec("roscore", list(self.cfg.ros.roscore_command), {}, ctx, paths)
            )
            services.append(roscore)
            ready = self._wait_for(lambda: port_accepts(port), roscore, self.cfg.ros.ready_timeout_s)
            if ready is not None:
                self.sup.stop_all(graceful=not self.stop.urgent)
                return ready
            log.info("ROS master up on port %d", port)
        for name in SERVICE_ORDER:
            section: ServiceSection = getattr(self.cfg, name)
            if not section.enabled or (name == "learner" and policy is None):
                continue
            services.append(
                self.sup.start(self._spec(name, list(section.command or []), dict(section.env), ctx, paths))
            )
        collector = self.sup.start(
            self._spec(
                "collector", list(self.cfg.collector.command), dict(self.cfg.collector.env), ctx, paths
            )
        )
        result = self._wait_task(collector, self.cfg.collector.timeout_s, services)
        reports = self.sup.stop_all(graceful=not self.stop.urgent)
        for rep in reports:
            log.info("stopped %s: exit %s after %s", rep.name, rep.returncode, rep.escalation.value)
        if result.status is Status.COMPLETE and self.stop.requested:
            return StageResult(Status.INTERRUPTED, result.exit_code, "stop requested while stopping services")
        return result

    def _wait_for(self, condition: Any, child: Child, timeout_s: float) -> StageResult | None:
        """Wait until condition() holds; a StageResult if the child died, a stop came or time ran out."""
        deadline = time.monotonic() + timeout_s
        while not condition():
            if self.stop.requested:
                return StageResult(Status.INTERRUPTED, None, f"stop requested while waiting for {child.name}")
            rc = child.poll()
            if rc is not None:
                return StageResult(
                    Status.FAILED, rc, f"{child.name} exited with code {rc} before it was ready"
                )
            if time.monotonic() >= deadline:
                return StageResult(Status.FAILED, None, f"{child.name} not ready within {timeout_s:.1f} s")
            time.sleep(self.cfg.signals.poll_interval_s)
        return None

    def _wait_task(self, task: Child, timeout_s: float, services: list[Child]) -> StageResult:
        """Wait for a task child to exit while watching the services it needs, the clock and stop requests."""
        deadline = time.monotonic() + timeout_s
        while True:
            rc = task.poll()
            if rc is not None:
                reap_zombies(exclude={c.pid for c in self.sup.children})
                # A task that exits is done only if its own descendants are too (no orphaned helpers).
                self.sup.stop(task, graceful=True)
                if rc == 0:
                    return StageResult(Status.COMPLETE, 0, "")
                if self.stop.requested:
                    return StageResult(Status.INTERRUPTED, rc, f"{task.name} exited with code {rc} on stop")
                return StageResult(Status.FAILED, rc, f"{task.name} exited with code {rc}")
            if self.stop.requested:
                rep = self.sup.stop(task, graceful=not self.stop.urgent)
                return StageResult(
                    Status.INTERRUPTED,
                    rep.returncode,
                    f"{signal.Signals(self.stop.signum or signal.SIGINT).name} received; {task.name} stopped "
                    f"with {rep.escalation.value} (exit {rep.returncode})",
                )
            for svc in services:
                src = svc.poll()
                if src is not None:
                    rep = self.sup.stop(task, graceful=True)
                    return StageResult(
                        Status.FAILED,
                        rep.returncode,
                        f"{svc.name} exited with code {src} while {task.name} was running",
                    )
            if time.monotonic() >= deadline:
                rep = self.sup.stop(task, graceful=True)
                return StageResult(
                    Status.FAILED, rep.returncode, f"{task.name} timed out after {timeout_s:.1f} s"
                )
            self.sup.refresh()
            time.sleep(self.cfg.signals.poll_interval_s)

    # ---- state, lock ----
    def _state(self) -> RunState:
        if self.state is None:
            raise ManagerError("internal: state not loaded")
        return self.state

    def _load_or_create_state(self) -> RunState:
        digest = config_digest(self.cfg)
        if self.layout.state.exists():
            state = RunState.load(self.layout.state)
            if state.config_sha256 != digest:
                if not self.allow_config_change:
                    raise ManagerError(
                        f"{self.layout.config} differs from the given config (sha256 "
                        f"{state.config_sha256[:12]} vs {digest[:12]}); resume with the same config, or pass "
                        "--allow-config-change"
                    )
                backup = self.layout.run_dir / f"config.{time.strftime('%Y%m%d-%H%M%S')}.yaml"
                if self.layout.config.exists():
                    os.replace(self.layout.config, backup)
                log.warning("config changed on resume; previous config kept as %s", backup)
                state.config_sha256 = digest
            for stages in state.rounds.values():  # a manager that died hard leaves 'running' stages behind
                for st in stages.values():
                    if st.status is Status.RUNNING:
                        st.status, st.reason = Status.INTERRUPTED, "manager ended without closing the stage"
            if self.redo_from is not None:
                self._discard_rounds(state, self.redo_from)
        else:
            if self.redo_from is not None:
                raise ManagerError(
                    f"--redo-from {self.redo_from}: {self.layout.run_dir} has no run state "
                    f"({self.layout.state.name}) to redo from; start the run without --redo-from"
                )
            state = RunState(config_sha256=digest)
        if not self.layout.config.exists():
            self.layout.config.write_text(self.config_text)
        state.finished = False
        state.save(self.layout.state)
        return state

    def _discard_rounds(self, state: RunState, first: int) -> None:
        """`--redo-from`: move round directories >= `first` aside and forget their state (under the lock)."""
        stamp = time.strftime("%Y%m%d-%H%M%S")
        moved = []
        for path in sorted(self.layout.run_dir.glob("round_[0-9][0-9][0-9]")):
            index = int(path.name[len("round_") :])
            if index >= first:
                target = path.with_name(f"{path.name}.discarded-{stamp}")
                os.replace(path, target)
                moved.append(target.name)
        dropped = state.discard_rounds_from(first)
        state.save(self.layout.state)
        log.warning("--redo-from %d: rounds %s discarded; directories moved to %s", first, dropped, moved)

    def _acquire_lock(self) -> None:
        fd = os.open(self.layout.lock, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.read(fd, 64).decode(errors="replace").strip() or "?"
            os.close(fd)
            raise ManagerError(f"{self.layout.run_dir} is in use by another manager (pid {holder})") from None
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self._lock_fd = fd

    def _release_lock(self) -> None:
        if self._lock_fd is not None:
            fcntl.flock(self._lock_fd, fcntl.LOCK_UN)
            os.close(self._lock_fd)
            self._lock_fd = None
