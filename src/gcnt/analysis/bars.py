"""Bar chart of zero-shot returns on robot variant sets (paper figure 8).

Reads the summary of :func:`gcnt.analysis.variants.variant_summary`
(``{set: {method: {"robots", "seeds", "interval", "protocol", stat: {"point", "low", "high"}}}}``):
a panel per set, a group of bars per method (one bar per statistic), the bar at the point
estimate and the error bar from the interval ends. Every panel has the same methods at the same
places and the same y range, computed from the interval ends and points with a margin so that no
bar or error bar is cut. An interval that could not be computed (nan, or null in the JSON: one
seed) draws no error bar. The title says what the error bars are: the summary's ``interval``
text, or the ``interval`` argument.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from gcnt.analysis.plotting import FigureStyle
from gcnt.analysis.runs import AnalysisError, method_key, protocols_text

#: margin above and below the drawn values, as a fraction of their span
MARGIN = 0.08
STAT_NAMES = {"mean": "mean", "iqm": "IQM"}
HATCHES = ("", "//", "..", "xx")


def _finite(*values: Any) -> list[float]:
    return [float(v) for v in values if v is not None and math.isfinite(float(v))]


def bar_limits(summary: dict[str, Any], statistics: Sequence[str]) -> tuple[float, float]:
    """(bottom, top) that holds zero, every point and every finite interval end, with a margin."""
    values = [0.0]
    for entry in summary.values():
        for item in entry.values():
            for kind in statistics:
                if kind in item:
                    est = item[kind]
                    values += _finite(est["point"], est["low"], est["high"])
    lo, hi = min(values), max(values)
    pad = MARGIN * (hi - lo) if hi > lo else 1.0
    return lo - (pad if lo < 0 else 0.0), hi + (pad if hi > 0 or lo == hi else 0.0)


def caption(summary: dict[str, Any], interval: str | None = None) -> str:
    """What the error bars are (``interval``, else the summary's, which name their n) and, where
    the summary says it, the evaluation protocol the numbers come from."""
    from gcnt.analysis.variants import intervals_text

    items = [item for entry in summary.values() for item in entry.values()]
    if interval is None:
        interval = intervals_text(items) or "the summary's low-high intervals"
    text = f"Zero-shot return per method. Error bars: {interval}."
    protocols = [str(i["protocol"]) for i in items if i.get("protocol")]
    if protocols:
        text += f" Evaluation: {protocols_text(protocols)}."
    return text


def bar_figure(
    summary: dict[str, Any],
    statistics: Sequence[str] = ("mean",),
    interval: str | None = None,
    style: FigureStyle | None = None,
):
    """The figure: a panel per set, sharing the methods' places and the y range; methods and
    sets by their display names (``style``'s over the defaults), its size and fonts as
    ``style`` says, and its title ``style``'s (none by default: :func:`caption` is written
    beside the figure)."""
    style = style or FigureStyle()
    with style.context():
        return _bar_figure(summary, statistics, interval, style)


def _bar_figure(
    summary: dict[str, Any], statistics: Sequence[str], interval: str | None, style: FigureStyle
):
    from gcnt.analysis.plotting import pyplot
    from gcnt.analysis.variants import set_display

    plt = pyplot()
    import numpy as np

    if not summary:
        raise AnalysisError("no variant set to plot")
    sets = list(summary)
    methods = sorted({m for entry in summary.values() for m in entry}, key=method_key)
    stats = [k for k in statistics if any(k in it for e in summary.values() for it in e.values())]
    if not stats:
        raise AnalysisError(
            f"the summary has none of the statistics {', '.join(statistics)} to plot"
        )
    cmap = plt.get_cmap("tab10")
    colour = {m: cmap(i % 10) for i, m in enumerate(methods)}
    width = 0.8 / len(stats)
    panel_width = 1.2 + 0.9 * len(methods) * len(stats) ** 0.5
    fig, axes = plt.subplots(
        1,
        len(sets),
        figsize=style.size((panel_width * len(sets), 3.4)),
        sharey=True,
        squeeze=False,
    )
    x = np.arange(len(methods), dtype=np.float64)
    for ax, name in zip(axes[0], sets, strict=True):
        for s, kind in enumerate(stats):
            for i, m in enumerate(methods):
                est = (summary[name].get(m) or {}).get(kind)
                if est is None or not _finite(est["point"]):
                    continue
                pos = x[i] + (s - (len(stats) - 1) / 2) * width
                point = float(est["point"])
                ax.bar(
                    pos, point, width * 0.9, color=colour[m], hatch=HATCHES[s % len(HATCHES)],
                    edgecolor="0.2", linewidth=0.5,
                )  # fmt: skip
                if len(_finite(est["low"], est["high"])) == 2:
                    err = [[point - float(est["low"])], [float(est["high"]) - point]]
                    ax.errorbar(pos, point, yerr=err, fmt="none", ecolor="k", capsize=3)
        items = summary[name].values()
        robots = max(int(it.get("robots") or 0) for it in items)
        seeds = max(int(it.get("seeds") or 0) for it in items)
        title = f"{set_display(summary, name, style)} ({robots} robots, {seeds} seeds)"
        ax.set_title(title, fontsize="medium")
        tilt = len(methods) > 4
        shown = [style.name(m) for m in methods]
        ax.set_xticks(x, shown, rotation=30 if tilt else 0, ha="right" if tilt else "center")
        ax.set_xlim(-0.6, len(methods) - 0.4)
        ax.set_xlabel("method")
        ax.axhline(0.0, color="0.3", linewidth=0.6)
        ax.grid(axis="y", alpha=0.3)
        ax.set_axisbelow(True)
    label = " / ".join(STAT_NAMES.get(k, k) for k in stats)
    axes[0, 0].set_ylabel(f"zero-shot return ({label} over robots)")
    axes[0, 0].set_ylim(*bar_limits(summary, stats))
    if len(stats) > 1:
        from matplotlib.patches import Patch

        handles = [
            Patch(facecolor="0.85", edgecolor="0.2", hatch=HATCHES[s % len(HATCHES)], label=lab)
            for s, lab in enumerate(STAT_NAMES.get(k, k) for k in stats)
        ]
        axes[0, -1].legend(
            handles=handles, fontsize="small", loc="upper left", bbox_to_anchor=(1.01, 1.0)
        )
    style.suptitle(fig)  # the caption goes beside the figure (:func:`caption`), not into it
    fig.tight_layout()
    return fig


def plot_bars(
    summary: dict[str, Any],
    path: Path,
    statistics: Sequence[str] = ("mean",),
    interval: str | None = None,
    style: FigureStyle | None = None,
) -> Path:
    """:func:`bar_figure` written as ``style`` says (default: to ``path``, in the format of its
    suffix); returns the first file written."""
    style = style or FigureStyle()
    fig = bar_figure(summary, statistics, interval, style)
    return style.save(fig, path)[0]
