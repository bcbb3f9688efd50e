"""Learning curves (paper figures 6, 7 and 9): mean ± standard error over seeds vs env steps.

A curve is a column of ``metrics.jsonl`` (default ``train_return/mean``: the return of the
training episodes, exploring, and during TD3's first ``init_random_frames`` steps the return of
uniform random actions), or ``eval``: the return of the evaluations made during training
(``eval/step<N>.json``, every ``eval.interval`` steps and at the end; the curve of the paper's
figures), averaged over the training robots (``eval/ROBOT``: one robot). The rows are the logged
env steps. Where the seeds log at different steps, each seed's curve is linearly interpolated
onto the union of their logged steps within the range every seed covers (from the latest first
log step to the earliest last one), and ``logged`` counts the seeds that logged at each row.
Smoothing (a trailing moving average over log rows, per seed) happens only when asked for.

A curve is one experiment's seeds (:func:`gcnt.analysis.groups.comparable_groups`: runs of one
task and method whose recipes differ in more than the seed are separate curves, named by what
tells them apart). Single-robot baselines (SR-fair, SR-top: ``gcnt sweep --per-robot``) are one
run per robot and seed. Within a group, the runs of one seed that each train one robot are that
seed's per-robot runs: their curves are averaged first (each interpolated onto the steps all of
them cover; the mean over robots), and the seeds are then aggregated as above. ``seeds`` counts
seeds, ``robots`` the robots averaged per seed (1 for ordinary runs).
"""

from __future__ import annotations

import csv
import io
import logging
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from gcnt.analysis.groups import comparable_groups
from gcnt.analysis.plotting import FigureStyle
from gcnt.analysis.runs import (
    AnalysisError,
    Run,
    method_key,
    protocols_text,
    score,
)
from gcnt.files import write_text

log = logging.getLogger(__name__)

CSV_FIELDS = (
    "task", "method", "env_steps", "mean", "stderr", "seeds", "robots", "logged", "length_mean",
)  # fmt: skip
#: the ``--metric`` of the training evaluations' return (``eval/ROBOT``: one robot's)
EVAL_METRIC = "eval"


def _is_eval(metric: str) -> bool:
    return metric == EVAL_METRIC or metric.startswith(EVAL_METRIC + "/")


def _eval_points(run: Run, metric: str) -> list[tuple[float, float]]:
    """(env_steps, return) of the evaluations made during training: the mean over the training
    robots (``eval``) or one robot's (``eval/ROBOT``)."""
    records = [e for e in run.evals() if e.label == ""]
    if metric != EVAL_METRIC:
        robot = metric.split("/", 1)[1]
        return [(e.env_steps, score(e.robots[robot])) for e in records if robot in e.robots]
    train = set(run.train_robot_names())
    test = set(run.test_robot_names())
    pts = []
    for e in records:
        names = [r for r in e.robots if r in train] if train else []
        names = names or [r for r in e.robots if r not in test]
        if names:
            pts.append((e.env_steps, float(np.mean([score(e.robots[r]) for r in names]))))
    return pts


