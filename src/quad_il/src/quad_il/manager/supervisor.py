"""Process supervisor: children in their own process groups, stopped SIGINT -> SIGTERM -> SIGKILL, none left
behind.

- Each child runs in a new session (its own process group), so a Ctrl-C in the terminal reaches only the
manager,
  which then stops the children in reverse start order (the collector before the simulator it records from).
- Stop = SIGINT to the child's group (graceful: roslaunch forwards it to its nodes, the collector finalises
its
  data), wait `sigint_timeout_s`; SIGTERM to the group, wait `sigterm_timeout_s`; SIGKILL. The wait is for
  every process of the child's tree, not just its root: a roslaunch parent may exit before its nodes.
- Descendants are tracked with psutil snapshots while the child runs; one that left the group (setsid) is
  signalled individually. The manager is also a child subreaper (Linux prctl), so orphaned descendants are
  re-parented to it instead of init: `sweep_descendants` then finds and kills whatever survived, and reaps
  zombies.
- Direct children get PR_SET_PDEATHSIG = SIGTERM: if the manager itself is SIGKILLed, they are told to stop.
"""

from __future__ import annotations

import ctypes
import dataclasses
import enum
import logging
import os
import signal
import subprocess
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import psutil

_PR_SET_PDEATHSIG = 1
_PR_SET_CHILD_SUBREAPER = 36

log = logging.getLogger("quad_il.manager")


def _libc() -> ctypes.CDLL | None:
    try:
        return ctypes.CDLL("libc.so.6", use_errno=True)
    except OSError:  # not glibc Linux: no subreaper / pdeathsig, the psutil tracking still works
        return None


def become_subreaper() -> bool:
    libc = _libc()
    return bool(libc is not None and libc.prctl(_PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0) == 0)


def _child_preexec(parent_pid: int) -> Callable[[], None]:
    def setup() -> None:
        libc = _libc()
        if libc is not None:
            libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
        if os.getppid() != parent_pid:  # the manager died between fork and prctl
            os._exit(1)

    return setup


class ChildStartError(RuntimeError):
    """A child could not be started (missing executable, bad working directory); the message names it."""


class Escalation(enum.Enum):
    NONE = "none"  # had already exited
    SIGINT = "sigint"
    SIGTERM = "sigterm"
    SIGKILL = "sigkill"


@dataclasses.dataclass(frozen=True)
class ChildSpec:
    name: str
    argv: Sequence[str]
    log_path: Path
    env: Mapping[str, str] | None = None
    cwd: Path | None = None


@dataclasses.dataclass(frozen=True)
class StopReport:
    name: str
    returncode: int | None
    escalation: Escalation
    stragglers_killed: int  # tracked descendants outside the group that needed an individual signal


class Child:
    def __init__(self, spec: ChildSpec, popen: subprocess.Popen[bytes]) -> None:
        self.spec = spec
        self.popen = popen
        self.pid = popen.pid
        self.pgid = popen.pid  # new session: the child leads its own group
        self.started_monotonic = time.monotonic()
        self._tracked: dict[int, psutil.Process] = {}
        self.refresh_tree()

    @property
    def name(self) -> str:
        return self.spec.name

    def poll(self) -> int | None:
        return self.popen.poll()

    def refresh_tree(self) -> None:
        """Remember every current descendant (psutil.Process keeps its create time: PID reuse is detected)."""
        try:
            root = psutil.Process(self.pid)
            procs = [root, *root.children(recursive=True)]
        except psutil.NoSuchProcess:
            return
        for p in procs:
            self._tracked.setdefault(p.pid, p)

    def alive_tree(self) -> list[psutil.Process]:
        """Tracked processes (and current group members) still running (zombies count as gone)."""
        alive = []
        seen: set[int] = set()
        for p in list(self._tracked.values()) + _group_members(self.pgid):
            if p.pid in seen:
                continue
            seen.add(p.pid)
            try:
                if p.is_running() and p.status() != psutil.STATUS_ZOMBIE:
                    alive.append(p)
            except psutil.NoSuchProcess:
                continue
        return alive


def _group_members(pgid: int) -> list[psutil.Process]:
    out = []
    for p in psutil.process_iter():
        try:
            if os.getpgid(p.pid) == pgid:
                out.append(p)
        except (ProcessLookupError, psutil.NoSuchProcess, PermissionError):
            continue
    return out


