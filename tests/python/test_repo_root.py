"""The one place that finds the repository root (quad_il.tools.repo, issue 31)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from quad_il.tools.repo import ROOT_ENV, RepoRootError, repo_path, repo_root

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "src" / "quad_il" / "src" / "quad_il"


def test_without_the_variable_the_checkout_of_the_package_is_the_root(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.delenv(ROOT_ENV, raising=False)
    assert repo_root() == ROOT
    assert repo_path("config", "train.yaml") == ROOT / "config" / "train.yaml"


def test_the_variable_names_another_checkout(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "config").mkdir()
    (tmp_path / "src" / "quad_il").mkdir(parents=True)
    (tmp_path / "src" / "quad_il" / "package.xml").write_text("<package/>")
    monkeypatch.setenv(ROOT_ENV, str(tmp_path))
    assert repo_root() == tmp_path.resolve()


def test_a_variable_that_is_not_a_checkout_is_refused_naming_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv(ROOT_ENV, str(tmp_path))
    with pytest.raises(RepoRootError, match=rf"QUAD_IL_ROOT={re.escape(str(tmp_path))} is not a quad_il "):
        repo_root()


def test_no_module_searches_for_the_root_by_itself() -> None:
    """Only tools/repo.py reads QUAD_IL_ROOT or climbs from a file to the repository (parents[2] and up: the
    package's own directory, parents[1], is no root search)."""
    search = re.compile(r"__file__\)?(\.resolve\(\))?\.parents\[[2-9]\]|environ(\.get\(|\[)\"QUAD_IL_ROOT\"")
    offenders = [
        str(path.relative_to(PACKAGE))
        for path in sorted(PACKAGE.rglob("*.py"))
        if path != PACKAGE / "tools" / "repo.py" and search.search(path.read_text())
    ]
    assert offenders == []
