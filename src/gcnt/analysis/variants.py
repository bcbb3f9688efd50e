"""Zero-shot returns on robot variant sets (paper figure 8) with 95% bootstrap confidence intervals.

A *set* is a group of evaluations named the same way: ``gcnt eval RUN --robots SPEC`` keeps each
evaluation under a label saying what was evaluated, and a set name matches that label or a part
of the evaluated robot specification (e.g. ``variants-kinematics`` matches
``Unimal:variants-kinematics``).

Scores are each seed's mean return per robot. The aggregate of a method on a set is the mean
over robots of the mean over seeds (optionally the interquartile mean, IQM, of all seed x robot
scores), with a stratified percentile bootstrap: seeds are resampled within each robot, which is
what scipy's ``scipy.stats.bootstrap`` does when given one sample per robot. (``rliable`` was the
first choice; its pinned ``arch`` dependency fails to import with pandas 3, so scipy is used.)
Performance profiles (the fraction of seed x robot scores above each return threshold) are
offered as well.
"""

from __future__ import annotations

import json
import math
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from gcnt.analysis.runs import AnalysisError, Run, method_key, method_labels

STATISTICS = ("mean", "iqm")


def available_sets(runs: Sequence[Run]) -> list[str]:
    """Labels and robot specifications of the runs' evaluations (what ``--sets`` can name)."""
    names: list[str] = []
    for r in runs:
        for e in r.evals():
            names.append(e.label or "training")
            spec = e.meta.get("robots_spec") or []
            names += [spec] if isinstance(spec, str) else [str(s) for s in spec]
    return list(dict.fromkeys(names))


def set_scores(runs: Sequence[Run], name: str) -> dict[str, dict[str, list[float]]]:
    """``{method: {robot: [score per seed]}}`` for the evaluations matching set ``name`` (per run
    and robot, the evaluation with the most env steps, then episodes)."""
    labels = method_labels(runs)
    out: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    for r in runs:
        best: dict[str, tuple[int, int, float]] = {}
        for e in r.evals():
            if not e.matches(name):
                continue
            for robot, res in e.robots.items():
                key = (e.env_steps, int(res.get("episodes") or 0), float(res["mean"]))
                if robot not in best or key[:2] > best[robot][:2]:
                    best[robot] = key
        for robot, (_, _, score) in best.items():
            out[labels[r.path]][robot].append(score)
    return {m: dict(v) for m, v in out.items()}


def _statistic(kind: str):
    from scipy.stats import trim_mean

    if kind == "mean":

        def stat(*samples, axis=-1):
            return np.mean([np.mean(s, axis=axis) for s in samples], axis=0)

    elif kind == "iqm":

        def stat(*samples, axis=-1):
            return trim_mean(np.concatenate(samples, axis=axis), 0.25, axis=axis)

    else:
        raise ValueError(f"unknown statistic {kind!r} (known: {', '.join(STATISTICS)})")
    return stat


def bootstrap_ci(
    per_robot: Sequence[Sequence[float]],
    kind: str = "mean",
    confidence: float = 0.95,
    reps: int = 2000,
    seed: int = 0,
) -> tuple[float, float, float]:
    """(point, low, high) of the statistic over robots with a stratified percentile bootstrap.

    With a single seed per robot the robots themselves are resampled; with a single score the
    interval is (nan, nan).
    """
    from scipy.stats import bootstrap

    samples = [np.asarray(s, dtype=np.float64) for s in per_robot if len(s)]
    if not samples:
        return math.nan, math.nan, math.nan
    stat = _statistic(kind)
    point = float(stat(*samples))
    if all(len(s) >= 2 for s in samples):
        data: tuple = tuple(samples)
    else:  # one seed: resample robots (their seed-mean scores)
        data = (np.array([s.mean() for s in samples]),)
        if len(data[0]) < 2:
            return point, math.nan, math.nan
        if kind == "mean":
            stat = _statistic("mean")
    if all(np.ptp(d) == 0 for d in data):
        return point, point, point
    res = bootstrap(
        data,
        stat,
        n_resamples=reps,
        confidence_level=confidence,
        method="percentile",
        vectorized=True,
        rng=np.random.default_rng(seed),
    )
    return point, float(res.confidence_interval.low), float(res.confidence_interval.high)


