"""Parameter tables (paper tables 7-8) as Markdown, from what ``gcnt params`` counts.

``gcnt.commands.params.count_table(preset)`` gives one row per (world, method) (``actor``,
``critic``, ``total`` and the paper's count when known). The Markdown names methods by their
display names (:mod:`gcnt.analysis.names`; a style's ``names`` over the defaults), the rows by
their ids.
"""

from __future__ import annotations

from typing import Any

from gcnt.analysis.plotting import FigureStyle

PRESETS = {"smpenv": "Table 7 (SMPENV, TD3)", "unimal": "Table 8 (UNIMAL, PPO)"}


def _fmt(v: Any) -> str:
    if isinstance(v, bool) or v is None:
        return "–"
    if isinstance(v, int):
        return f"{v:,}"
    if isinstance(v, float):
        return f"{v:,.3g}"
    return str(v)


def rows_to_markdown(rows: list[dict[str, Any]], style: FigureStyle | None = None) -> str:
    """A Markdown table of ``rows``; with ``style``, the ``method`` column by display names."""
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
        shown = {**r, "method": style.name(r["method"])} if style and "method" in r else r
        lines.append("| " + " | ".join(_fmt(shown.get(c)) for c in cols) + " |")
    return "\n".join(lines)


def params_table(preset: str, style: FigureStyle | None = None) -> tuple[str, list[dict[str, Any]]]:
    """(Markdown, rows) of the parameter counts at ``preset``; methods by their display names
    in the Markdown, by their ids in the rows."""
    from gcnt.analysis.params import count_table

    rows = count_table(preset)
    return rows_to_markdown(rows, style or FigureStyle()), rows


def parameter_tables(
    presets: tuple[str, ...] = tuple(PRESETS), style: FigureStyle | None = None
) -> tuple[str, dict[str, Any]]:
    """Markdown of tables 7-8 and the rows behind them."""
    parts, data = [], {}
    for preset in presets:
        md, rows = params_table(preset, style)
        parts += [f"### {PRESETS.get(preset, preset)}: parameters per method\n", md, ""]
        data[preset] = rows
    return "\n".join(parts), data
