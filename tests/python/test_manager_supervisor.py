"""Process supervisor: SIGINT -> SIGTERM -> SIGKILL escalation, whole trees stopped, no descendant survives.

The children are stand-in Python scripts (CHILD_SCRIPT, also used by test_manager_run.py) that record their
PIDs and the signals they receive, trap SIGINT to finalise, and can ignore signals or spawn grandchildren that
escape the process group.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import psutil
import pytest

from quad_il.manager.supervisor import ChildSpec, Escalation, Supervisor

ROOT = Path(__file__).resolve().parents[2]
SRC = ROOT / "src" / "quad_il" / "src"

CHILD_SCRIPT = r'''
"""Stand-in child for the manager tests (service, collector, trainer), see test_manager_supervisor.py."""
import argparse, json, os, signal, subprocess, sys, time
from pathlib import Path

p = argparse.ArgumentParser()
p.add_argument("--name", required=True)
p.add_argument("--control", required=True, type=Path)
p.add_argument("--mode", choices=["service", "collector", "train", "exit"], default="service")
p.add_argument("--ignore-int", action="store_true")
p.add_argument("--ignore-term", action="store_true")
p.add_argument("--setsid", action="store_true")
p.add_argument("--spawn", choices=["none", "child", "escaper"], default="none")
p.add_argument("--data", type=Path)
p.add_argument("--episodes", type=int, default=3)
p.add_argument("--out", type=Path)
p.add_argument("--inputs", default="")
p.add_argument("--exit-code", type=int, default=0)
p.add_argument("--slow-flag", default="slow")
p.add_argument("--wait-for", default="", help="comma-separated children to wait for (live pid files)")
p.add_argument("--block-flag", default="", help="while this control file exists: write a torn output, wait")
a = p.parse_args()
if a.setsid:
    os.setsid()
ctl = a.control
stop = False

def event(what):
    fd = os.open(ctl / "events.log", os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    os.write(fd, f"{a.name} {os.getpid()} {what}\n".encode())
    os.close(fd)

def on_int(signum, frame):
    global stop
    event("SIGINT")
    if not a.ignore_int:
        stop = True

def on_term(signum, frame):
    event("SIGTERM")
    if not a.ignore_term:
        os._exit(143)

signal.signal(signal.SIGINT, on_int)
signal.signal(signal.SIGTERM, on_term)
(ctl / "pids").mkdir(parents=True, exist_ok=True)
kids = []
if a.spawn != "none":
    extra = ["--setsid", "--ignore-int", "--ignore-term"] if a.spawn == "escaper" else []
    kids.append(subprocess.Popen([sys.executable, __file__, "--name", a.name + "_" + a.spawn, "--control",
                                  str(ctl), *extra]))
    while not any((ctl / "pids").glob(a.name + "_" + a.spawn + ".*")) and kids[0].poll() is None and not stop:
        time.sleep(0.01)
(ctl / "pids" / f"{a.name}.{os.getpid()}").write_text(str(os.getpid()))
event("started")

def live(name):
    for f in (ctl / "pids").glob(name + ".*"):
        try:
            os.kill(int(f.read_text()), 0)
            return True
        except (ProcessLookupError, ValueError):
            pass
    return False

for other in filter(None, a.wait_for.split(",")):
    while not live(other) and not stop:
        time.sleep(0.01)

if a.block_flag and (ctl / a.block_flag).exists():
    # A stage caught half-way: a torn output (a checkpoint or metrics being written), then a wait; SIGINT
    # ends it like a KeyboardInterrupt would, without completing the output.
    if a.out:
        a.out.mkdir(parents=True, exist_ok=True)
        (a.out / "torn.partial").write_text("half")
    event("blocked")
    while (ctl / a.block_flag).exists() and not stop:
        time.sleep(0.02)
    if stop:
        event("interrupted")
        for k in kids:
            k.send_signal(signal.SIGINT)
            k.wait()
        sys.exit(130)

if a.mode == "service":
    while not stop:
        signal.pause()
    event("finalised")
elif a.mode == "collector":
    a.data.mkdir(parents=True, exist_ok=True)
    done = 0
    for ep in range(a.episodes):
        part = a.data / f"episode_{ep:03d}.ep.partial"
        with open(part, "w") as fh:
            fh.write(f"begin {ep}\n")
            fh.flush()
            if (ctl / a.slow_flag).exists():
                time.sleep(0.3)   # "recording"; a SIGINT lets the episode finish first
            fh.write(f"end {ep}\n")
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(part, a.data / f"episode_{ep:03d}.ep")
        done += 1
        if stop:
            break
    (a.data / "manifest.json").write_text(json.dumps({"episodes": done, "interrupted": stop}))
    event("finalised")
elif a.mode == "train":
    with open(ctl / "train.log", "a") as fh:
        fh.write(f"{a.name} {a.inputs}\n")
    if (ctl / "fail_train").exists():
        sys.exit(3)
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "policy.pt").write_text(a.inputs)
    event("finalised")
    for k in kids:  # a trainer's helpers (data loader workers) end with it
        k.send_signal(signal.SIGINT)
else:
    if a.out:
        a.out.mkdir(parents=True, exist_ok=True)
        (a.out / "metrics.json").write_text(json.dumps({"name": a.name}))
    sys.exit(a.exit_code)
for k in kids:
    k.wait()
'''


def write_child(tmp_path: Path) -> Path:
    script = tmp_path / "child.py"
    script.write_text(CHILD_SCRIPT)
    return script


def wait_until(pred: Callable[[], bool], timeout_s: float = 15.0, what: str = "condition") -> None:
    deadline = time.monotonic() + timeout_s
    while not pred():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.02)


def pids(control: Path, name: str) -> list[int]:
    return (
        [int(p.read_text()) for p in (control / "pids").glob(f"{name}.*")]
        if (control / "pids").exists()
        else []
    )


def events(control: Path) -> list[str]:
    f = control / "events.log"
    return (
        [" ".join((ln.split()[0], ln.split()[2])) for ln in f.read_text().splitlines()] if f.exists() else []
    )


def alive(pid: int) -> bool:
    try:
        return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


@pytest.fixture
def setup(tmp_path: Path):
    """(make_supervisor, script, control). Graceful waits end as soon as the tree is gone, so generous
    defaults cost nothing and keep the tests robust on a loaded machine; escalation tests shorten what they
    must wait."""
    control = tmp_path / "control"
    control.mkdir()
    script = write_child(tmp_path)
    made: list[Supervisor] = []

    def make(sigint_timeout_s: float = 10.0, sigterm_timeout_s: float = 10.0) -> Supervisor:
        sup = Supervisor(sigint_timeout_s, sigterm_timeout_s, poll_interval_s=0.02)
        made.append(sup)
        return sup

    yield make, script, control
    for sup in made:
        sup.stop_all(graceful=False)


def start(sup: Supervisor, script: Path, control: Path, name: str, *args: str):
    child = sup.start(
        ChildSpec(
            name,
            [sys.executable, str(script), "--name", name, "--control", str(control), *args],
            control / f"{name}.log",
        )
    )
    wait_until(lambda: pids(control, name), what=f"{name} to start")
    return child


def test_a_child_trapping_sigint_stops_gracefully(setup) -> None:
    make, script, control = setup
    sup = make()
    child = start(sup, script, control, "svc")
    rep = sup.stop(child)
    assert rep.escalation is Escalation.SIGINT and rep.returncode == 0
    assert events(control) == ["svc started", "svc SIGINT", "svc finalised"]
    assert sup.children == []


def test_a_child_ignoring_sigint_is_escalated_to_sigterm(setup) -> None:
    make, script, control = setup
    sup = make(sigint_timeout_s=0.5)
    child = start(sup, script, control, "stubborn", "--ignore-int")
    rep = sup.stop(child)
    assert rep.escalation is Escalation.SIGTERM and rep.returncode == 143
    assert events(control) == ["stubborn started", "stubborn SIGINT", "stubborn SIGTERM"]


def test_a_child_ignoring_sigint_and_sigterm_is_killed(setup) -> None:
    make, script, control = setup
    sup = make(sigint_timeout_s=0.5, sigterm_timeout_s=0.5)
    child = start(sup, script, control, "deaf", "--ignore-int", "--ignore-term")
    rep = sup.stop(child)
    assert rep.escalation is Escalation.SIGKILL and rep.returncode == -signal.SIGKILL
    assert not alive(child.pid)


def test_grandchildren_in_the_group_receive_sigint_and_the_whole_tree_ends(setup) -> None:
    make, script, control = setup
    sup = make()
    child = start(sup, script, control, "launch", "--spawn", "child")
    grandchild = pids(control, "launch_child")[0]
    rep = sup.stop(child)
    assert rep.escalation is Escalation.SIGINT
    assert {"launch SIGINT", "launch_child SIGINT", "launch_child finalised"} <= set(events(control))
    assert not alive(grandchild)


def test_a_grandchild_that_left_the_group_and_ignores_signals_is_still_killed(setup) -> None:
    make, script, control = setup
    sup = make(sigint_timeout_s=0.5, sigterm_timeout_s=0.5)
    child = start(sup, script, control, "svc", "--spawn", "escaper")
    escaper = pids(control, "svc_escaper")[0]
    assert os.getpgid(escaper) != child.pgid
    sup.refresh()  # the manager snapshots the tree on every poll
    rep = sup.stop(child)
    assert rep.stragglers_killed >= 1 and rep.escalation is Escalation.SIGKILL
    assert not alive(escaper) and not alive(child.pid)


def test_stop_all_stops_the_last_started_child_first(setup) -> None:
    make, script, control = setup
    sup = make()
    start(sup, script, control, "first")
    start(sup, script, control, "second")
    reports = sup.stop_all()
    assert [r.name for r in reports] == ["second", "first"]
    sigints = [e for e in events(control) if e.endswith("SIGINT")]
    assert sigints == ["second SIGINT", "first SIGINT"]


DRIVER_SWEEP = r"""
import subprocess, sys, time
from pathlib import Path
from quad_il.manager.supervisor import become_subreaper, sweep_descendants
script, control = sys.argv[1], Path(sys.argv[2])
assert become_subreaper()
# A short-lived child leaves an escaper (own session, ignores SIGINT/SIGTERM) behind: an orphan, re-parented
# to us.
subprocess.run([sys.executable, script, "--name", "svc", "--control", str(control), "--mode", "exit",
                "--spawn", "escaper"], check=True)
