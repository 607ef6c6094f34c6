"""Summarise JUnit XML test results (gtest, rostest, pytest) into one closing line.

Usage: python -m quad_il.tools.test_summary RESULTS_DIR [RESULTS_DIR ...]

Prints one line per failed test case, one line per suite file, then `N passed, N failed, N skipped`.
Exits 1 if any case failed or errored, 2 if no test case was found at all.
"""

from __future__ import annotations

import argparse
import sys
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

from quad_il.tools.cli import HelpFormatter


@dataclass
class Summary:
    passed: int = 0
    failed: int = 0
    skipped: int = 0
    failures: list[str] = field(default_factory=list)

    @property
    def total(self) -> int:
        return self.passed + self.failed + self.skipped


def summarise_file(path: Path) -> Summary:
    """Count the test cases of one JUnit XML file; an unreadable file counts as one failure."""
    s = Summary()
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        s.failed = 1
        s.failures.append(f"{path}: unreadable result file ({exc})")
        return s
    for case in root.iter("testcase"):
        name = f"{case.get('classname', '')}.{case.get('name', '')}".strip(".")
        if case.find("failure") is not None or case.find("error") is not None:
            s.failed += 1
            node = case.find("failure") if case.find("failure") is not None else case.find("error")
            msg = (node.get("message") or node.text or "").strip().splitlines()
            s.failures.append(f"{path.name}: {name}: {msg[0] if msg else 'failed'}")
        elif case.find("skipped") is not None:
            s.skipped += 1
        else:
            s.passed += 1
    # A suite that reports errors/failures without test cases (e.g. a crashed rostest) still fails.
    if s.total == 0:
        errors = int(root.get("errors", 0) or 0) + int(root.get("failures", 0) or 0)
        if errors:
            s.failed = errors
            s.failures.append(f"{path}: suite reports {errors} error(s) and no test case")
    return s


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(formatter_class=HelpFormatter, description=__doc__.splitlines()[0])
    ap.add_argument("dirs", nargs="+", type=Path, help="directories of test result XML files")
    args = ap.parse_args(argv)
    total = Summary()
    files = sorted(p for d in args.dirs if d.exists() for p in d.rglob("*.xml"))
    for f in files:
        s = summarise_file(f)
        print(f"  {f.relative_to(f.parents[1])}: {s.passed} passed, {s.failed} failed, {s.skipped} skipped")
        total.passed += s.passed
        total.failed += s.failed
        total.skipped += s.skipped
        total.failures += s.failures
    for line in total.failures:
        print(f"FAILED {line}")
    print(f"{total.passed} passed, {total.failed} failed, {total.skipped} skipped")
    if total.failed:
        return 1
    if total.total == 0:
        print("no test results found in: " + " ".join(map(str, args.dirs)), file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
