"""Zero-shot returns on robot variant sets (paper figure 8) with intervals over seeds.

A *set* is one evaluation of each run: ``gcnt eval RUN --robots SPEC`` keeps each evaluation
under a label saying what was evaluated, and a set name is that label, that robot specification
or its split (``variants-kinematics`` for ``Unimal:variants-kinematics``). Inside an evaluation of
several specifications (training's own, of the train and the test robots), a set name selects the
robots of the specification it names (``test``: the recipe's test robots), never more. Per run,
one evaluation gives all of the set's scores: the one with the most env steps, then one made
with the recipe's protocol (``eval.deterministic``), then the most episodes, then the whole
evaluation over a part of a larger one. Each table states the protocol its numbers come from.

The aggregate of a method on a set follows rliable's recipe for few runs: each seed's aggregate
over the set's robots (the mean, or with ``iqm`` the interquartile mean), then the mean of these
per-seed aggregates, with a stratified percentile bootstrap over seeds (the seeds of each task
resampled with replacement and the mean recomputed): a 95% CI where every task has at least
:data:`~gcnt.analysis.intervals.MIN_BOOTSTRAP` (5) seeds. With fewer seeds a bootstrap is no
confidence interval (over two seeds its interval is their range at any level), so the interval is
the range of the seeds' aggregates, and is called so; one seed gives none. Each item's
``interval`` names the interval and its n. Per-robot runs (``gcnt sweep --per-robot``) of one seed are that
seed's scores together. A method's seeds are one experiment's
(:func:`gcnt.analysis.groups.comparable_groups`). Performance profiles (the fraction of seed x robot scores above each
return threshold) are offered as well.
"""

from __future__ import annotations

import json
import math
from collections import defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gcnt.analysis.groups import RunGroup, comparable_groups
from gcnt.analysis.intervals import MIN_BOOTSTRAP
from gcnt.analysis.plotting import FigureStyle
from gcnt.analysis.runs import (
    AnalysisError,
    EvalRecord,
    Run,
    method_key,
    protocols_text,
    score,
)
from gcnt.files import write_text

STATISTICS = ("mean", "iqm")


@dataclass
class SeedScores:
    """One seed's scores on a set: a run's, or the per-robot runs' of that seed together."""

    task: str
    seed: int
    #: robot -> mean return
    scores: dict[str, float] = field(default_factory=dict)
    protocols: list[str] = field(default_factory=list)
    sources: list[str] = field(default_factory=list)


def available_sets(runs: Sequence[Run]) -> list[str]:
    """Labels and robot specifications of the runs' evaluations (what ``--sets`` can name)."""
    names: list[str] = []
    for r in runs:
        for e in r.evals():
            names.append(e.label or "training")
            names += e.specs
    return list(dict.fromkeys(names))


def set_evaluation(run: Run, evals: Sequence[EvalRecord], name: str):
    """``(evaluation, robots)``: the one evaluation of ``run`` that gives its scores on set
    ``name`` and the robots of the set in it (see the module's docstring); None if none has
    it."""
    best, best_key = None, None
    for e in evals:
        robots = run.set_robots(e, name)
        if not robots:
            continue
        key = (e.env_steps, e.deterministic == run.eval_deterministic, e.episodes, e.matches(name))
        if best_key is None or key > best_key:
            best, best_key = (e, robots), key
    return best


def set_scores(
    runs: Sequence[Run], name: str, groups: Sequence[RunGroup] | None = None
) -> dict[str, list[SeedScores]]:
    """``{method: [SeedScores per seed]}`` on set ``name``, in seed order; a method is the
    seeds of one experiment per task (``groups``: :func:`comparable_groups` of ``runs``, when
    already made)."""
    units: dict[str, dict[tuple, SeedScores]] = defaultdict(dict)
    groups = comparable_groups(runs) if groups is None else groups
    for group, r in ((g, r) for g in groups for r in g.runs):
        got = set_evaluation(r, r.evals(), name)
        if got is None:
            continue
        e, robots = got
        key = (r.task, r.seed) if r.single_robot is not None else (r.task, r.seed, str(r.path))
        unit = units[group.label].setdefault(key, SeedScores(r.task, r.seed))
        unit.scores.update({robot: score(e.robots[robot]) for robot in robots})
        unit.protocols.append(e.protocol)
        unit.sources.append(str(e.path))
    return {
        m: sorted(v.values(), key=lambda u: (u.task, u.seed, u.sources)) for m, v in units.items()
    }


