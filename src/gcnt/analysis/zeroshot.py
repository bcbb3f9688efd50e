"""Zero-shot table (paper table 1): return on unseen test robots, per robot and method.

Per run (one seed) and test robot, the evaluation with the most environment steps that covers the
robot gives that seed's mean return; between equals, one made with the run's recipe protocol
(``eval.deterministic``), then the one with the most episodes, then a test evaluation (``gcnt eval
--robots test``). A cell is the mean ± standard error of those per-seed means over seeds, and
says which protocol (deterministic or sampled actions, episodes per robot) they come from. The
best mean of a row is in bold where its mean ± 1 s.e. lies above the runner-up's (not where
they overlap). Written as Markdown and LaTeX (methods and tasks by their display names) and JSON
(by their ids). A column is one experiment's seeds (:func:`gcnt.analysis.groups.comparable_groups`).
"""

from __future__ import annotations

import json
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from gcnt.analysis.groups import RunGroup, comparable_groups
from gcnt.analysis.intervals import separated_best, stderr_text
from gcnt.analysis.plotting import FigureStyle
from gcnt.analysis.runs import (
    AnalysisError,
    EvalRecord,
    Run,
    mean_stderr,
    protocols_text,
    score,
)
from gcnt.files import write_text


def seed_score(
    evals: Sequence[EvalRecord],
    robot: str,
    label: str | None = None,
    deterministic: bool | None = None,
    run: Run | None = None,
) -> tuple[float, EvalRecord] | None:
    """A run's mean return on ``robot`` from its latest, largest evaluation of it (``evals``: the
    run's evaluations, ``Run.evals()``); between equal steps, one with ``deterministic`` actions
    as asked (the run's recipe protocol) wins, then the one with more episodes, then a test
    evaluation (``gcnt eval --robots test``) over the one made during training. ``label``: only
    evaluations of that set (with ``run``: also the part of a larger evaluation it names)."""

    def named(e: EvalRecord) -> bool:
        if label is None or e.matches(label):
            return True
        return run is not None and robot in run.set_robots(e, label)

    evals = [e for e in evals if robot in e.robots and named(e)]
    if not evals:
        return None
    best = max(
        evals,
        key=lambda e: (
            e.env_steps,
            deterministic is not None and e.deterministic == deterministic,
            e.episodes,
            _test_eval_rank(e),
        ),
    )
    return score(best.robots[robot]), best


def _test_eval_rank(e: EvalRecord) -> int:
    """2 for a ``gcnt eval --robots test`` evaluation, 1 for another evaluation of the test
    robots (training's own, when its one robot spec is a ``Benchmark:test`` split), else 0."""
    if e.label and (e.specs == ["test"] or e.label == "test"):
        return 2
    return int(e.matches("test"))


def test_robots(runs: Sequence[Run]) -> list[str]:
    """The runs' test robots (from their recipes; else robots evaluated but not trained on)."""
    names = list(dict.fromkeys(n for r in runs for n in r.test_robot_names()))
    if names:
        return names
    trained = {n for r in runs for n in r.train_robot_names()}
    return list(
        dict.fromkeys(n for r in runs for e in r.evals() for n in e.robots if n not in trained)
    )


def zero_shot_table(
    runs: Sequence[Run], robots: Sequence[str] | None = None, label: str | None = None
) -> dict[str, Any]:
    """``{task: {"robots": [...], "methods": [...], "cells": {robot: {method: cell}},
    "best": {robot: method or None}}}`` (``best``: the method shown in bold, :func:`bold_method`);
    a cell holds mean, stderr, seeds and the per-seed means."""
    by_task: dict[str, list[RunGroup]] = defaultdict(list)
    for group in comparable_groups(runs):  # the seeds of one experiment each: a column
        by_task[group.task].append(group)
    out: dict[str, Any] = {}
    evals = {r.path: r.evals() for r in runs}  # each run's eval files, read once
    for task, groups in by_task.items():
        members = [r for g in groups for r in g.runs]
        names = list(robots) if robots else test_robots(members)
        methods = [g.label for g in groups]
        cells: dict[str, dict[str, Any]] = {}
        for robot in names:
            row = {}
            for m, group in zip(methods, groups, strict=True):
                per_seed = {}
                sources, protocols = [], []
                for r in group.runs:
                    got = seed_score(evals[r.path], robot, label, r.eval_deterministic, r)
                    if got is not None:
                        per_seed[str(r.seed)] = got[0]
                        sources.append(str(got[1].path))
                        protocols.append(got[1].protocol)
                if per_seed:
                    mean, se = mean_stderr(list(per_seed.values()))
                    row[m] = {
                        "mean": mean,
                        "stderr": se,
                        "seeds": len(per_seed),
                        "per_seed": per_seed,
                        "sources": sources,
                        "protocol": protocols_text(protocols),
                    }
            if row:
                cells[robot] = row
        if not cells:
            continue
        # the tables' bold: a best whose interval is separated from the runner-up's, else null
        best = {robot: bold_method(row) for robot, row in cells.items()}
        protocol = protocols_text(c["protocol"] for row in cells.values() for c in row.values())
        out[task] = {
            "robots": list(cells),
            "methods": methods,
            "cells": cells,
            "best": best,
            "protocol": protocol,
        }
    if not out:
        raise AnalysisError(
            "no evaluation of a test robot in these runs: run `gcnt eval RUN_DIR --robots test` "
            "(or `gcnt zeroshot DIR --evaluate`, or `gcnt sweep ... --eval test`) first"
        )
    return out


