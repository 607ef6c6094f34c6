"""docs/RESULTS.md holds current results only (issue 31): at most 300 lines, the history in docs/notebook/.

Also checks that every relative Markdown link in RESULTS.md and in the notebook resolves, so moving a stretch
of history to the notebook cannot leave a dangling link behind.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "docs" / "RESULTS.md"
NOTEBOOK = ROOT / "docs" / "notebook"
MAX_RESULTS_LINES = 300

LINK = re.compile(r"\]\(([^)\s]+)\)")


def line_count(path: Path) -> int:
    return len(path.read_text().splitlines())


def test_results_has_at_most_300_lines() -> None:
    n = line_count(RESULTS)
    assert n <= MAX_RESULTS_LINES, (
        f"{RESULTS.relative_to(ROOT)} has {n} lines, more than {MAX_RESULTS_LINES}: keep the current result "
        "of each component there and move how it was found, unchanged, to a file in docs/notebook/"
    )


def test_the_size_check_counts_lines(tmp_path: Path) -> None:
    # The check can fail: a page one line over the limit is counted as such.
    long = tmp_path / "RESULTS.md"
    long.write_text("x\n" * (MAX_RESULTS_LINES + 1))
    assert line_count(long) == MAX_RESULTS_LINES + 1 > MAX_RESULTS_LINES


def relative_links(path: Path) -> list[str]:
    out = []
    in_code = False
    for line in path.read_text().splitlines():
        if line.startswith("```"):
            in_code = not in_code
            continue
        if in_code:
            continue
        for target in LINK.findall(line):
            if not re.match(r"^[a-z]+:", target) and not target.startswith("#"):
                out.append(target.split("#", 1)[0])
    return out


DOCS = [RESULTS, *sorted(NOTEBOOK.glob("*.md"))]


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(doc: Path) -> None:
    missing = [t for t in relative_links(doc) if not (doc.parent / t).exists()]
    assert not missing, f"{doc.relative_to(ROOT)} links to files that do not exist: {missing}"


def test_results_links_every_notebook_file() -> None:
    linked = {(RESULTS.parent / t).resolve() for t in relative_links(RESULTS)}
    unlinked = [p.name for p in sorted(NOTEBOOK.glob("*.md")) if p.resolve() not in linked]
    assert not unlinked, f"docs/RESULTS.md does not point to these notebook files: {unlinked}"


def test_a_dangling_link_is_found(tmp_path: Path) -> None:
    doc = tmp_path / "page.md"
    (tmp_path / "there.md").write_text("")
    doc.write_text("[a](there.md) [b](notebook/gone.md#part) [c](https://example.org) [d](#top)\n")
    assert [t for t in relative_links(doc) if not (doc.parent / t).exists()] == ["notebook/gone.md"]