def aggregate(scores: Sequence[float], kind: str = "mean") -> float:
    """One seed's aggregate over a set's robots: the mean, or the interquartile mean (``iqm``:
    the mean of the middle 50%, scipy's ``trim_mean(x, 0.25)``)."""
    x = np.asarray(scores, dtype=np.float64)
    if kind == "mean":
        return float(x.mean())
    if kind == "iqm":
        from scipy.stats import trim_mean

        return float(trim_mean(x, 0.25))
    raise ValueError(f"unknown statistic {kind!r} (known: {', '.join(STATISTICS)})")


def _strata(
    per_seed: Sequence[float], strata: Sequence[str] | None
) -> tuple[np.ndarray, list[np.ndarray]]:
    """The per-seed values (float64) and their values per stratum, in first-seen order."""
    x = np.asarray(per_seed, dtype=np.float64)
    groups = np.asarray(strata if strata is not None else [""] * len(x))
    return x, [x[groups == g] for g in dict.fromkeys(groups.tolist())]


def bootstrap_ci(
    per_seed: Sequence[float],
    strata: Sequence[str] | None = None,
    confidence: float = 0.95,
    reps: int = 2000,
    seed: int = 0,
) -> tuple[float, float, float]:
    """(point, low, high): the mean of the per-seed aggregates and its stratified percentile
    bootstrap interval (the seeds of each stratum, a task, resampled with replacement, the mean
    of all recomputed; ``reps`` resamples drawn from ``seed``). No interval (nan) when no stratum
    has two seeds."""
    x, members = _strata(per_seed, strata)
    if x.size == 0:
        return math.nan, math.nan, math.nan
    point = float(x.mean())
    if all(len(v) < 2 for v in members):
        return point, math.nan, math.nan
    rng = np.random.default_rng(seed)
    total = np.zeros(reps)
    for v in members:
        total += v[rng.integers(0, len(v), size=(reps, len(v)))].sum(1)
    means = total / len(x)
    tail = 100 * (1 - confidence) / 2
    low, high = np.percentile(means, [tail, 100 - tail])
    return point, float(low), float(high)


def seed_range(
    per_seed: Sequence[float], strata: Sequence[str] | None = None
) -> tuple[float, float, float]:
    """(point, low, high): the mean of the per-seed aggregates and the range the stratified mean
    spans (each stratum's lowest seed, and its highest, in the mean; one stratum: the lowest and
    the highest seed). No interval (nan) when no stratum has two seeds."""
    x, members = _strata(per_seed, strata)
    if x.size == 0:
        return math.nan, math.nan, math.nan
    if all(len(v) < 2 for v in members):
        return float(x.mean()), math.nan, math.nan
    low = sum(len(v) * v.min() for v in members) / len(x)
    high = sum(len(v) * v.max() for v in members) / len(x)
    return float(x.mean()), float(low), float(high)


def seed_interval(
    per_seed: Sequence[float],
    strata: Sequence[str] | None = None,
    confidence: float = 0.95,
    reps: int = 2000,
    seed: int = 0,
) -> tuple[float, float, float]:
    """(point, low, high): :func:`bootstrap_ci` where every stratum has at least
    :data:`~gcnt.analysis.intervals.MIN_BOOTSTRAP` seeds, else :func:`seed_range` (a bootstrap
    over fewer seeds is no confidence interval: over two, its interval is their range)."""
    if _fewest(strata, len(per_seed)) >= MIN_BOOTSTRAP:
        return bootstrap_ci(per_seed, strata, confidence, reps, seed)
    return seed_range(per_seed, strata)


def _fewest(strata: Sequence[str] | None, n: int) -> int:
    """The fewest seeds of any stratum (``n`` seeds, one stratum when ``strata`` is None)."""
    return min(_counts(strata).values(), default=0) if strata is not None else n


def _counts(strata: Sequence[str]) -> dict[str, int]:
    counts: dict[str, int] = defaultdict(int)
    for s in strata:
        counts[s] += 1
    return counts


