"""Every command-line tool's `--help` shows every option's default (issue 31).

Each CLI module of quad_il (learning, imitation, data, evaluation, collection, manager, tools) and of
training_only/ is found by its source (a module that builds an argparse parser). Its `main` is called with
argparse's parsing replaced by a capture, so the parser is built exactly as the command builds it and nothing
runs. Every option (and optional positional) whose default is not None must have help text that shows the
default; a module with a parser this test does not reach fails too (add its argv to ARGVS).
"""

from __future__ import annotations

import argparse
import ast
import importlib
import importlib.util
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "src" / "quad_il" / "src" / "quad_il"
SUBPACKAGES = ("learning", "imitation", "data", "evaluation", "collection", "manager", "tools", "engine")
# The argv lists that reach each parser of a module (default: [[]]; main dispatches on its argv first).
ARGVS = {
    "quad_il.imitation.convert": [[], ["train"]],
    "quad_il.learning.scale_bench": [[], ["worker"]],
    "quad_il.imitation.wait_peers": [["--help"]],  # the options before `--`, the command after it
}


def _parser_calls(path: Path) -> int:
    """How many parsers the source builds: ArgumentParser(...) and subparsers' add_parser(...) calls."""
    n = 0
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Call):
            f = node.func
            name = f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else ""
            n += name in ("ArgumentParser", "add_parser")
    return n


def _cli_sources() -> list[tuple[str, Path]]:
    found = []
    for sub in SUBPACKAGES:
        for path in sorted((PACKAGE / sub).glob("*.py")):
            if _parser_calls(path):
                found.append((f"quad_il.{sub}.{path.stem}", path))
    for path in sorted((ROOT / "training_only").glob("*.py")):
        found.append((f"training_only/{path.name}", path))
    return found


CLI_SOURCES = _cli_sources()


def _load(name: str, path: Path) -> ModuleType:
    if name.startswith("quad_il."):
        return importlib.import_module(name)
    spec = importlib.util.spec_from_file_location(f"_cli_{path.stem}", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


class _Captured(Exception):
    def __init__(self, parser: argparse.ArgumentParser) -> None:
        super().__init__(parser.prog)
        self.parser = parser


def _capture(main, argv: list[str], monkeypatch: pytest.MonkeyPatch) -> argparse.ArgumentParser:
    def stop(self: argparse.ArgumentParser, args=None, namespace=None):
        raise _Captured(self)

    with monkeypatch.context() as m:
        m.setattr(argparse.ArgumentParser, "parse_known_args", stop)
        with pytest.raises(_Captured) as caught:
            main(argv)
    return caught.value.parser


def _with_subparsers(parser: argparse.ArgumentParser) -> list[argparse.ArgumentParser]:
    out = [parser]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in dict.fromkeys(action.choices.values()):
                out.extend(_with_subparsers(sub))
    return out


def _missing_defaults(parser: argparse.ArgumentParser) -> list[str]:
    """The options of one parser whose rendered help does not show their non-None default."""
    bad = []
    formatter = parser._get_formatter()
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction | argparse._VersionAction | argparse._SubParsersAction):
            continue
        if action.default is None or action.default is argparse.SUPPRESS:
            continue
        name = "/".join(action.option_strings) or action.dest
        if not action.help:
            bad.append(f"{name} (default {action.default!r}) has no help text, so --help cannot show it")
            continue
        text = " ".join(formatter._expand_help(action).split())
        shown = " ".join(str(action.default).split())
        if f"default: {shown})" not in text and f"default {shown}" not in text:
            bad.append(f"{name}: help {text!r} does not show its default {shown!r}")
    return bad


def test_every_cli_module_is_found() -> None:
    names = {n for n, _ in CLI_SOURCES}
    # A sample across the subpackages and training_only/ (the discovery itself must not come back empty).
    for expected in (
        "quad_il.learning.train",
        "quad_il.imitation.convert",
        "quad_il.evaluation.run_eval",
        "quad_il.manager.cli",
        "quad_il.tools.import_cycles",
        "training_only/evaluate_policy.py",
    ):
        assert expected in names


@pytest.mark.parametrize("name,path", CLI_SOURCES, ids=[n for n, _ in CLI_SOURCES])
def test_help_shows_every_default(name: str, path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    module = _load(name, path)
    # A command's module has main(argv); a command line kept apart from its ROS node has parse_args(argv).
    main = getattr(module, "main", None) or module.parse_args
    parsers: dict[int, argparse.ArgumentParser] = {}
    for argv in ARGVS.get(name, [[]]):
        for p in _with_subparsers(_capture(main, argv, monkeypatch)):
            parsers[id(p)] = p
    if name.startswith("quad_il."):
        assert len(parsers) == _parser_calls(path), (
            f"{name} builds {_parser_calls(path)} parsers, the test reached {len(parsers)}: "
            "add the argv that reaches the others to ARGVS"
        )
    problems = [f"{p.prog}: {msg}" for p in parsers.values() for msg in _missing_defaults(p)]
    assert not problems, "\n".join(problems)


def test_the_training_script_runs_from_the_installed_package_and_lists_its_defaults() -> None:
    # -I: no PYTHONPATH and no script directory on sys.path; quad_il comes from the venv's editable install.
    proc = subprocess.run(
        [sys.executable, "-I", str(ROOT / "training_only" / "train_on_cpp_datasets.py"), "--help"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    text = " ".join(proc.stdout.split())
    assert "--resume" in text and "(default: False)" in text
    assert "--config CONFIG YAML config; repeat to layer (later wins) (default: [])" in text
