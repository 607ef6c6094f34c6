"""scripts/setup.sh is idempotent; a missing apt package or failed pip step stops naming it."""

import os
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def run_setup(**env):
    full_env = {**os.environ, **env}
    return subprocess.run(
        ["bash", str(ROOT / "scripts" / "setup.sh")],
        capture_output=True,
        text=True,
        env=full_env,
        cwd=ROOT,
        timeout=600,
    )


def test_second_run_changes_nothing_and_says_so():
    first = run_setup()
    assert first.returncode == 0, first.stderr
    second = run_setup()
    assert second.returncode == 0, second.stderr
    assert "apt: all" in second.stdout
    assert "venv: .venv present" in second.stdout
    assert "pip: requirements unchanged" in second.stdout
    assert "pkg: quad_il installed (editable" in second.stdout


def test_the_venv_imports_quad_il_from_this_checkout_without_any_path_setup():
    # -I ignores PYTHONPATH (which scripts/env.sh and the devel space set): the venv's editable install alone.
    venv_python = ROOT / ".venv" / "bin" / "python"
    proc = subprocess.run(
        [str(venv_python), "-I", "-c", "import quad_il; print(quad_il.__file__)"],
        capture_output=True,
        text=True,
        timeout=60,
        cwd="/",
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == str(ROOT / "src" / "quad_il" / "src" / "quad_il" / "__init__.py")


def test_training_only_scripts_and_the_manager_node_do_not_patch_sys_path():
    scripts = [
        *sorted((ROOT / "training_only").glob("*.py")),
        ROOT / "src/quad_il/nodes/imitation_learning_manager.py",
    ]
    for path in scripts:
        assert "sys.path" not in path.read_text(), path


def test_unknown_apt_package_is_named():
    res = run_setup(QUAD_IL_SETUP_STEPS="apt", QUAD_IL_EXTRA_APT="quad-il-no-such-package")
    assert res.returncode != 0
    assert "not found in Debian's archive: quad-il-no-such-package" in res.stderr


def test_failed_pip_step_is_named_and_keeps_the_venv():
    res = run_setup(QUAD_IL_SETUP_STEPS="pip", QUAD_IL_EXTRA_PIP="quad-il-no-such-package==0.0.1")
    assert res.returncode != 0
    assert "pip: install failed for: quad-il-no-such-package==0.0.1" in res.stderr
    # The failed attempt must not mark the requirements as installed nor break the venv.
    again = run_setup(QUAD_IL_SETUP_STEPS="venv pip")
    assert again.returncode == 0, again.stderr
    assert "pip: requirements unchanged" in again.stdout


def test_unknown_step_is_named():
    res = run_setup(QUAD_IL_SETUP_STEPS="apt bogus")
    assert res.returncode != 0
    assert "unknown step 'bogus'" in res.stderr