def interval_text(confidence: float, reps: int, strata: Sequence[str]) -> str:
    """What :func:`seed_interval` gives over seeds of ``strata`` (a seed's task each), for
    captions and tables: it names the interval and its n (the fewest seeds of a task)."""
    counts = _counts(strata)
    seeds, tasks = min(counts.values(), default=0), len(counts)
    n = f"n = {seeds} seed{'s' if seeds != 1 else ''}{' per task' if tasks > 1 else ''}"
    if seeds >= MIN_BOOTSTRAP:
        return (
            f"{confidence:.0%} CI ({n}): stratified percentile bootstrap over seeds ({reps} "
            "resamples) of each seed's aggregate over the set's robots (rliable's interval for "
            "few runs)"
        )
    if max(counts.values(), default=0) >= 2:
        per_task = ", per task, averaged over tasks" if tasks > 1 else ""
        return (
            f"range of the seeds' aggregates over the set's robots{per_task} ({n}; fewer than "
            f"{MIN_BOOTSTRAP} seeds: no bootstrap CI)"
        )
    return f"no interval ({n})"


def variant_summary(
    runs: Sequence[Run],
    sets: Sequence[str],
    statistics: Sequence[str] = ("mean",),
    confidence: float = 0.95,
    reps: int = 2000,
    seed: int = 0,
) -> dict[str, Any]:
    """``{set: {method: {"robots", "seeds", "scores": {seed: {robot: score}}, "protocol",
    "interval", stat: {"point", "low", "high", "per_seed"}}}}``."""
    out: dict[str, Any] = {}
    groups = comparable_groups(runs)
    for name in sets:
        scores = set_scores(runs, name, groups)
        if not scores:
            continue
        entry = {}
        for m in sorted(scores, key=method_key):
            units = scores[m]
            tasks = {u.task for u in units}
            ids = [f"{u.task}/seed{u.seed}" if len(tasks) > 1 else f"seed{u.seed}" for u in units]
            item: dict[str, Any] = {
                "robots": len({(u.task, robot) for u in units for robot in u.scores}),
                "seeds": len(units),
                "scores": dict(zip(ids, (u.scores for u in units), strict=True)),
                "protocol": protocols_text(p for u in units for p in u.protocols),
                "interval": interval_text(confidence, reps, [u.task for u in units]),
                "sources": [src for u in units for src in u.sources],
            }
            if len({len(u.scores) for u in units}) > 1:
                item["robots_per_seed"] = dict(
                    zip(ids, (len(u.scores) for u in units), strict=True)
                )
            for kind in statistics:
                per_seed = [aggregate(list(u.scores.values()), kind) for u in units]
                p, lo, hi = seed_interval(per_seed, [u.task for u in units], confidence, reps, seed)
                item[kind] = {
                    "point": p,
                    "low": lo,
                    "high": hi,
                    "per_seed": dict(zip(ids, per_seed, strict=True)),
                }
            entry[m] = item
        out[name] = entry
    if not out:
        known = ", ".join(available_sets(runs)) or "none"
        raise AnalysisError(
            f"no evaluation matches the sets {', '.join(sets)} (evaluations found: {known}); "
            "evaluate with `gcnt eval RUN_DIR --robots SPEC` or `gcnt sweep ... --eval SPEC`"
        )
    return out