def variant_summary(
    runs: Sequence[Run],
    sets: Sequence[str],
    statistics: Sequence[str] = ("mean",),
    confidence: float = 0.95,
    reps: int = 2000,
) -> dict[str, Any]:
    """``{set: {method: {"robots", "seeds", "scores", stat: {"point","low","high"}}}}``."""
    out: dict[str, Any] = {}
    for name in sets:
        scores = set_scores(runs, name)
        if not scores:
            continue
        entry = {}
        for m in sorted(scores, key=method_key):
            per_robot = scores[m]
            item: dict[str, Any] = {
                "robots": len(per_robot),
                "seeds": max(len(v) for v in per_robot.values()),
                "scores": per_robot,
            }
            for kind in statistics:
                p, lo, hi = bootstrap_ci(list(per_robot.values()), kind, confidence, reps)
                item[kind] = {"point": p, "low": lo, "high": hi}
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
        m: np.array([s for v in item["scores"].values() for s in v])
        for m, item in summary[name].items()
    }
    allv = np.concatenate(list(flat.values()))
    taus = np.linspace(allv.min(), allv.max(), points)
    return taus, {m: (v[None, :] > taus[:, None]).mean(1) for m, v in flat.items()}


def plot(
    summary: dict[str, Any],
    path: Path,
    statistics: Sequence[str] = ("mean",),
    profile: bool = False,
) -> Path:
    """A panel per (statistic, set): each method's point estimate with its interval; with
    ``profile`` a row of performance profiles below."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sets = list(summary)
    methods = sorted({m for s in summary.values() for m in s}, key=method_key)
    colours = {m: plt.get_cmap("tab10")(i % 10) for i, m in enumerate(methods)}
    nrows = len(statistics) + int(profile)
    fig, axes = plt.subplots(
        nrows,
        len(sets),
        figsize=(4.2 * len(sets), 0.5 * len(methods) * nrows + 1.6 * nrows),
        squeeze=False,
    )
    for row, kind in enumerate(statistics):
        for col, name in enumerate(sets):
            ax = axes[row, col]
            ms = [m for m in methods if m in summary[name]]
            for i, m in enumerate(ms):
                est = summary[name][m][kind]
                lo, hi = est["low"], est["high"]
                if lo == lo and hi == hi:
                    ax.barh(i, hi - lo, left=lo, height=0.6, color=colours[m], alpha=0.6)
                ax.plot([est["point"]], [i], "k|", markersize=14)
            ax.set_yticks(range(len(ms)), ms)
            ax.set_title(f"{name}: {kind.upper() if kind == 'iqm' else kind} return")
            ax.grid(axis="x", alpha=0.3)
    if profile:
        for col, name in enumerate(sets):
            ax = axes[-1, col]
            taus, frac = performance_profile(summary, name)
            for m, f in frac.items():
                ax.plot(taus, f, color=colours[m], label=m)
            ax.set_xlabel("return threshold τ")
            ax.set_ylabel("fraction of runs > τ")
            ax.legend(fontsize="small")
            ax.grid(alpha=0.3)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def to_markdown(summary: dict[str, Any], statistics: Sequence[str] = ("mean",)) -> str:
    lines = []
    for name, entry in summary.items():
        lines.append(f"### {name}\n")
        head = " | ".join(f"{k} [95% CI]" for k in statistics)
        lines += [
            f"| method | robots | seeds | {head} |",
            "|---|---:|---:|" + "---:|" * len(statistics),
        ]
        for m, item in entry.items():
            cells = []
            for k in statistics:
                e = item[k]
                cells.append(f"{e['point']:.1f} [{e['low']:.1f}, {e['high']:.1f}]")
            lines.append(
                f"| {m} | {item['robots']} | {item['seeds']} | " + " | ".join(cells) + " |"
            )
        lines.append("")
    return "\n".join(lines)


def write_json(summary: dict[str, Any], path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(summary, indent=1))
    return path