class Supervisor:
    def __init__(
        self,
        sigint_timeout_s: float,
        sigterm_timeout_s: float,
        poll_interval_s: float = 0.1,
        urgent: Callable[[], bool] | None = None,
    ) -> None:
        self.sigint_timeout_s = sigint_timeout_s
        self.sigterm_timeout_s = sigterm_timeout_s
        self.poll_interval_s = poll_interval_s
        # True when the user insists (second Ctrl-C): graceful waits are cut short.
        self.urgent = urgent or (lambda: False)
        self.children: list[Child] = []

    def start(self, spec: ChildSpec) -> Child:
        spec.log_path.parent.mkdir(parents=True, exist_ok=True)
        with open(spec.log_path, "ab") as fh:
            banner = f"\n===== {time.strftime('%Y-%m-%d %H:%M:%S')} start {spec.name}: {list(spec.argv)}\n"
            fh.write(banner.encode())
            fh.flush()
            try:
                popen = subprocess.Popen(
                    list(spec.argv),
                    stdin=subprocess.DEVNULL,
                    stdout=fh,
                    stderr=subprocess.STDOUT,
                    env=dict(spec.env) if spec.env is not None else None,
                    cwd=spec.cwd,
                    start_new_session=True,
                    preexec_fn=_child_preexec(os.getpid()),  # safe: the manager is single-threaded
                )
            except (OSError, subprocess.SubprocessError) as e:
                fh.write(f"cannot start {spec.name}: {e}\n".encode())
                raise ChildStartError(f"cannot start {spec.name} ({spec.argv[0]!r}): {e}") from None
        child = Child(spec, popen)
        self.children.append(child)
        log.info("started %s (pid %d): %s", spec.name, child.pid, " ".join(spec.argv))
        return child

    def refresh(self) -> None:
        for c in self.children:
            c.refresh_tree()
        reap_zombies(exclude={c.pid for c in self.children})

    def wait_tree_gone(self, child: Child, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while True:
            child.poll()  # reap the root as soon as it exits
            reap_zombies(exclude={c.pid for c in self.children})
            if not child.alive_tree():
                return True
            if time.monotonic() >= deadline or self.urgent():
                return False
            time.sleep(self.poll_interval_s)

    def stop(self, child: Child, graceful: bool = True) -> StopReport:
        """Stop one child and its whole tree; returns how far the escalation went."""
        child.refresh_tree()
        if not child.alive_tree():
            child.poll()
            self._forget(child)
            return StopReport(child.name, child.popen.returncode, Escalation.NONE, 0)
        steps: list[tuple[Escalation, signal.Signals, float]] = []
        if graceful:
            steps.append((Escalation.SIGINT, signal.SIGINT, self.sigint_timeout_s))
        steps.append((Escalation.SIGTERM, signal.SIGTERM, self.sigterm_timeout_s))
        steps.append((Escalation.SIGKILL, signal.SIGKILL, 10.0))
        stragglers = 0
        reached = Escalation.NONE
        for level, sig, timeout in steps:
            if self.urgent() and sig is not signal.SIGKILL:
                continue
            reached = level
            log.info("stopping %s (pid %d) with %s", child.name, child.pid, sig.name)
            stragglers += self._signal_tree(child, sig)
            if self.wait_tree_gone(child, timeout):
                break
            log.warning("%s did not stop within %.1f s of %s", child.name, timeout, sig.name)
        child.poll()
        self._forget(child)
        return StopReport(child.name, child.popen.returncode, reached, stragglers)

    def stop_all(self, graceful: bool = True) -> list[StopReport]:
        """Stop every running child, last started first."""
        return [self.stop(c, graceful) for c in reversed(list(self.children))]

    def _signal_tree(self, child: Child, sig: signal.Signals) -> int:
        try:
            os.killpg(child.pgid, sig)
        except ProcessLookupError:
            pass
        outside = 0
        for p in child.alive_tree():
            try:
                if os.getpgid(p.pid) != child.pgid:
                    p.send_signal(sig)
                    outside += 1
            except (ProcessLookupError, psutil.NoSuchProcess):
                continue
        return outside

    def _forget(self, child: Child) -> None:
        if child in self.children:
            self.children.remove(child)


def reap_zombies(exclude: set[int]) -> None:
    """Reap exited orphans re-parented to us (subreaper); never our own Popen children (their codes
    matter)."""
    try:
        kids = psutil.Process().children()
    except psutil.NoSuchProcess:
        return
    for p in kids:
        if p.pid in exclude:
            continue
        try:
            if p.status() == psutil.STATUS_ZOMBIE:
                os.waitpid(p.pid, os.WNOHANG)
        except (psutil.NoSuchProcess, ChildProcessError):
            continue


def sweep_descendants(timeout_s: float, exclude: set[int] | None = None) -> list[int]:
    """Kill every remaining descendant of this process (SIGTERM, then SIGKILL); returns the PIDs found."""
    exclude = exclude or set()
    try:
        procs = [p for p in psutil.Process().children(recursive=True) if p.pid not in exclude]
    except psutil.NoSuchProcess:
        return []
    procs = [p for p in procs if _is_live(p)]
    if not procs:
        reap_zombies(exclude)
        return []
    found = [p.pid for p in procs]
    log.warning("sweeping %d leftover descendant process(es): %s", len(procs), found)
    for sig in (signal.SIGTERM, signal.SIGKILL):
        for p in procs:
            try:
                p.send_signal(sig)
            except psutil.NoSuchProcess:
                continue
        _, procs = psutil.wait_procs(procs, timeout=timeout_s)
        procs = [p for p in procs if _is_live(p)]
        if not procs:
            break
    reap_zombies(exclude)
    return found


def _is_live(p: psutil.Process) -> bool:
    try:
        return p.is_running() and p.status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False