def performance_profile(
    summary: dict[str, Any], name: str, points: int = 101
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """(thresholds, {method: fraction of seed x robot scores above each threshold})."""
    flat = {
        m: np.array([s for seed in item["scores"].values() for s in seed.values()])
        for m, item in summary[name].items()
    }
    allv = np.concatenate(list(flat.values()))
    taus = np.linspace(allv.min(), allv.max(), points)
    return taus, {m: (v[None, :] > taus[:, None]).mean(1) for m, v in flat.items()}


def set_display(summary: dict[str, Any], name: str, style: FigureStyle | None = None) -> str:
    """What figures and tables call set ``name`` of ``summary``: its display name, and for a
    robot name pattern the robots it resolved to (:func:`gcnt.analysis.names.set_display_name`)."""
    from gcnt.analysis.names import set_display_name

    entry = summary.get(name) or {}
    robots = sorted(
        {robot for item in entry.values() for s in item.get("scores", {}).values() for robot in s}
    )
    return set_display_name(name, robots, (style or FigureStyle()).names)


def intervals_text(items: Iterable[dict[str, Any]]) -> str:
    """The distinct ``interval`` texts of summary items, joined."""
    return "; ".join(dict.fromkeys(str(i["interval"]) for i in items if i.get("interval")))


def plot(
    summary: dict[str, Any],
    path: Path,
    statistics: Sequence[str] = ("mean",),
    profile: bool = False,
    style: FigureStyle | None = None,
) -> Path:
    """:func:`panels_figure` written as ``style`` says (default: to ``path``, in the format of
    its suffix); returns the first file written."""
    style = style or FigureStyle()
    return style.save(panels_figure(summary, statistics, profile, style), path)[0]


def panels_figure(
    summary: dict[str, Any],
    statistics: Sequence[str] = ("mean",),
    profile: bool = False,
    style: FigureStyle | None = None,
):
    """A panel per (statistic, set): each method's point estimate with its interval, the x range
    holding every interval; with ``profile`` a row of performance profiles below; methods and
    sets by their display names. Its caption (the intervals and their n) is written beside it
    (:func:`gcnt.analysis.bars.caption`)."""
    from gcnt.analysis.plotting import padded_limits, pyplot

    plt = pyplot()
    style = style or FigureStyle()

    sets = list(summary)
    methods = sorted({m for s in summary.values() for m in s}, key=method_key)
    colours = {m: plt.get_cmap("tab10")(i % 10) for i, m in enumerate(methods)}
    nrows = len(statistics) + int(profile)
    size = (4.2 * len(sets), 0.5 * len(methods) * nrows + 1.6 * nrows)
    with style.context():
        fig, axes = plt.subplots(nrows, len(sets), figsize=style.size(size), squeeze=False)
        for row, kind in enumerate(statistics):
            for col, name in enumerate(sets):
                ax = axes[row, col]
                ms = [m for m in methods if m in summary[name]]
                drawn = []
                for i, m in enumerate(ms):
                    est = summary[name][m][kind]
                    lo, hi = est["low"], est["high"]
                    if lo == lo and hi == hi:
                        ax.barh(i, hi - lo, left=lo, height=0.6, color=colours[m], alpha=0.6)
                    ax.plot([est["point"]], [i], "k|", markersize=14)
                    drawn += [est["point"], lo, hi]
                limits = padded_limits(drawn)
                if limits is not None:
                    ax.set_xlim(*limits)
                ax.set_yticks(range(len(ms)), [style.name(m) for m in ms])
                stat = kind.upper() if kind == "iqm" else kind
                ax.set_title(f"{set_display(summary, name, style)}: {stat} return")
                ax.grid(axis="x", alpha=0.3)
        if profile:
            for col, name in enumerate(sets):
                ax = axes[-1, col]
                taus, frac = performance_profile(summary, name)
                for m, f in frac.items():
                    ax.plot(taus, f, color=colours[m], label=style.name(m))
                ax.set_xlabel("return threshold τ")
                ax.set_ylabel("fraction of runs > τ")
                ax.legend(fontsize="small")
                ax.grid(alpha=0.3)
        style.suptitle(fig)
        fig.tight_layout()
    return fig


def _cell(e: dict[str, float]) -> str:
    if e["low"] == e["low"]:
        return f"{e['point']:.1f} [{e['low']:.1f}, {e['high']:.1f}]"
    return f"{e['point']:.1f} [no interval: 1 seed]"


def to_markdown(
    summary: dict[str, Any],
    statistics: Sequence[str] = ("mean",),
    style: FigureStyle | None = None,
) -> str:
    """A table per set: per method (its display name) the robots, seeds, each statistic with
    its interval and the protocol of its evaluations; what the intervals are (with their n) and
    the set's protocol above it."""
    style = style or FigureStyle()
    lines = []
    for name, entry in summary.items():
        protocol = protocols_text(item["protocol"] for item in entry.values())
        lines += [
            f"### {set_display(summary, name, style)}\n",
            f"Intervals: {intervals_text(entry.values())}. Evaluation: {protocol}.\n",
        ]
        head = " | ".join(f"{k} [interval]" for k in statistics)
        lines += [
            f"| method | robots | seeds | {head} | evaluation |",
            "|---|---:|---:|" + "---:|" * len(statistics) + "---|",
        ]
        for m, item in entry.items():
            cells = " | ".join(_cell(item[k]) for k in statistics)
            lines.append(
                f"| {style.name(m)} | {item['robots']} | {item['seeds']} | {cells} | "
                f"{item['protocol']} |"
            )
        lines.append("")
    return "\n".join(lines)


def write_json(summary: dict[str, Any], path: Path) -> Path:
    """The summary as strict JSON (no interval: ``null``)."""
    from gcnt.run.directory import strict_json

    path.parent.mkdir(parents=True, exist_ok=True)
    write_text(path, json.dumps(strict_json(summary), indent=1, allow_nan=False))
    return path
