"""The import-cycle check of `make lint` (quad_il/tools/import_cycles.py, issue 31)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from quad_il.tools.import_cycles import find_cycles, main, scan_edges

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "src" / "quad_il" / "src" / "quad_il"
CHECKER = PACKAGE / "tools" / "import_cycles.py"


def _write(root: Path, files: dict[str, str]) -> Path:
    for rel, text in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return root


def _synthetic(tmp_path: Path, b_imports_a: str) -> Path:
    """pkg: subpackages a, b, c and a top-level module m; a -> b -> c and b -> m; b's module may import a."""
    return _write(
        tmp_path / "pkg",
        {
            "__init__.py": "",
            "m.py": "X = 1\n",
            "a/__init__.py": "",
            "a/core.py": "from pkg.b import helper\n",
            "b/__init__.py": "from . import helper\n",
            "b/helper.py": f"import pkg.c.leaf\nfrom ..m import X\n\n\ndef f():\n{b_imports_a}    return X\n",
            "c/__init__.py": "",
            "c/leaf.py": "import os\n",
        },
    )


def test_the_quad_il_package_has_no_cycle_between_its_subpackages() -> None:
    edges = scan_edges(PACKAGE)
    assert find_cycles(edges) == []
    # The scan sees the package's real layering (a sanity check that it finds edges at all).
    assert any(e.src == "learning" and e.dst == "data" for e in edges)
    assert not any(e.src == "learning" and e.dst == "imitation" for e in edges)


def test_make_lint_runs_the_checker_as_a_script_and_it_passes() -> None:
    assert "tools/import_cycles.py" in (ROOT / "scripts" / "lint.sh").read_text()
    proc = subprocess.run([sys.executable, str(CHECKER)], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert "no cycle" in proc.stdout


def test_a_package_without_a_cycle_passes(tmp_path: Path) -> None:
    pkg = _synthetic(tmp_path, "")
    edges = {(e.src, e.dst) for e in scan_edges(pkg)}
    # absolute, relative (`from ..m`) and dotted imports are all seen
    assert edges == {("a", "b"), ("b", "c"), ("b", "m")}
    assert main([str(pkg)]) == 0


def test_a_cycle_hidden_in_a_function_local_import_is_found_and_named(tmp_path: Path, capsys) -> None:
    pkg = _synthetic(tmp_path, "    from pkg.a.core import something  # noqa\n")
    assert find_cycles(scan_edges(pkg)) == [["a", "b"]]
    assert main([str(pkg)]) == 1
    err = capsys.readouterr().err
    assert "import cycle between pkg.a, pkg.b" in err
    assert "b -> a  (b/helper.py:6)" in err
    assert "a -> b  (a/core.py:1)" in err


def test_a_cycle_through_three_units_and_a_relative_import_is_one_component(tmp_path: Path) -> None:
    pkg = _synthetic(tmp_path, "")
    (pkg / "c" / "leaf.py").write_text("from ..a import core\n")  # c -> a closes a -> b -> c -> a
    assert find_cycles(scan_edges(pkg)) == [["a", "b", "c"]]


def test_the_checker_exits_1_from_the_command_line_on_a_cycle(tmp_path: Path) -> None:
    pkg = _synthetic(tmp_path, "    import pkg.a\n")
    proc = subprocess.run(
        [sys.executable, str(CHECKER), str(pkg)], capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == 1
    assert "import cycle between pkg.a, pkg.b" in proc.stderr


def test_a_file_that_does_not_parse_is_named_with_exit_2(tmp_path: Path, capsys) -> None:
    pkg = _synthetic(tmp_path, "")
    (pkg / "c" / "broken.py").write_text("def (:\n")
    assert main([str(pkg)]) == 2
    assert "broken.py" in capsys.readouterr().err
