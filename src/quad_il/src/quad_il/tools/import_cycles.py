"""Fail on an import cycle between the subpackages of a Python package (issue 31; STYLE.md item 16).

Every module of the package is parsed with `ast` (nothing is imported or run) and every `import` statement is
counted, wherever it stands: at module level, inside a function, under `if TYPE_CHECKING:`. A cycle hidden in
a function-local import is still a cycle of the design, so it counts. Units are the package's direct children:
a subpackage (`quad_il.learning`) or a top-level module (`quad_il.lockstep`). An edge A -> B exists when a
module of A imports anything of B; the cycles are the strongly connected components of that graph with more
than one unit. For each one the report names the units and, per edge, the first importing file and line.

    python -m quad_il.tools.import_cycles [PACKAGE_DIR]      # default: the quad_il package itself

Exit status 0 without a cycle, 1 naming each cycle, 2 on a file that does not parse.
"""

from __future__ import annotations

import argparse
import ast
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class Edge:
    """One dependency between two units and the first import that makes it (path relative to the package)."""

    src: str
    dst: str
    path: str
    line: int


class ImportScanError(ValueError):
    """A module of the package does not parse."""


def _module_name(pkg_dir: Path, path: Path) -> str:
    rel = path.relative_to(pkg_dir).with_suffix("")
    parts = [pkg_dir.name, *rel.parts]
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _imported_modules(tree: ast.AST, module: str, is_package: bool) -> Iterator[tuple[str, int]]:
    """Absolute names imported by a module (`from X import y` yields X.y as well as X: y may be a module)."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, node.lineno
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                # Relative import: level 1 is the current package (the module itself when it is __init__).
                base = module.split(".") if is_package else module.split(".")[:-1]
                base = base[: len(base) - (node.level - 1)] if node.level > 1 else base
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            yield target, node.lineno
            for alias in node.names:
                if alias.name != "*":
                    yield f"{target}.{alias.name}", node.lineno


def scan_edges(pkg_dir: Path) -> list[Edge]:
    """Every unit-to-unit edge of the package in `pkg_dir` (one Edge per pair: its first import)."""
    pkg_dir = Path(pkg_dir).resolve()
    if not (pkg_dir / "__init__.py").is_file():
        raise ImportScanError(f"{pkg_dir} is not a Python package (no __init__.py)")
    root = pkg_dir.name
    units = {p.name for p in pkg_dir.iterdir() if p.is_dir() and (p / "__init__.py").is_file()}
    units |= {p.stem for p in pkg_dir.glob("*.py") if p.name != "__init__.py"}
    first: dict[tuple[str, str], Edge] = {}
    for path in sorted(pkg_dir.rglob("*.py")):
        rel = path.relative_to(pkg_dir)
        if len(rel.parts) == 1 and rel.name == "__init__.py":
            continue  # the package's own __init__ belongs to no unit
        src_unit = rel.parts[0] if len(rel.parts) > 1 else rel.stem
        module = _module_name(pkg_dir, path)
        try:
            tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        except (SyntaxError, UnicodeDecodeError) as e:
            raise ImportScanError(f"cannot parse {path}: {e}") from e
        for name, line in _imported_modules(tree, module, path.name == "__init__.py"):
            parts = name.split(".")
            if len(parts) < 2 or parts[0] != root or parts[1] not in units or parts[1] == src_unit:
                continue
            key = (src_unit, parts[1])
            if key not in first or (str(rel), line) < (first[key].path, first[key].line):
                first[key] = Edge(src_unit, parts[1], str(rel), line)
    return sorted(first.values(), key=lambda e: (e.src, e.dst))


def find_cycles(edges: list[Edge]) -> list[list[str]]:
    """The strongly connected components with more than one unit (Tarjan), each sorted, in sorted order."""
    graph: dict[str, list[str]] = {}
    for e in edges:
        graph.setdefault(e.src, []).append(e.dst)
        graph.setdefault(e.dst, [])
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[list[str]] = []

    def visit(v: str) -> None:  # recursion depth is bounded by the number of units (a dozen)
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                components.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(components)


def describe_cycles(pkg_name: str, edges: list[Edge], cycles: list[list[str]]) -> list[str]:
    lines = []
    for comp in cycles:
        members = set(comp)
        lines.append(f"import cycle between {', '.join(f'{pkg_name}.{u}' for u in comp)}:")
        for e in edges:
            if e.src in members and e.dst in members:
                lines.append(f"  {e.src} -> {e.dst}  ({e.path}:{e.line})")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.splitlines()[0], formatter_class=argparse.ArgumentDefaultsHelpFormatter
    )
    ap.add_argument(
        "package_dir",
        nargs="?",
        default=str(Path(__file__).resolve().parents[1]),
        help="directory of the package to check",
    )
    args = ap.parse_args(argv)
    pkg_dir = Path(args.package_dir).resolve()
    try:
        edges = scan_edges(pkg_dir)
    except ImportScanError as e:
        print(f"import_cycles: {e}", file=sys.stderr)
        return 2
    cycles = find_cycles(edges)
    if cycles:
        for line in describe_cycles(pkg_dir.name, edges, cycles):
            print(line, file=sys.stderr)
        return 1
    units = sorted({e.src for e in edges} | {e.dst for e in edges})
    print(f"import_cycles: no cycle between the {len(units)} connected units of {pkg_dir.name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
