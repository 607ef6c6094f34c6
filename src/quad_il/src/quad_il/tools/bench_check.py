"""Check benchmark output against the project's BENCH convention.

Every benchmark prints result lines `BENCH <name> <value> <unit>`: name in [a-z0-9_]+, value a finite
decimal number, unit a single token; nothing else may start with `BENCH`. Reads stdin (or files), echoes
the input, and exits 1 naming the first offending line, or if an `--expect` name is missing.
"""

from __future__ import annotations

import argparse
import math
import re
import sys
from dataclasses import dataclass

from quad_il.tools.cli import HelpFormatter

BENCH_RE = re.compile(r"^BENCH (?P<name>[a-z0-9_]+) (?P<value>\S+) (?P<unit>\S+)$")


class BenchFormatError(ValueError):
    """A line starting with BENCH that does not follow `BENCH <name> <value> <unit>`."""


@dataclass(frozen=True)
class BenchLine:
    name: str
    value: float
    unit: str


def parse_bench_line(line: str) -> BenchLine | None:
    """Parse one output line; None for a non-BENCH line, BenchFormatError for a malformed BENCH line."""
    line = line.rstrip("\n")
    if not line.startswith("BENCH"):
        return None
    m = BENCH_RE.match(line)
    if not m:
        raise BenchFormatError(f"malformed BENCH line (want 'BENCH <name> <value> <unit>'): {line!r}")
    try:
        value = float(m["value"])
    except ValueError:
        raise BenchFormatError(f"BENCH value is not a number: {line!r}") from None
    if not math.isfinite(value):
        raise BenchFormatError(f"BENCH value is not finite: {line!r}")
    return BenchLine(m["name"], value, m["unit"])


def format_bench_line(name: str, value: float, unit: str) -> str:
    """The one way Python benchmarks print a result (validated by parse_bench_line)."""
    line = f"BENCH {name} {value:.6g} {unit}"
    parse_bench_line(line)
    return line


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(formatter_class=HelpFormatter, description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="*", help="benchmark outputs (none: stdin)")
    ap.add_argument("--expect", action="append", default=[], help="a BENCH name that must appear")
    args = ap.parse_args(argv)
    streams = [open(f) for f in args.files] if args.files else [sys.stdin]
    seen: set[str] = set()
    for stream in streams:
        for line in stream:
            sys.stdout.write(line)
            try:
                parsed = parse_bench_line(line)
            except BenchFormatError as exc:
                print(f"bench_check: {exc}", file=sys.stderr)
                return 1
            if parsed:
                seen.add(parsed.name)
    missing = [n for n in args.expect if n not in seen]
    if missing:
        print(f"bench_check: expected BENCH name(s) missing: {', '.join(missing)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
