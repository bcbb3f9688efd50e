"""The import graph of ``src/gcnt`` (imports inside functions and ``TYPE_CHECKING`` blocks
counted; a package ``__init__``'s re-exports left out): no import cycle between files or between
the package's top-level parts beyond the ones still listed in :data:`KNOWN`, each to be removed
with the change that breaks it. A new cycle fails; so does a listed one that no longer exists
(its entry must go)."""

from __future__ import annotations

import ast
from pathlib import Path

SRC = Path(__file__).parents[1] / "src"

#: the cycles not yet broken (each a sorted tuple of its members): the robot catalogues and the
#: imported UNIMAL set, and gcnt.rl against gcnt.run_data (the run's reader, which reads
#: metrics and checkpoints through gcnt.rl while gcnt.rl's fine-tuning reads a source run
#: through it)
KNOWN = {
    (
        "gcnt.morphology.catalogues",
        "gcnt.morphology.unimal.catalogue",
        "gcnt.morphology.unimal.imported",
    ),
    ("rl", "run_data"),
}


def _modules() -> dict[str, Path]:
    out = {}
    for p in (SRC / "gcnt").rglob("*.py"):
        parts = p.relative_to(SRC).with_suffix("").parts
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = p
    return out


def _edges(mods: dict[str, Path]) -> dict[str, set[str]]:
    edges: dict[str, set[str]] = {}
    for name, path in mods.items():
        if path.name == "__init__.py":
            continue
        package = name.rpartition(".")[0]
        found = set()
        for node in ast.walk(ast.parse(path.read_text())):
            targets = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    up = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join([*up, base] if base else up)
                targets = [f"{base}.{a.name}" for a in node.names] + [base]
            for t in targets:
                while t and t not in mods:
                    t = t.rpartition(".")[0]
                if t and t != name and t != "gcnt" and mods[t].name != "__init__.py":
                    found.add(t)
        edges[name] = found
    return edges


def _cycles(graph: dict[str, set[str]]) -> set[tuple[str, ...]]:
    """Strongly connected components of more than one node (Tarjan's, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: set[tuple[str, ...]] = set()
    counter = 0
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph.get(root, ()))))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on.add(root)
        while work:
            v, children = work[-1]
            w = next(children, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(graph.get(w, ())))))
                elif w in on:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                component = []
                while True:
                    w = stack.pop()
                    on.discard(w)
                    component.append(w)
                    if w == v:
                        break
                if len(component) > 1:
                    out.add(tuple(sorted(component)))
    return out


def test_no_import_cycle_but_the_known_ones():
    mods = _modules()
    edges = _edges(mods)
    files = _cycles(edges)
    parts: dict[str, set[str]] = {}
    for a, targets in edges.items():
        for b in targets:
            pa, pb = a.split(".")[1], b.split(".")[1]
            if pa != pb:
                parts.setdefault(pa, set()).add(pb)
    found = files | _cycles(parts)
    # a part cycle made of a file cycle's parts is that file cycle seen from above
    assert found - KNOWN == set(), f"new import cycles: {sorted(found - KNOWN)}"
    assert KNOWN - found == set(), f"broken since (remove from KNOWN): {sorted(KNOWN - found)}"


def test_the_graph_sees_a_cycle_made_through_a_function_level_import():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert _cycles(graph) == {("a", "b", "c")}