def run_curve(run: Run, metric: str, smooth: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """(env_steps, values) of ``metric`` in a run (a column of its metrics, or ``eval``),
    optionally smoothed. A non-finite value (a NaN return: a diverged run) stays NaN, so that
    the curve shows a gap there instead of a line drawn across it, and is warned about, naming
    the run and the steps."""
    if _is_eval(metric):
        raw = _eval_points(run, metric)
    else:
        raw = [
            (float(r["env_steps"]), float(r[metric]))
            for r in run.metrics()
            if isinstance(r.get(metric), int | float)
        ]
    pts = sorted((x, y if np.isfinite(y) else np.nan) for x, y in raw)
    if not pts:
        return np.zeros(0), np.zeros(0)
    x, y = map(np.asarray, zip(*pts, strict=True))
    bad = ~np.isfinite(y)
    if bad.all():  # never a value (a loss a method does not have): nothing logged
        return np.zeros(0), np.zeros(0)
    if bad.any():
        steps = ", ".join(f"{int(v)}" for v in x[bad][:5]) + (" ..." if bad.sum() > 5 else "")
        log.warning(
            "%s: %s is not finite at %d logged step(s) (%s): shown as a gap", run.path, metric,
            int(bad.sum()), steps,
        )  # fmt: skip
    if smooth > 1:  # a moving average over the finite values of each window
        v = np.where(bad, 0.0, y)
        c = np.cumsum(np.insert(v, 0, 0.0))
        n = np.cumsum(np.insert((~bad).astype(float), 0, 0.0))
        lo = np.maximum(np.arange(1, len(y) + 1) - smooth, 0)
        count = n[1:] - n[lo]
        with np.errstate(invalid="ignore", divide="ignore"):
            y = np.where(bad | (count == 0), np.nan, (c[1:] - c[lo]) / count)
    return x, y


def _common_range(curves: Sequence[tuple[np.ndarray, np.ndarray]]) -> tuple[float, float]:
    lo = max(float(x[0]) for x, _ in curves)
    hi = min(float(x[-1]) for x, _ in curves)
    return (hi, hi) if hi < lo else (lo, hi)  # disjoint ranges: compare at the common end


def aggregate(
    curves: Sequence[tuple[np.ndarray, np.ndarray]], points: int | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Seeds at equal step counts: (steps, mean, stderr, logged) over the steps every curve
    covers. The steps are the curves' logged steps there (their union; every seed is
    interpolated onto it), or with ``points`` an evenly spaced grid of that many; ``logged``
    counts the curves logged at each step.

    The standard error is nan with one seed. Curves with one point are kept as that point.
    """
    curves = [c for c in curves if len(c[0])]
    if not curves:
        return np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0, dtype=int)
    lo, hi = _common_range(curves)
    if points is not None and hi > lo:
        grid = np.unique(np.linspace(lo, hi, max(2, points)))
    else:
        steps = np.concatenate([x for x, _ in curves])
        grid = np.unique(steps[(steps >= lo) & (steps <= hi)])
        if not len(grid):  # disjoint ranges with no step in common
            grid = np.array([hi])
    ys = np.stack([np.interp(grid, x, y) for x, y in curves])
    logged = np.sum([np.isin(grid, x) for x, _ in curves], axis=0)
    mean = ys.mean(0)
    if len(curves) > 1:
        stderr = ys.std(0, ddof=1) / np.sqrt(len(curves))
    else:
        stderr = np.full_like(mean, np.nan)
    return grid, mean, stderr, logged


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
    grid, mean, _, _ = aggregate(curves)
    return grid, mean


def logged_steps(curves: Sequence[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """The steps at which every one of a seed's per-robot curves logged."""
    steps = curves[0][0]
    for x, _ in curves[1:]:
        steps = steps[np.isin(steps, x)]
    return steps


def seed_groups(members: Sequence[Run]) -> list[list[Run]]:
    """The runs of one group (the seeds of one experiment), one list per seed: the runs of a
    seed that each train one robot together (per-robot runs), every other run alone; in seed
    order."""
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
    runs: Sequence[Run],
    metric: str = "train_return/mean",
    points: int | None = None,
    smooth: int = 1,
) -> list[dict]:
    """One row per (task, method, step): mean, stderr, the number of seeds, the number of robots
    averaged per seed (per-robot runs; 1 otherwise) and the number of seeds logged there."""
    rows = []
    for group in comparable_groups(runs):  # the seeds of one experiment each
        task, method = group.task, group.label
        curves, robots = [], []
        for unit in seed_groups(group.runs):
            per_run = [run_curve(r, metric, smooth) for r in unit]
            per_run = [c for c in per_run if len(c[0])]
            if per_run:
                x, y = mean_over_robots(per_run)
                # a seed counts as logged where all its robots logged (else interpolated)
                keep = np.isin(x, logged_steps(per_run))
                curves.append((x, y, keep))
                robots.append(len(per_run))
        if not curves:
            continue
        if len(set(robots)) > 1:
            log.warning(
                "%s %s: the seeds average different numbers of robots (%s); robots = the fewest",
                task,
                method,
                ", ".join(map(str, robots)),
            )
        grid, mean, se, _ = aggregate([(x, y) for x, y, _ in curves], points)
        logged = np.sum([np.isin(grid, x[keep]) for x, _, keep in curves], axis=0)
        for s, m, e, n in zip(grid, mean, se, logged, strict=True):
            rows.append(
                {
                    "task": task,
                    "method": method,
                    "env_steps": int(round(s)),
                    "mean": float(m),
                    "stderr": float(e),
                    "seeds": len(curves),
                    "robots": min(robots),
                    "logged": int(n),
                }
            )
    if not rows:
        where = "eval/step<N>.json" if _is_eval(metric) else "metrics.jsonl"
        raise AnalysisError(
            f"no run has the metric {metric!r} in its {where} "
            f"({', '.join(str(r.path) for r in runs[:3])}{', ...' if len(runs) > 3 else ''})"
        )
    if metric in LENGTH_OF:
        _join_lengths(rows, runs, LENGTH_OF[metric], points, smooth)
    return rows