found = sweep_descendants(timeout_s=1.0)
print(" ".join(map(str, found)))
"""

DRIVER_PDEATHSIG = r"""
import sys, time
from pathlib import Path
from quad_il.manager.supervisor import ChildSpec, Supervisor
script, control = sys.argv[1], Path(sys.argv[2])
sup = Supervisor(1.0, 1.0)
sup.start(ChildSpec("orphan", [sys.executable, script, "--name", "orphan", "--control", str(control)],
                    control / "orphan.log"))
time.sleep(600)
"""


def _driver_env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = f"{SRC}{os.pathsep}{env.get('PYTHONPATH', '')}"
    return env


def test_sweep_kills_orphaned_descendants_re_parented_to_the_subreaper(tmp_path: Path) -> None:
    control = tmp_path / "control"
    control.mkdir()
    script = write_child(tmp_path)
    out = subprocess.run(
        [sys.executable, "-c", DRIVER_SWEEP, str(script), str(control)],
        env=_driver_env(),
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    escaper = pids(control, "svc_escaper")[0]
    assert str(escaper) in out.stdout.split()
    wait_until(lambda: not alive(escaper), what="the escaper to die")


def test_children_are_told_to_stop_when_the_manager_is_killed(tmp_path: Path) -> None:
    control = tmp_path / "control"
    control.mkdir()
    script = write_child(tmp_path)
    driver = subprocess.Popen(
        [sys.executable, "-c", DRIVER_PDEATHSIG, str(script), str(control)], env=_driver_env()
    )
    try:
        wait_until(lambda: pids(control, "orphan"), what="the child to start")
        orphan = pids(control, "orphan")[0]
        driver.kill()  # SIGKILL: no handler runs in the manager
        driver.wait()
        wait_until(lambda: "orphan SIGTERM" in events(control), what="PR_SET_PDEATHSIG's SIGTERM")
        wait_until(lambda: not alive(orphan), what="the orphan to exit")
    finally:
        if driver.poll() is None:
            driver.kill()
