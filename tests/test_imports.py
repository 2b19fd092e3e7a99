"""The package's imports form layers (DESIGN.md): every import, function-level ones included, goes to the same part
or a lower floor, and no two parts import each other, directly or through others."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "cosmos_lite"
# From the ground up; a part may import its own floor's other parts or any lower floor.
FLOORS = [
    {"errors", "log", "config", "files", "text"},
    {"video", "sim"},
    {"core"},
    {"curation", "tokenizers", "guardrails"},
    {"models"},
    {"eval"},
    {"cli", "demo", "probe", "train"},
]


def import_graph(pkg: Path = PACKAGE) -> dict[str, set[str]]:
    """Edges between the package's parts (subpackages and top-level modules), from every import statement."""
    edges: dict[str, set[str]] = {}
    for f in pkg.rglob("*.py"):
        rel = f.relative_to(pkg).parts
        part = rel[0] if len(rel) > 1 else rel[0][:-3]
        here = [pkg.name, *rel[:-1]]  # the package a relative import starts from
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.ImportFrom):
                base = here[: len(here) - node.level + 1] if node.level else []
                names = [base + node.module.split(".")] if node.module else [base + [a.name] for a in node.names]
            elif isinstance(node, ast.Import):
                names = [a.name.split(".") for a in node.names]
            else:
                continue
            for name in names:
                if len(name) > 1 and name[0] == pkg.name and name[1] != part:
                    edges.setdefault(part, set()).add(name[1])
    return edges


def cycles(edges: dict[str, set[str]]) -> list[tuple[str, str]]:
    """Pairs of parts that reach each other."""
    def reaches(a: str) -> set[str]:
        seen, todo = set(), [a]
        while todo:
            for b in edges.get(todo.pop(), ()):
                if b not in seen:
                    seen.add(b)
                    todo.append(b)
        return seen

    reach = {a: reaches(a) for a in edges}
    return sorted((a, b) for a in reach for b in reach[a] if a < b and a in reach.get(b, ()))


def floor(part: str) -> int:
    return next(i for i, parts in enumerate(FLOORS) if part in parts)


def test_the_walk_finds_function_level_and_relative_imports(tmp_path):
    pkg = tmp_path / "cosmos_lite"
    (pkg / "a").mkdir(parents=True)
    (pkg / "a" / "m.py").write_text("def f():\n    from ..b.x import y\n    import cosmos_lite.c\n")
    (pkg / "b").mkdir()
    (pkg / "b" / "x.py").write_text("from .. import a\n")
    graph = import_graph(pkg)
    assert graph == {"a": {"b", "c"}, "b": {"a"}} and cycles(graph) == [("a", "b")]


def test_no_import_cycle_between_parts():
    assert cycles(import_graph()) == []


def test_every_import_goes_to_the_same_or_a_lower_floor():
    graph = import_graph()
    unplaced = sorted(p for p in set(graph) | set().union(*graph.values()) if not any(p in f for f in FLOORS))
    assert unplaced == [], f"place these parts in FLOORS (and DESIGN.md): {unplaced}"
    upward = sorted(f"{a} -> {b}" for a, bs in graph.items() for b in bs if floor(b) > floor(a))
    assert upward == []