def _join_lengths(
    rows: list[dict], runs: Sequence[Run], length: str, points: int | None, smooth: int
) -> None:
    """Each row's mean episode length (``length_mean``: the mean over seeds of ``length``, the
    length metric logged with the return), where the runs logged it at that step."""
    try:
        found = learning_curves(runs, length, points, smooth)
    except AnalysisError:  # runs from before lengths were logged
        return
    at = {(r["task"], r["method"], r["env_steps"]): r["mean"] for r in found}
    for row in rows:
        row["length_mean"] = at.get((row["task"], row["method"], row["env_steps"]))


def metric_label(runs: Sequence[Run], metric: str) -> str:
    """The y axis label: what the curve is (and for ``eval``, the evaluations' protocol)."""
    if metric == "train_return/mean":
        return "training return (exploring; mean over robots)"
    if _is_eval(metric):
        protocol = protocols_text(e.protocol for r in runs for e in r.evals() if e.label == "")
        what = "mean over training robots" if metric == EVAL_METRIC else metric.split("/", 1)[1]
        return f"evaluation return ({what})\n{protocol}"
    return metric


def random_phase(runs: Sequence[Run]) -> dict[str, list[int]]:
    """``{task: [env steps]}``: where the runs' uniform random exploration ends (TD3's
    ``init_random_frames``; no entry for runs without the phase)."""
    out: dict[str, set[int]] = defaultdict(set)
    for r in runs:
        steps = r.init_random_frames
        if steps:
            out[r.task].add(steps)
    return {task: sorted(v) for task, v in out.items()}


#: the per-seed file's columns besides the metric's own (``seeds_rows``)
SEED_FIELDS = ["task", "method", "seed", "run", "env_steps"]
#: logged beside a return: its episodes' mean length (a return of survival bonuses is told
#: apart from one of progress)
LENGTH_OF = {"train_return/mean": "train_length/mean"}


