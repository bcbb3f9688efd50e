"""Zero-shot table (paper table 1): return on unseen test robots, per robot and method.

Per run (one seed) and test robot, the evaluation with the most environment steps that covers the
robot gives that seed's mean return; between equals, one made with the run's recipe protocol
(``eval.deterministic``), then the one with the most episodes, then a test evaluation (``gcnt eval
--robots test``). A cell is the mean ± standard error of those per-seed means over seeds, and
says which protocol (deterministic or sampled actions, episodes per robot) they come from. The
best method of each row is marked.
"""

from __future__ import annotations

import json
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from gcnt.analysis.runs import (
    AnalysisError,
    EvalRecord,
    Run,
    mean_stderr,
    method_key,
    method_labels,
    protocols_text,
    score,
)


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
    "best": {robot: method}}}``; a cell holds mean, stderr, seeds and the per-seed means."""
    labels = method_labels(runs)
    by_task: dict[str, list[Run]] = defaultdict(list)
    for r in runs:
        by_task[r.task].append(r)
    out: dict[str, Any] = {}
    evals = {r.path: r.evals() for r in runs}  # each run's eval files, read once
    for task, members in by_task.items():
        names = list(robots) if robots else test_robots(members)
        methods = sorted({labels[r.path] for r in members}, key=method_key)
        cells: dict[str, dict[str, Any]] = {}
        for robot in names:
            row = {}
            for m in methods:
                per_seed = {}
                sources, protocols = [], []
                for r in members:
                    if labels[r.path] != m:
                        continue
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
        best = {
            robot: max(row, key=lambda m, row=row: row[m]["mean"]) for robot, row in cells.items()
        }
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


def _fmt(cell: dict[str, Any] | None, bold: bool) -> str:
    if cell is None:
        return "–"
    se = cell["stderr"]
    text = f"{cell['mean']:.1f} ± {se:.1f}" if se == se else f"{cell['mean']:.1f}"
    return f"**{text}**" if bold else text


def to_markdown(table: dict[str, Any]) -> str:
    """One Markdown table per task: a row per test robot, a column per method, best in bold."""
    parts = []
    for task, t in table.items():
        methods = t["methods"]
        seeds = sorted({c["seeds"] for row in t["cells"].values() for c in row.values()})
        parts.append(f"### {task} (mean ± s.e. over {'/'.join(map(str, seeds))} seeds)\n")
        parts.append(f"Evaluation: {t.get('protocol', 'not recorded')}.\n")
        parts.append("| robot | " + " | ".join(methods) + " |")
        parts.append("|---|" + "---:|" * len(methods))
        for robot in t["robots"]:
            row = t["cells"][robot]
            cells = [_fmt(row.get(m), t["best"][robot] == m) for m in methods]
            parts.append(f"| {robot} | " + " | ".join(cells) + " |")
        parts.append("")
    return "\n".join(parts)


def write(table: dict[str, Any], out: Path, stem: str = "zeroshot") -> tuple[Path, Path]:
    """``<stem>.md`` and ``<stem>.json`` (strict JSON: a missing standard error is ``null``)."""
    from gcnt.rl.run_dir import strict_json

    out.mkdir(parents=True, exist_ok=True)
    md, js = out / f"{stem}.md", out / f"{stem}.json"
    md.write_text(to_markdown(table))
    js.write_text(json.dumps(strict_json(table), indent=1, allow_nan=False))
    return md, js
