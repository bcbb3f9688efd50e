"""Parameter tables (paper tables 7-8) as Markdown, from what ``gcnt params`` counts.

``gcnt.commands.params.count_table(preset)`` gives one row per method (``method``, ``actor``,
``critic`` and the paper's count when known); if that function is not there, the text that
``gcnt params --preset PRESET`` prints is kept verbatim in a code block.
"""

from __future__ import annotations

import subprocess
import sys
from typing import Any

PRESETS = {"smpenv": "Table 7 (SMPENV, TD3)", "unimal": "Table 8 (UNIMAL, PPO)"}


def _fmt(v: Any) -> str:
    if isinstance(v, bool) or v is None:
        return "–"
    if isinstance(v, int):
        return f"{v:,}"
    if isinstance(v, float):
        return f"{v:,.3g}"
    return str(v)


def rows_to_markdown(rows: list[dict[str, Any]]) -> str:
    cols = list(dict.fromkeys(k for r in rows for k in r))
    # a column empty in every row (e.g. the world of a one-world benchmark) is left out
    cols = [c for c in cols if c == "paper" or any(r.get(c) not in (None, "") for r in rows)]
    if "actor" in cols and "critic" in cols and not {"actor+critic", "total"} & set(cols):
        idx = cols.index("critic") + 1
        cols.insert(idx, "actor+critic")
        rows = [
            {**r, "actor+critic": r["actor"] + r["critic"]}
            if isinstance(r.get("actor"), int) and isinstance(r.get("critic"), int)
            else r
            for r in rows
        ]
    lines = ["| " + " | ".join(cols) + " |", "|---|" + "---:|" * (len(cols) - 1)]
    for r in rows:
        lines.append("| " + " | ".join(_fmt(r.get(c)) for c in cols) + " |")
    return "\n".join(lines)


def params_table(preset: str) -> tuple[str, list[dict[str, Any]] | None]:
    """(Markdown, rows or None) of the parameter counts at ``preset``."""
    try:
        from gcnt.commands.params import count_table
    except ImportError:
        count_table = None
    if count_table is not None:
        try:
            rows = count_table(preset)
        except TypeError:
            rows = None
        if isinstance(rows, list) and rows and all(isinstance(r, dict) for r in rows):
            return rows_to_markdown(rows), rows
    text = subprocess.run(
        [sys.executable, "-m", "gcnt.cli", "params", "--preset", preset],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    return f"```\n{text.rstrip()}\n```", None


def parameter_tables(presets: tuple[str, ...] = tuple(PRESETS)) -> tuple[str, dict[str, Any]]:
    """Markdown of tables 7-8 and the rows behind them."""
    parts, data = [], {}
    for preset in presets:
        md, rows = params_table(preset)
        parts += [f"### {PRESETS.get(preset, preset)}: parameters per method\n", md, ""]
        data[preset] = rows
    return "\n".join(parts), data