def seeds_rows(runs: Sequence[Run], metric: str = "train_return/mean") -> list[dict]:
    """Every run's own points of ``metric`` (no averaging, no smoothing): one row per run and
    logged step, with the run's task, method label, seed and folder name, and, for the
    exploring return, the episodes' mean length logged with it. What a reader re-tests a
    verdict from (``gcnt curves --per-seed``)."""
    rows = []
    length = LENGTH_OF.get(metric)
    for group in comparable_groups(runs):
        for run in sorted(group.runs, key=lambda r: (r.seed, str(r.path))):
            x, y = run_curve(run, metric, 1)
            lengths = {}
            if length is not None:
                lengths = {int(m["env_steps"]): m[length] for m in run.metrics() if length in m}
            for step, value in zip(x, y, strict=True):
                row = {
                    "task": group.task,
                    "method": group.label,
                    "seed": run.seed,
                    "run": run.path.name,
                    "env_steps": int(step),
                    metric: float(value),
                }
                if length is not None:
                    row[length] = lengths.get(int(step))
                rows.append(row)
    return rows


def write_seeds_csv(rows: Sequence[dict], metric: str, path: Path) -> Path:
    """:func:`seeds_rows` as a CSV file."""
    fields = [*SEED_FIELDS, metric, *([LENGTH_OF[metric]] if metric in LENGTH_OF else [])]
    text = io.StringIO(newline="")
    w = csv.DictWriter(text, fieldnames=fields)
    w.writeheader()
    w.writerows({k: row.get(k) for k in fields} for row in rows)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text(path, text.getvalue())
    return path


