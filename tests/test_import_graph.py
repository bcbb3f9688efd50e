"""The import graph of ``src/gcnt`` (imports inside functions and ``TYPE_CHECKING`` blocks
counted; a package ``__init__``'s re-exports left out): no import cycle between files or between
the package's top-level parts beyond the ones still listed in :data:`KNOWN`, each to be removed
with the change that breaks it. A new cycle fails; so does a listed one that no longer exists
(its entry must go)."""

from __future__ import annotations

import ast
from pathlib import Path

SRC = Path(__file__).parents[1] / "src"

#: the cycles not yet broken (each a sorted tuple of its members): none; a cycle added to the
#: code fails the test, and so would one listed here that no longer exists
KNOWN: set[tuple[str, ...]] = set()

#: the package's top-level parts from the bottom up: a part imports only parts of lower layers
LAYERS = (
    ("files", "keys", "suggest", "bootstrap", "builtin", "data_folders", "extras"),
    ("plugins", "morphology"),
    ("envs",),
    ("nn",),
    ("recipes",),
    ("run",),  # a run as files: below training and analysis, which both read and write runs
    ("rl",),
    ("analysis", "bench", "sweep"),
    ("api", "commands"),
    ("cli",),
)


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


def _parts(edges: dict[str, set[str]]) -> dict[str, set[str]]:
    """The imports between top-level parts (``gcnt.rl.loop`` -> ``gcnt.run.lock``: rl -> run)."""
    parts: dict[str, set[str]] = {}
    for a, targets in edges.items():
        for b in targets:
            pa, pb = a.split(".")[1], b.split(".")[1]
            if pa != pb:
                parts.setdefault(pa, set()).add(pb)
    return parts


def _upward(parts: dict[str, set[str]], layers=LAYERS) -> list[str]:
    """The imports from a part to one of the same or a higher layer, and parts with no layer."""
    layer = {p: i for i, names in enumerate(layers) for p in names}
    out = [p for p in sorted({*parts, *(b for t in parts.values() for b in t)}) if p not in layer]
    for a, targets in sorted(parts.items()):
        for b in sorted(targets):
            if a in layer and b in layer and layer[b] >= layer[a]:
                out.append(f"{a} -> {b}")
    return out


def test_no_import_cycle_but_the_known_ones():
    edges = _edges(_modules())
    found = _cycles(edges) | _cycles(_parts(edges))
    # a part cycle made of a file cycle's parts is that file cycle seen from above
    assert found - KNOWN == set(), f"new import cycles: {sorted(found - KNOWN)}"
    assert KNOWN - found == set(), f"broken since (remove from KNOWN): {sorted(KNOWN - found)}"


def test_the_graph_sees_a_cycle_made_through_a_function_level_import():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert _cycles(graph) == {("a", "b", "c")}


def test_every_part_imports_only_parts_below_it():
    upward = _upward(_parts(_edges(_modules())))
    assert upward == [], f"imports that climb a layer, or parts without one (LAYERS): {upward}"


def test_the_layer_check_sees_an_import_that_climbs():
    layers = (("files",), ("run",), ("rl",))
    assert _upward({"rl": {"run", "files"}, "run": {"files"}}, layers) == []
    assert _upward({"rl": {"run"}, "run": {"rl"}}, layers) == ["run -> rl"]
    assert _upward({"new": {"files"}}, layers) == ["new"]