def shown_runs(table: dict[str, Any], runs: Sequence[Run]) -> list[Run]:
    """The runs of ``runs`` whose evaluations give a cell of ``table`` (what its caption
    counts): a run without a test robot's evaluation is left out of the table, and of that."""
    folders = {
        Path(source).parent
        for t in table.values()
        for row in t["cells"].values()
        for cell in row.values()
        for source in cell["sources"]
    }
    return [r for r in runs if r.path / "eval" in folders]


def _fmt(cell: dict[str, Any] | None, bold: bool, pm: str = "±", mark: str = "**{}**") -> str:
    if cell is None:
        return "–"
    se = cell["stderr"]
    text = f"{cell['mean']:.1f} {pm} {se:.1f}" if se == se else f"{cell['mean']:.1f}"
    return mark.format(text) if bold else text


def bold_method(row: dict[str, dict[str, Any]]) -> str | None:
    """The method of a row shown in bold: the best mean, when its mean ± 1 s.e. lies wholly
    above the runner-up's (:func:`gcnt.analysis.intervals.separated_best`); else none."""
    return separated_best(
        {m: (c["mean"], c["mean"] - c["stderr"], c["mean"] + c["stderr"]) for m, c in row.items()}
    )


def _caption(t: dict[str, Any]) -> tuple[str, str]:
    """(what the cells are and what bold means, the evaluation protocol) of a task's table."""
    seeds = [c["seeds"] for row in t["cells"].values() for c in row.values()]
    return (
        f"Cells: {stderr_text(seeds)}. Bold: a row's best mean whose interval lies above the "
        "runner-up's (none where they overlap).",
        f"Evaluation: {t.get('protocol', 'not recorded')}.",
    )


def to_markdown(table: dict[str, Any], style: FigureStyle | None = None) -> str:
    """One Markdown table per task: a row per test robot, a column per method (display names,
    ``style``'s over the defaults), the interval and its n stated, separated bests in bold."""
    style = style or FigureStyle()
    parts = []
    for task, t in table.items():
        methods = t["methods"]
        cells_text, protocol = _caption(t)
        parts += [f"### {style.name(task)}\n", f"{cells_text}\n", f"{protocol}\n"]
        parts.append("| robot | " + " | ".join(style.name(m) for m in methods) + " |")
        parts.append("|---|" + "---:|" * len(methods))
        for robot in t["robots"]:
            row = t["cells"][robot]
            bold = bold_method(row)
            cells = [_fmt(row.get(m), bold == m) for m in methods]
            parts.append(f"| {robot} | " + " | ".join(cells) + " |")
        parts.append("")
    return "\n".join(parts)


_TEX = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_",
        "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}",
        "±": r"$\pm$", "–": "--", "…": r"\dots{}"}  # fmt: skip


def tex_text(text: str) -> str:
    """``text`` with LaTeX's special characters escaped."""
    return "".join(_TEX.get(c, c) for c in str(text))


def to_latex(table: dict[str, Any], style: FigureStyle | None = None) -> str:
    """One LaTeX table (``booktabs``) per task, as :func:`to_markdown`: the caption names the
    interval, its n, what bold means and the evaluation protocol."""
    style = style or FigureStyle()
    parts = ["% needs \\usepackage{booktabs}"]
    for task, t in table.items():
        methods = t["methods"]
        cells_text, protocol = _caption(t)
        caption = f"Zero-shot return on the {style.name(task)} test robots. {cells_text} {protocol}"
        parts += [
            r"\begin{table}[t]",
            r"\centering",
            rf"\caption{{{tex_text(caption)}}}",
            rf"\begin{{tabular}}{{l{'r' * len(methods)}}}",
            r"\toprule",
            " & ".join(["Robot", *(tex_text(style.name(m)) for m in methods)]) + r" \\",
            r"\midrule",
        ]
        for robot in t["robots"]:
            row = t["cells"][robot]
            bold = bold_method(row)
            cells = [
                _fmt(row.get(m), bold == m, pm=r"$\pm$", mark=r"\textbf{{{}}}").replace("–", "--")
                for m in methods
            ]
            parts.append(" & ".join([tex_text(robot), *cells]) + r" \\")
        parts += [r"\bottomrule", r"\end{tabular}", r"\end{table}", ""]
    return "\n".join(parts)


def write(
    table: dict[str, Any],
    out: Path,
    stem: str = "zeroshot",
    style: FigureStyle | None = None,
    caption: str | None = None,
) -> tuple[Path, Path, Path]:
    """``<stem>.md``, ``<stem>.tex`` and ``<stem>.json`` (strict JSON: a missing standard error
    is ``null``; methods by their ids). ``caption`` (the code of the runs,
    :func:`gcnt.run.provenance.caption`) ends the Markdown and the LaTeX (as a comment)."""
    from gcnt.run.directory import strict_json

    out.mkdir(parents=True, exist_ok=True)
    md, tex, js = out / f"{stem}.md", out / f"{stem}.tex", out / f"{stem}.json"
    write_text(md, to_markdown(table, style) + (f"\n_{caption}_\n" if caption else ""))
    write_text(tex, to_latex(table, style) + (f"% {caption}\n" if caption else ""))
    write_text(js, json.dumps(strict_json(table), indent=1, allow_nan=False))
    return md, tex, js
