"""imitation_learning_manager.py end to end with stand-in children: rounds, run-directory layout, SIGINT in
the middle of a round (data finalised, state says incomplete, resume), failures, config changes, a private
roscore."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import psutil
import pytest
import yaml
from test_manager_supervisor import alive, events, pids, wait_until, write_child

ROOT = Path(__file__).resolve().parents[2]
MANAGER = ROOT / "src" / "quad_il" / "nodes" / "imitation_learning_manager.py"
SRC = ROOT / "src" / "quad_il" / "src"


def make_config(tmp: Path, **overrides: Any) -> tuple[Path, Path, Path]:
    """(config path, run dir, control dir) for a 2-round DAgger run with stand-in children."""
    script = write_child(tmp)
    control = tmp / "control"
    control.mkdir(exist_ok=True)
    py = sys.executable

    def child(name: str, *args: str) -> list[str]:
        return [py, str(script), "--name", name, "--control", str(control), *args]

    tree: dict[str, Any] = {
        "run": {"run_dir": str(tmp / "run"), "seed": 7},
        "ros": {"enabled": False},
        "simulator": {"command": child("simulator")},
        "expert": {"command": child("expert", "--spawn", "child")},
        "learner": {"enabled": True, "command": child("learner")},
        "collector": {
            "command": child(
                "collector",
                "--mode",
                "collector",
                "--data",
                "{data_dir}",
                "--episodes",
                "{episodes}",
                "--slow-flag",
                "slow_{round}",
                "--wait-for",
                "simulator,expert,expert_child",
            ),
            "episodes_per_round": 3,
        },
        "algorithm": {"name": "dagger", "beta": {"kind": "linear", "rounds_to_zero": 2}},
        "rounds": {"count": 2},
        "training": {
            "command": child(
                "train_{round}",
                "--mode",
                "train",
                "--out",
                "{checkpoint_dir}",
                "--inputs",
                "{data_dirs}|{policy}",
            ),
        },
        "eval": {"enabled": True, "command": child("eval_{round}", "--mode", "exit")},
        # Generous: graceful stops end as soon as the children are gone (robust on a loaded machine).
        "signals": {"sigint_timeout_s": 10.0, "sigterm_timeout_s": 10.0, "poll_interval_s": 0.05},
    }
    for key, value in overrides.items():
        section, _, field = key.partition("__")
        if field:
            tree[section][field] = value
        else:
            tree[section] = value
    cfg = tmp / "il_manager.yaml"
    cfg.write_text(yaml.safe_dump(tree))
    return cfg, tmp / "run", control


def env() -> dict[str, str]:
    e = dict(os.environ)
    e["PYTHONPATH"] = f"{SRC}{os.pathsep}{e.get('PYTHONPATH', '')}"
    return e


def manager(cfg: Path, *args: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, str(MANAGER), str(cfg), *args],
        env=env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )


def run_manager(cfg: Path, *args: str, timeout_s: float = 120.0) -> tuple[int, str]:
    proc = manager(cfg, *args)
    out, _ = proc.communicate(timeout=timeout_s)
    return proc.returncode, out


def state(run: Path) -> dict[str, Any]:
    return json.loads((run / "state.json").read_text())


def all_child_pids(control: Path) -> list[int]:
    return [int(p.read_text()) for p in (control / "pids").glob("*")]


def survivors(run: Path) -> list[int]:
    """Live processes started for this run: every child of the manager carries QUAD_IL_RUN_DIR."""
    found = []
    for p in psutil.process_iter():
        try:
            if p.environ().get("QUAD_IL_RUN_DIR") == str(run) and p.status() != psutil.STATUS_ZOMBIE:
                found.append(p.pid)
        except (psutil.NoSuchProcess, psutil.AccessDenied, psutil.ZombieProcess):
            continue
    return found


def no_child_survives(run: Path, control: Path) -> bool:
    return survivors(run) == [] and not any(alive(p) for p in all_child_pids(control))


def banners(log: Path) -> int:
    return log.read_text().count("=====") if log.exists() else 0


def test_a_full_run_lays_out_every_round_and_feeds_training_the_aggregated_data(tmp_path: Path) -> None:
    cfg, run, control = make_config(tmp_path)
    rc, out = run_manager(cfg)
    assert rc == 0, out
    st = state(run)
    assert st["finished"] and st["completed_rounds"] == [0, 1] and st["last_completed_round"] == 1
    for r in (0, 1):
        rd = run / f"round_{r:03d}"
        assert sorted(p.name for p in (rd / "data").iterdir()) == [
            "episode_000.ep",
            "episode_001.ep",
            "episode_002.ep",
            "manifest.json",
        ]
        assert json.loads((rd / "data" / "manifest.json").read_text()) == {
            "episodes": 3,
            "interrupted": False,
        }
        assert (rd / "checkpoint" / "policy.pt").exists()
        for name in ("simulator", "expert", "collector", "train", "eval"):
            assert (rd / "logs" / f"{name}.log").exists(), name
        summary = json.loads((rd / "round.json").read_text())
        assert summary["complete"] and set(summary["stages"]) == {"collect", "train", "eval"}
    # Round 0 has no policy yet: no learner, the expert flies (BC); round 1 flies round 0's policy.
    assert not (run / "round_000" / "logs" / "learner.log").exists()
    assert (run / "round_001" / "logs" / "learner.log").exists()
    algo0 = yaml.safe_load((run / "round_000" / "algorithm.yaml").read_text())
    algo1 = yaml.safe_load((run / "round_001" / "algorithm.yaml").read_text())
    assert (algo0["expert_only"], algo0["beta"], algo0["seed"]) == (True, 1.0, 7)
    assert (algo1["expert_only"], algo1["beta"], algo1["seed"]) == (False, 0.5, 8)
    assert algo1["algorithm"]["name"] == "dagger"
    d0, d1 = run / "round_000" / "data", run / "round_001" / "data"
    assert (control / "train.log").read_text().splitlines() == [
        f"train_0 {d0}|none",
        f"train_1 {d0},{d1}|{run / 'round_000' / 'checkpoint' / 'policy.pt'}",
    ]
    assert (run / "config.yaml").read_text() == cfg.read_text()
    assert no_child_survives(run, control)
    # Services were stopped gracefully once the collector finished.
    ev = events(control)
    assert ev.count("simulator SIGINT") == 2 and ev.count("expert_child finalised") == 2


def test_sigint_mid_round_finalises_data_and_a_second_invocation_resumes_that_round(tmp_path: Path) -> None:
    # The simulator ignores SIGINT (escalated to SIGTERM); round 1's collector records slowly.
    cfg, run, control = make_config(
        tmp_path,
        simulator__command=[
            sys.executable,
            str(tmp_path / "child.py"),
            "--name",
            "simulator",
            "--control",
            str(tmp_path / "control"),
            "--ignore-int",
        ],
        collector__episodes_per_round=40,
        # The simulator's SIGINT wait is the one the test pays in full.
        signals={"sigint_timeout_s": 3.0, "sigterm_timeout_s": 10.0, "poll_interval_s": 0.05},
    )
    (control / "slow_1").touch()
    proc = manager(cfg)
    data1 = run / "round_001" / "data"
    try:
        # Round 1 records and its learner is up (its pid file is written once its signal handlers are set).
        wait_until(
            lambda: len(list(data1.glob("*.ep"))) >= 1 and any(alive(p) for p in pids(control, "learner")),
            timeout_s=60,
            what="round 1 to record an episode",
        )
        # One manager per run directory: a second one is refused while this one runs.
        rc2, out2 = run_manager(cfg)
        assert rc2 == 2 and "in use by another manager" in out2
        assert (
            len(survivors(run)) >= 5
        )  # the check below can see the children: simulator, expert(+child), ...
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, out
    all_events = events(control)
    ev = all_events[len(all_events) - all_events[::-1].index("collector started") - 1 :]  # round 1's events
    for e in (
        "collector SIGINT",
        "collector finalised",
        "expert SIGINT",
        "expert_child SIGINT",
        "learner SIGINT",
        "simulator SIGINT",
        "simulator SIGTERM",
    ):
        assert e in ev, (e, ev)
    # The collector got SIGINT before the services it records from.
    assert ev.index("collector SIGINT") < min(ev.index("learner SIGINT"), ev.index("expert SIGINT"))
    # Data finalised: no torn episode, a manifest that says interrupted and counts the complete episodes.
    assert not list(data1.glob("*.partial"))
    manifest = json.loads((data1 / "manifest.json").read_text())
    episodes = sorted(data1.glob("*.ep"))
    assert manifest == {"episodes": len(episodes), "interrupted": True} and 1 <= len(episodes) < 40
    for i, ep in enumerate(episodes):
        assert ep.read_text() == f"begin {i}\nend {i}\n"
    st = state(run)
    assert st["completed_rounds"] == [0] and not st["finished"]
    assert st["rounds"]["001"]["complete"] is False
    assert st["rounds"]["001"]["stages"]["collect"]["status"] == "interrupted"
    assert "train" not in st["rounds"]["001"]["stages"]
    assert st["last_event"]["status"] == "interrupted" and st["last_event"]["round"] == 1
    assert no_child_survives(run, control)

    # Resume: round 0 is not redone; round 1's interrupted collection is kept aside and redone.
    (control / "slow_1").unlink()
    rc, out = run_manager(cfg)
    assert rc == 0, out
    assert "resuming" in out and "at round 1" in out
    st = state(run)
    assert st["finished"] and st["completed_rounds"] == [0, 1]
    assert st["rounds"]["001"]["stages"]["collect"]["attempts"] == 2
    kept = run / "round_001" / "attempts" / "collect_001" / "data"
    assert json.loads((kept / "manifest.json").read_text())["interrupted"] is True
    assert json.loads((data1 / "manifest.json").read_text()) == {"episodes": 40, "interrupted": False}
    assert [ln.split()[0] for ln in (control / "train.log").read_text().splitlines()] == [
        "train_0",
        "train_1",
    ]
    assert banners(run / "round_000" / "logs" / "collector.log") == 1
    assert banners(run / "round_001" / "logs" / "collector.log") == 2
    assert no_child_survives(run, control)


def test_a_failed_stage_exits_1_and_is_retried_without_redoing_earlier_stages(tmp_path: Path) -> None:
    cfg, run, control = make_config(tmp_path, rounds={"count": 1})
    (control / "fail_train").touch()
    rc, out = run_manager(cfg)
    assert rc == 1, out
    stages = state(run)["rounds"]["000"]["stages"]
    assert stages["collect"]["status"] == "complete"
    assert stages["train"]["status"] == "failed" and stages["train"]["exit_code"] == 3
    assert "exited with code 3" in stages["train"]["reason"]
    (control / "fail_train").unlink()
    rc, out = run_manager(cfg)
    assert rc == 0, out
    assert state(run)["rounds"]["000"]["stages"]["train"]["attempts"] == 2
    assert banners(run / "round_000" / "logs" / "collector.log") == 1


def test_a_service_that_dies_fails_the_collection(tmp_path: Path) -> None:
    cfg, run, control = make_config(
        tmp_path,
        rounds={"count": 1},
        expert__command=[
            sys.executable,
            str(tmp_path / "child.py"),
            "--name",
            "expert",
            "--control",
            str(tmp_path / "control"),
            "--mode",
            "exit",
            "--exit-code",
            "4",
            "--wait-for",
            "collector",  # dies once the collector is up
        ],
        collector__episodes_per_round=1000,
    )
    (control / "slow_0").touch()
    rc, out = run_manager(cfg)
    assert rc == 1, out
    collect = state(run)["rounds"]["000"]["stages"]["collect"]
    assert (
        collect["status"] == "failed"
        and "expert exited with code 4 while collector was running" in collect["reason"]
    )
    assert "collector SIGINT" in events(control)
    assert no_child_survives(run, control)


def test_resuming_with_a_changed_config_is_refused_unless_allowed(tmp_path: Path) -> None:
    cfg, run, _ = make_config(tmp_path, rounds={"count": 1})
    assert run_manager(cfg)[0] == 0
    tree = yaml.safe_load(cfg.read_text())
    tree["rounds"]["count"] = 2
    cfg.write_text(yaml.safe_dump(tree))
    rc, out = run_manager(cfg)
    assert rc == 2 and "differs from the given config" in out
    rc, out = run_manager(cfg, "--allow-config-change")
    assert rc == 0, out
    assert state(run)["completed_rounds"] == [0, 1]
    assert list(run.glob("config.*.yaml"))


def test_redo_from_moves_later_rounds_aside_and_runs_them_again(tmp_path: Path) -> None:
    cfg, run, _ = make_config(tmp_path)
    assert run_manager(cfg)[0] == 0
    first = state(run)["rounds"]["000"]["stages"]["collect"]["finished"]
    marker = run / "round_001" / "data" / "old.txt"
    marker.write_text("kept")
    rc, out = run_manager(cfg, "--redo-from", "1")
    assert rc == 0, out
    st = state(run)
    assert st["completed_rounds"] == [0, 1]
    assert st["rounds"]["000"]["stages"]["collect"]["finished"] == first  # round 0 untouched
    assert st["rounds"]["001"]["stages"]["collect"]["attempts"] == 1  # round 1 started afresh
    discarded = list(run.glob("round_001.discarded-*"))
    assert len(discarded) == 1 and (discarded[0] / "data" / "old.txt").read_text() == "kept"
    assert not (run / "round_001" / "data" / "old.txt").exists()
    assert "rounds [1] discarded" in (run / "manager.log").read_text()


def test_redo_from_a_round_the_config_does_not_have_is_refused(tmp_path: Path) -> None:
    cfg, run, _ = make_config(tmp_path)
    rc, out = run_manager(cfg, "--redo-from", "2")
    assert rc == 2 and "--redo-from 2: the config has rounds 0..1 (rounds.count 2)" in out
    assert not (run / "state.json").exists()


def test_redo_from_without_a_run_to_redo_is_refused(tmp_path: Path) -> None:
    cfg, run, _ = make_config(tmp_path)
    rc, out = run_manager(cfg, "--redo-from", "1")
    assert rc == 2 and f"--redo-from 1: {run} has no run state (state.json) to redo from" in out
    assert not (run / "state.json").exists() and not list(run.glob("round_*"))


def test_config_errors_exit_2_naming_the_key(tmp_path: Path) -> None:
    cfg, run, _ = make_config(tmp_path, rounds={"count": 1, "initial_polcy": "x"})
    rc, out = run_manager(cfg)
    assert rc == 2 and "config key 'rounds.initial_polcy': Extra inputs are not permitted" in out
    assert not run.exists()


ROS_CHECK = (
    "import os, sys, xmlrpc.client; uri = os.environ['ROS_MASTER_URI']; "
    "code, _, _ = xmlrpc.client.ServerProxy(uri).getSystemState('/il_test'); "
    "open(sys.argv[1], 'w').write(uri if code == 1 else 'bad')"
)


@pytest.mark.skipif(not Path("/usr/bin/roscore").exists(), reason="needs Debian's roscore")
def test_roscore_runs_on_a_private_port_and_leaves_nothing_behind(tmp_path: Path) -> None:
    cfg, run, control = make_config(
        tmp_path,
        ros={"enabled": True, "port": "auto"},
        rounds={"count": 1},
        eval={"enabled": False},
        collector__command=[sys.executable, "-c", ROS_CHECK, str(tmp_path / "uri.txt")],
    )
    rc, out = run_manager(cfg)
    assert rc == 0, out
    uri = (tmp_path / "uri.txt").read_text()
    port = int(uri.rsplit(":", 1)[1])
    assert uri.startswith("http://localhost:") and port != 11311
    assert (run / "round_000" / "logs" / "roscore.log").exists()

    def ros_processes() -> list[psutil.Process]:
        """Every process started for this master (roscore, rosmaster, rosout, ...) carries its URI."""
        found = []
        for p in psutil.process_iter():
            try:
                if p.environ().get("ROS_MASTER_URI") == uri or str(port) in " ".join(p.cmdline()):
                    found.append(p)
            except (psutil.NoSuchProcess, psutil.AccessDenied, psutil.ZombieProcess):
                continue
        return found

    assert ros_processes() == []


def test_a_missing_executable_fails_the_stage_naming_the_child(tmp_path: Path) -> None:
    cfg, run, control = make_config(tmp_path, rounds={"count": 1}, expert__command=["/nonexistent/planner"])
    rc, out = run_manager(cfg)
    assert rc == 1, out
    reason = state(run)["rounds"]["000"]["stages"]["collect"]["reason"]
    assert "cannot start expert ('/nonexistent/planner')" in reason and "No such file" in reason
    # The simulator had been started before the expert failed; it was stopped with the rest.
    assert banners(run / "round_000" / "logs" / "simulator.log") == 1
    assert "cannot start expert" in (run / "round_000" / "logs" / "expert.log").read_text()
    assert no_child_survives(run, control)


STAGE_OUTPUT = {"collect": "data", "train": "checkpoint", "eval": "metrics"}


@pytest.mark.parametrize("stage", ["collect", "train", "eval"])
def test_sigint_in_each_stage_leaves_no_process_and_a_resumed_run_completes(
    tmp_path: Path, stage: str
) -> None:
    """Issue 30, fault table "manager SIGINT in each stage": every process the manager started (roscore and
    its rosmaster/rosout in the collect case, a stage child's own child) is gone when it exits with 130, the
    stage is recorded as interrupted and nothing after it ran; the resumed run moves the interrupted stage's
    output aside, redoes only that stage and completes."""
    if stage == "collect" and not Path("/usr/bin/roscore").exists():
        pytest.skip("needs Debian's roscore")
    control = tmp_path / "control"

    def child(name: str, *args: str) -> list[str]:
        return [sys.executable, str(tmp_path / "child.py"), "--name", name, "--control", str(control), *args]

    overrides: dict[str, Any] = {
        "rounds": {"count": 1},
        "training": {
            "command": child("train_{round}", "--mode", "train", "--out", "{checkpoint_dir}", "--inputs",
                             "{data_dirs}|{policy}", "--block-flag", "block_train", "--spawn", "child"),
        },
        "eval": {
            "enabled": True,
            "command": child("eval_{round}", "--mode", "exit", "--out", "{metrics_dir}", "--block-flag",
                             "block_eval", "--spawn", "child"),
        },
    }  # fmt: skip
    if stage == "collect":
        overrides["ros"] = {"enabled": True, "port": "auto"}
        overrides["collector__episodes_per_round"] = 40
    cfg, run, control = make_config(tmp_path, **overrides)
    (control / {"collect": "slow_0", "train": "block_train", "eval": "block_eval"}[stage]).touch()
    out_dir = run / "round_000" / STAGE_OUTPUT[stage]
    proc = manager(cfg)
    try:
        if stage == "collect":
            wait_until(lambda: len(list(out_dir.glob("*.ep"))) >= 1, timeout_s=60, what="an episode recorded")
        else:
            wait_until(lambda: f"{stage}_0 blocked" in events(control), timeout_s=60, what=f"{stage} to run")
        started = survivors(run)
        # Every process of the stage is seen: roscore's tree, or the stage child and its own child.
        assert len(started) >= (3 if stage == "collect" else 2), started
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=90)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, out
    assert not any(alive(p) for p in started), [p for p in started if alive(p)]
    assert no_child_survives(run, control)
    stages = state(run)["rounds"]["000"]["stages"]
    order = ["collect", "train", "eval"]
    for s in order[: order.index(stage)]:
        assert stages[s]["status"] == "complete", stages
    assert stages[stage]["status"] == "interrupted" and "SIGINT received" in stages[stage]["reason"], stages
    assert not set(order[order.index(stage) + 1 :]) & set(stages), stages
    if stage == "collect":  # the collector finalised what it had: whole episodes only, marked interrupted
        assert json.loads((out_dir / "manifest.json").read_text())["interrupted"] is True
        assert not list(out_dir.glob("*.partial"))
    else:  # the stage never completed its output
        assert (out_dir / "torn.partial").exists()
        assert not (out_dir / ("policy.pt" if stage == "train" else "metrics.json")).exists()
        assert f"{stage}_0 interrupted" in events(control)

    for flag in ("slow_0", "block_train", "block_eval"):
        (control / flag).unlink(missing_ok=True)
    rc, out = run_manager(cfg)
    assert rc == 0, out
    st = state(run)
    assert st["finished"] and st["completed_rounds"] == [0]
    for s in order:
        assert st["rounds"]["000"]["stages"][s]["attempts"] == (2 if s == stage else 1), (s, st)
    kept = run / "round_000" / "attempts" / f"{stage}_001" / STAGE_OUTPUT[stage]
    assert kept.is_dir() and any(kept.iterdir())
    assert not list(out_dir.glob("*.partial"))
    assert json.loads((run / "round_000" / "data" / "manifest.json").read_text()) == {
        "episodes": 40 if stage == "collect" else 3,
        "interrupted": False,
    }
    assert (run / "round_000" / "checkpoint" / "policy.pt").exists()
    assert json.loads((run / "round_000" / "metrics" / "metrics.json").read_text()) == {"name": "eval_0"}
    assert no_child_survives(run, control)