def write_csv(rows: Sequence[dict], path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    text = io.StringIO(newline="")
    w = csv.DictWriter(text, fieldnames=CSV_FIELDS)
    w.writeheader()
    w.writerows({k: row.get(k, 1 if k == "robots" else None) for k in CSV_FIELDS} for row in rows)
    write_text(path, text.getvalue())
    return path


def plot_curves(
    rows: Sequence[dict],
    path: Path,
    metric: str = "train_return/mean",
    *,
    ylabel: str | None = None,
    random_until: dict[str, list[int]] | None = None,
    style: FigureStyle | None = None,
) -> Path:
    """:func:`curves_figure` written as ``style`` says (default: to ``path``, in the format of
    its suffix); returns the first file written."""
    style = style or FigureStyle()
    fig = curves_figure(rows, metric, ylabel=ylabel, random_until=random_until, style=style)
    return style.save(fig, path)[0]


def curves_figure(
    rows: Sequence[dict],
    metric: str = "train_return/mean",
    *,
    ylabel: str | None = None,
    random_until: dict[str, list[int]] | None = None,
    style: FigureStyle | None = None,
):
    """One panel per task, one line per method, a band of ± one standard error over seeds (an
    error bar at a point with no finite neighbour: a single evaluation, or one between gaps); a
    marker at each row (filled where every seed logged, hollow where some are interpolated), and
    a dotted vertical line where the random exploration phase ends (``random_until``: task ->
    steps). The legend names the interval and each method's number of seeds; each panel's y
    range holds every band. Tasks and methods by their display names; size, fonts and title as
    ``style`` says. On a page of a given size (``style.figsize``: a paper's column) the text is a
    step smaller, the y axis says what the curve is and the legend below, in as few rows as fit,
    the rest (:func:`split_label`), with a method's seed count only where they differ."""
    from matplotlib.lines import Line2D

    from gcnt.analysis.intervals import stderr_text
    from gcnt.analysis.plotting import padded_limits, pyplot

    plt = pyplot()
    style = style or FigureStyle()

    tasks = list(dict.fromkeys(r["task"] for r in rows))
    methods = sorted({r["method"] for r in rows}, key=method_key)
    colours = {m: plt.get_cmap("tab10")(i % 10) for i, m in enumerate(methods)}
    counts: dict[str, list[tuple[int, int]]] = {m: [] for m in methods}  # (seeds, robots)
    random_line = False
    # on a page of a given size (a paper's column) the axis says what the curve is, the legend's
    # title the rest (the interval, how the return was measured)
    axis_label, details = (ylabel or metric), []
    if style.figsize is not None:
        axis_label, details = split_label(axis_label)
    cols = min(4, len(tasks))
    nrows = -(-len(tasks) // cols)
    with style.context():
        fig, axes = plt.subplots(
            nrows, cols, figsize=style.size((4.6 * cols, 3.6 * nrows)), squeeze=False
        )
        for ax, task in zip(axes.flat, tasks, strict=False):
            drawn = []
            present = [
                m for m in methods if any(r["task"] == task and r["method"] == m for r in rows)
            ]
            # every method at one step (a single evaluation): side by side, so that no point or
            # error bar hides another
            steps = {r["env_steps"] for r in rows if r["task"] == task}
            dodge = DODGE * max(abs(next(iter(steps))), 1) if len(steps) == 1 else 0.0
            for j, m in enumerate(present):
                sel = [r for r in rows if r["task"] == task and r["method"] == m]
                x = np.array([r["env_steps"] for r in sel], dtype=np.float64)
                x = x + dodge * (j - (len(present) - 1) / 2)
                y = np.array([r["mean"] for r in sel], dtype=np.float64)
                e = np.nan_to_num(np.array([r["stderr"] for r in sel], dtype=np.float64))
                n, k = sel[0]["seeds"], sel[0].get("robots", 1)
                counts[m].append((n, k))
                full = np.array([r.get("logged", n) >= n for r in sel])
                c = colours[m]
                ax.plot(x, y, color=c)
                ax.fill_between(x, y - e, y + e, color=c, alpha=0.2, linewidth=0)
                alone = _isolated(y)
                if alone.any():  # a band needs two points: these get an error bar
                    ax.errorbar(x[alone], y[alone], yerr=e[alone], fmt="none", ecolor=c, capsize=3)
                ax.plot(x[full], y[full], "o", color=c, markersize=3.5)
                ax.plot(x[~full], y[~full], "o", mfc="none", color=c, markersize=3.5)
                drawn += [*(y - e), *(y + e)]
            ends = (random_until or {}).get(task, [])
            for end in ends:
                ax.axvline(end, color="0.4", linestyle=":", linewidth=1)
                random_line = True
                if len(ends) > 1:  # runs of several random phases: each line says its step
                    ax.annotate(
                        f"{end:,}",
                        xy=(end, 1.0),
                        xycoords=("data", "axes fraction"),
                        xytext=(-2, -2),
                        textcoords="offset points",
                        rotation=90,
                        ha="right",
                        va="top",
                        fontsize="x-small",
                        color="0.4",
                    )
            limits = padded_limits(drawn)
            if limits is not None:
                ax.set_ylim(*limits)
            page = style.figsize is not None  # a page's text a step smaller
            ax.set_title(style.name(task), fontsize="medium" if page else None)
            ax.set_xlabel("environment steps", fontsize="small" if page else None)
            label = _fitted(axis_label, style, fig.get_figheight() / nrows, fig)
            ax.set_ylabel(label, fontsize="small")
            if page:
                ax.tick_params(labelsize="small")
            ax.grid(alpha=0.3)
            if dodge:  # one step: its tick alone
                ax.set_xticks(sorted(steps))
        for ax in axes.flat[len(tasks) :]:
            ax.set_visible(False)
        style.suptitle(fig)
        if style.figsize is None:
            fig.tight_layout()
        else:  # on a page every margin counts: laid out again at each size fit_page tries
            fig.set_layout_engine("tight", pad=0.3)
        # one legend, never over the data: its seed counts per method (per panel where they
        # differ). Beside every panel (the saved figure grows to hold it); on a page of a given
        # size, below the panels, as wide as the page
        handles = [Line2D([], [], color=colours[m], marker="o", markersize=3.5) for m in counts]
        labels = [f"{style.name(m)} ({_counts_text(c)})" for m, c in counts.items()]
        title = stderr_text([n for c in counts.values() for n, _ in c])
        if style.figsize is not None and len({x for c in counts.values() for x in c}) == 1:
            if next(iter(counts.values()))[0][1] == 1:  # one n for all, which the title gives
                labels = [style.name(m) for m in counts]
        if random_line:
            handles.append(Line2D([], [], color="0.4", linestyle=":", linewidth=1))
            labels.append("end of random actions")
        common = {"fontsize": "small", "title_fontsize": "small"}
        if style.figsize is None:
            fig.legend(
                handles, labels, title=title, **common, loc="upper left", bbox_to_anchor=(1.0, 1.0),
                bbox_transform=axes[0, -1].transAxes if nrows == 1 else fig.transFigure,
            )  # fmt: skip
        else:
            _legend_below(fig, handles, labels, "; ".join([title, *details]))
    return fig


def split_label(label: str) -> tuple[str, list[str]]:
    """An axis label as what the curve is and its details: ``"training return (exploring;
    mean over robots)"`` -> ``("training return", ["exploring; mean over robots"])``; an
    evaluation's protocol (its second line) is a detail too."""
    head, *rest = label.split("\n")
    if head.endswith(")") and " (" in head:
        head, inner = head[:-1].split(" (", 1)
        rest.insert(0, inner)
    return head, [r for r in rest if r.strip()]


#: the legend of a figure on a page of a given size: smaller type, no frame, tight spacing
PAGE_LEGEND = {
    "fontsize": "x-small", "title_fontsize": "x-small", "frameon": False, "handlelength": 1.2,
    "columnspacing": 0.8, "handletextpad": 0.4, "borderaxespad": 0.2, "labelspacing": 0.3,
}  # fmt: skip


def _legend_below(fig, handles: list, labels: list[str], title: str) -> None:
    """The figure's legend below its panels in as many columns as fit its width, the title
    wrapped to that width."""
    import textwrap

    from matplotlib.font_manager import FontProperties

    width = fig.get_figwidth() * fig.dpi
    renderer = fig.canvas.get_renderer()
    size = FontProperties(size="x-small").get_size_in_points() * fig.dpi / 72
    chars = max(int(width / (0.55 * size)), 20)
    for rows in range(1, len(handles) + 1):
        ncols = -(-len(handles) // rows)  # as few rows as fit, their columns balanced
        legend = fig.legend(
            handles, labels, title=textwrap.fill(title, chars), **PAGE_LEGEND, ncols=ncols,
            loc="upper center", bbox_to_anchor=(0.5, 0.0), bbox_transform=fig.transFigure,
        )  # fmt: skip
        if ncols == 1 or legend.get_window_extent(renderer).width <= width:
            return
        legend.remove()


def _fitted(label: str, style: FigureStyle, inches: float, fig) -> str:
    """An axis label in "small" type: on a page of a given size, wrapped to about half of the
    ``inches`` its panel has."""
    if style.figsize is None:
        return label
    import textwrap

    chars = int(0.5 * inches * fig.dpi / (0.55 * common_size(fig)))
    return textwrap.fill(label, max(chars, 12))


def common_size(fig) -> float:
    """The legend's font size in pixels ("small" of matplotlib's font size) of ``fig``."""
    from matplotlib.font_manager import FontProperties

    return FontProperties(size="small").get_size_in_points() * fig.dpi / 72


def _counts_text(counts: Sequence[tuple[int, int]]) -> str:
    """``n = 3`` (seeds), ``n = 3 × 4 robots`` (per-robot runs), ``n = 3 / 2`` where the panels
    differ."""
    texts = list(dict.fromkeys(f"{n}{f' × {k} robots' if k > 1 else ''}" for n, k in counts))
    return "n = " + " / ".join(texts)


#: the offset between methods drawn at one step, as a share of that step count
DODGE = 0.01


def _isolated(y: np.ndarray) -> np.ndarray:
    """Finite values whose neighbours are missing or not finite (a band cannot show them)."""
    ok = np.isfinite(y)
    before = np.concatenate([[False], ok[:-1]])
    after = np.concatenate([ok[1:], [False]])
    return ok & ~before & ~after
