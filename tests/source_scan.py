"""What the source-scan tests share: the calls of gcnt's sources a classifier picks out, each with
its enclosing function, and the ones not in an allowed list."""

from __future__ import annotations

import ast
from collections.abc import Callable, Collection
from pathlib import Path

SRC = Path(__file__).parents[1] / "src" / "gcnt"

#: a call -> what it does to a file ("open", "write_text", ...), or None for the calls of no interest
Classifier = Callable[[ast.Call], "str | None"]


def calls(tree: ast.AST, classify: Classifier) -> list[tuple[str, str, int]]:
    """(enclosing function, what the call does, line) of each call ``classify`` names."""
    found = []

    def visit(node: ast.AST, func: str) -> None:
        for child in ast.iter_child_nodes(node):
            name = child.name if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef) else func
            if isinstance(child, ast.Call):
                call = classify(child)
                if call is not None:
                    found.append((name, call, child.lineno))
            visit(child, name)

    visit(tree, "<module>")
    return found


def unguarded(classify: Classifier, allowed: Collection[tuple[str, str, str]]) -> list[str]:
    """``file:line function: call`` of each classified call in gcnt's sources (``files.py``, the
    guarded module itself, left out) that ``allowed`` does not list."""
    out = []
    for path in sorted(SRC.rglob("*.py")):
        rel = path.relative_to(SRC).as_posix()
        if rel == "files.py":
            continue
        for func, call, line in calls(ast.parse(path.read_text(), rel), classify):
            if (rel, func, call) not in allowed:
                out.append(f"{rel}:{line} {func}: {call}")
    return out


def mode(node: ast.Call, index: int) -> str | None:
    """The file mode a call gives as its ``index``-th argument or ``mode=``, when a literal."""
    args = [*node.args[index : index + 1], *(k.value for k in node.keywords if k.arg == "mode")]
    for a in args:
        if isinstance(a, ast.Constant) and isinstance(a.value, str):
            return a.value
    return None
