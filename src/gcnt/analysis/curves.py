"""Learning curves (paper figures 6, 7 and 9): mean ± standard error over seeds vs env steps.

Seeds log at their own step counts, so each seed's curve is linearly interpolated onto one grid
of environment steps that every seed of the group covers (from the latest first log step to the
earliest last one), and mean and standard error are taken there. Smoothing (a trailing moving
average over log rows, per seed) happens only when asked for.

Single-robot baselines (SR-fair, SR-top: ``gcnt sweep --per-robot``) are one run per robot and
seed. Within a (task, method) group, the runs of one seed that each train one robot are that
seed's per-robot runs: their curves are averaged first (each interpolated onto the steps all of
them cover; the mean over robots), and the seeds are then aggregated as above. ``seeds`` counts
seeds, ``robots`` the robots averaged per seed (1 for ordinary runs).
"""

from __future__ import annotations

import csv
import logging
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from gcnt.analysis.runs import AnalysisError, Run, method_key, method_labels

log = logging.getLogger(__name__)

CSV_FIELDS = ("task", "method", "env_steps", "mean", "stderr", "seeds", "robots")


def run_curve(run: Run, metric: str, smooth: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """(env_steps, values) of ``metric`` in a run's metrics, optionally smoothed."""
    pts = [
        (float(r["env_steps"]), float(r[metric]))
        for r in run.metrics()
        if isinstance(r.get(metric), int | float) and np.isfinite(r[metric])
    ]
    if not pts:
        return np.zeros(0), np.zeros(0)
    pts.sort()
    x, y = map(np.asarray, zip(*pts, strict=True))
    if smooth > 1:
        c = np.cumsum(np.insert(y, 0, 0.0))
        lo = np.maximum(np.arange(1, len(y) + 1) - smooth, 0)
        y = (c[1:] - c[lo]) / (np.arange(1, len(y) + 1) - lo)
    return x, y


def aggregate(
    curves: Sequence[tuple[np.ndarray, np.ndarray]], points: int = 100
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Seeds at equal step counts: (grid, mean, stderr) over the steps every curve covers.

    The standard error is nan with one seed. Curves with one point are kept as that point.
    """
    curves = [c for c in curves if len(c[0])]
    if not curves:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    lo = max(float(x[0]) for x, _ in curves)
    hi = min(float(x[-1]) for x, _ in curves)
    if hi < lo:  # disjoint ranges (e.g. a seed that just started): compare at the common end
        lo = hi
    grid = np.unique(np.linspace(lo, hi, max(2, points))) if hi > lo else np.array([hi])
    ys = np.stack([np.interp(grid, x, y) for x, y in curves])
    mean = ys.mean(0)
    if len(curves) > 1:
        stderr = ys.std(0, ddof=1) / np.sqrt(len(curves))
    else:
        stderr = np.full_like(mean, np.nan)
    return grid, mean, stderr


def mean_over_robots(
    curves: Sequence[tuple[np.ndarray, np.ndarray]],
) -> tuple[np.ndarray, np.ndarray]:
    """One seed's per-robot curves as one: (steps, mean over robots) on the steps every robot
    covers, at every robot's log steps there (the mean of piecewise-linear curves, exactly)."""
    curves = [c for c in curves if len(c[0])]
    if not curves:
        return np.zeros(0), np.zeros(0)
    if len(curves) == 1:
        return curves[0]
    lo = max(float(x[0]) for x, _ in curves)
    hi = min(float(x[-1]) for x, _ in curves)
    if hi < lo:  # disjoint ranges: compare at the common end, as between seeds
        lo = hi
    steps = np.concatenate([x for x, _ in curves] + [np.array([lo, hi])])
    grid = np.unique(steps[(steps >= lo) & (steps <= hi)])
    return grid, np.stack([np.interp(grid, x, y) for x, y in curves]).mean(0)


def seed_groups(members: Sequence[Run]) -> list[list[Run]]:
    """The runs of one (task, method) group, one list per seed: the runs of a seed that each
    train one robot together (per-robot runs), every other run alone; in seed order."""
    units: list[tuple[int, list[Run]]] = []
    per_robot: dict[int, list[Run]] = {}
    for r in members:
        if r.single_robot is None:
            units.append((r.seed, [r]))
        elif r.seed in per_robot:
            per_robot[r.seed].append(r)
        else:
            per_robot[r.seed] = [r]
            units.append((r.seed, per_robot[r.seed]))
    return [u for _, u in sorted(units, key=lambda su: su[0])]


def learning_curves(
    runs: Sequence[Run], metric: str = "train_return/mean", points: int = 100, smooth: int = 1
) -> list[dict]:
    """One row per (task, method, grid step): mean, stderr, the number of seeds and the number
    of robots averaged per seed (per-robot runs; 1 otherwise)."""
    labels = method_labels(runs)
    groups: dict[tuple[str, str], list[Run]] = defaultdict(list)
    for r in runs:
        groups[(r.task, labels[r.path])].append(r)
    rows = []
    for (task, method), members in sorted(
        groups.items(), key=lambda kv: (kv[0][0], method_key(kv[0][1]))
    ):
        curves, robots = [], []
        for unit in seed_groups(members):
            per_run = [run_curve(r, metric, smooth) for r in unit]
            per_run = [c for c in per_run if len(c[0])]
            if per_run:
                curves.append(mean_over_robots(per_run))
                robots.append(len(per_run))
        if len(set(robots)) > 1:
            log.warning(
                "%s %s: the seeds average different numbers of robots (%s); robots = the fewest",
                task,
                method,
                ", ".join(map(str, robots)),
            )
        grid, mean, se = aggregate(curves, points)
        for s, m, e in zip(grid, mean, se, strict=True):
            rows.append(
                {
                    "task": task,
                    "method": method,
                    "env_steps": int(round(s)),
                    "mean": float(m),
                    "stderr": float(e),
                    "seeds": len(curves),
                    "robots": min(robots),
                }
            )
    if not rows:
        raise AnalysisError(
            f"no run has the metric {metric!r} in its metrics.jsonl "
            f"({', '.join(str(r.path) for r in runs[:3])}{', ...' if len(runs) > 3 else ''})"
        )
    return rows


def write_csv(rows: Sequence[dict], path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=CSV_FIELDS)
        w.writeheader()
        w.writerows(
            {k: row.get(k, 1 if k == "robots" else None) for k in CSV_FIELDS} for row in rows
        )
    return path


def plot_curves(rows: Sequence[dict], path: Path, metric: str = "train_return/mean") -> Path:
    """One panel per task, one line per method, a band of ± one standard error."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tasks = list(dict.fromkeys(r["task"] for r in rows))
    methods = sorted({r["method"] for r in rows}, key=method_key)
    colours = {m: plt.get_cmap("tab10")(i % 10) for i, m in enumerate(methods)}
    cols = min(4, len(tasks))
    nrows = -(-len(tasks) // cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(4.2 * cols, 3.3 * nrows), squeeze=False)
    for ax, task in zip(axes.flat, tasks, strict=False):
        for m in methods:
            sel = [r for r in rows if r["task"] == task and r["method"] == m]
            if not sel:
                continue
            x = np.array([r["env_steps"] for r in sel])
            y = np.array([r["mean"] for r in sel])
            e = np.nan_to_num(np.array([r["stderr"] for r in sel]))
            n, k = sel[0]["seeds"], sel[0].get("robots", 1)
            label = f"{m} ({n}{f' x {k} robots' if k > 1 else ''})"
            if len(x) == 1:
                ax.errorbar(x, y, yerr=e, fmt="o", color=colours[m], label=label)
            else:
                ax.plot(x, y, color=colours[m], label=label)
                ax.fill_between(x, y - e, y + e, color=colours[m], alpha=0.2, linewidth=0)
        ax.set_title(task)
        ax.set_xlabel("environment steps")
        ax.set_ylabel(metric.replace("train_return/mean", "average return"))
        ax.grid(alpha=0.3)
        ax.legend(fontsize="small", title="method (seeds)", title_fontsize="small")
    for ax in axes.flat[len(tasks) :]:
        ax.set_visible(False)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
