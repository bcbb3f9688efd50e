"""Figures and tables ready to publish: one set of figure options on every figure command
(formats, size, fonts, title, display names), intervals named with their n, a bootstrap over
few values never called a 95% CI, a best result bold only when separated, and axes that hold
every interval."""

from __future__ import annotations

import argparse
import math
import re
from pathlib import Path

import matplotlib
import numpy as np
import pytest

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from cli_helpers import ROOT  # noqa: E402
from test_curves import make_run as curve_run  # noqa: E402
from test_variants import gcnt_eval  # noqa: E402
from test_variants import make_run as variant_run  # noqa: E402

from gcnt.analysis import bars, curves, intervals, strobe, variants, zeroshot  # noqa: E402
from gcnt.analysis.names import METHOD_NAMES, TASKS, display_name  # noqa: E402
from gcnt.analysis.plotting import FigureStyle  # noqa: E402
from gcnt.analysis.runs import find_runs  # noqa: E402
from gcnt.cli import build_parser, main  # noqa: E402

FIGURE_COMMANDS = ("curves", "variants", "embed", "strobe")


def _svg_text(path: Path) -> str:
    """The text of an SVG file's text elements, joined (matplotlib writes one per line)."""
    import html

    return " ".join(
        html.unescape(t) for t in re.findall(r"<text[^>]*>([^<]*)</text>", path.read_text())
    )


# ----------------------------------------------------------------------------- display names


def test_every_registered_method_and_shipped_task_has_a_display_name() -> None:
    from gcnt import builtin
    from gcnt.nn.registry import BUILTIN_NETWORKS, NETWORKS

    assert set(NETWORKS) <= set(METHOD_NAMES)
    assert builtin.METHODS == BUILTIN_NETWORKS  # the torch-free list of gcnt's own methods
    assert display_name("metamorph_star") == "MetaMorph*" and display_name("gcnt_hn") == "GCNT+HN"
    shipped = set()
    for recipe in ROOT.glob("recipes/*/*.yaml"):
        found = re.search(r"^task: (\S+)$", recipe.read_text(), re.M)
        if found and not found[1].startswith("quickstart"):
            shipped.add(found[1])
    assert shipped and shipped <= set(TASKS)


def test_a_task_spelt_as_a_folder_is_shown_as_the_task() -> None:
    from gcnt.run.directory import folder_name
    from gcnt.sweep.status import slug

    for task in TASKS:
        assert display_name(folder_name(task)) == task  # runs/Walkerpp/...
        assert display_name(slug(task)) == task  # sweeps/walkerpp
    assert display_name("ppo:metamorph_star") == "MetaMorph* (PPO)"
    assert display_name("gcnt [td3.lr=0.001]") == "GCNT [td3.lr=0.001]"
    assert display_name("gcnt", {"gcnt": "Ours"}) == "Ours"
    assert display_name("SR-fair") == "SR-fair"  # a recipe's label stays


# ----------------------------------------------------------------------------- the options


def usage_error(capsys, argv: list[str]) -> str:
    """Run gcnt with a bad option: argparse's one error line (exit 2, no traceback)."""
    capsys.readouterr()
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if ": error: " in line]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def _parse(command: str, *words: str) -> argparse.Namespace:
    return build_parser(command).parse_args([command, "DIR", *words])


def test_every_figure_command_has_the_figure_options() -> None:
    from gcnt.commands.options import figure_style

    for command in FIGURE_COMMANDS:
        args = _parse(
            command,
            *("--format", "pdf,svg", "--format", "png", "--figsize", "3.4,2.5"),
            *("--font-size", "7", "--dpi", "300", "--title", "T"),
            *("--names", "gcnt=Ours,swat=SWAT-2", "--names", "amorpheus=A"),
        )
        style = figure_style(args)
        assert style == FigureStyle(
            formats=("pdf", "svg", "png"),
            figsize=(3.4, 2.5),
            font_size=7.0,
            dpi=300,
            title="T",
            names={"gcnt": "Ours", "swat": "SWAT-2", "amorpheus": "A"},
        ), command
    assert figure_style(_parse("curves")).outputs(Path("f/curves.png")) == [Path("f/curves.png")]


def test_a_names_file_and_bad_figure_options_are_one_line(tmp_path: Path, capsys) -> None:
    from gcnt.commands.options import figure_style

    names = tmp_path / "names.yaml"
    names.write_text("metamorph_star: MetaMorph*\nWalker++: Walker\n")
    style = figure_style(_parse("curves", "--names", str(names)))
    assert style.name("metamorph_star") == "MetaMorph*" and style.name("Walker++") == "Walker"
    d = str(tmp_path)
    assert "'gif' is not one of png, pdf, svg" in usage_error(
        capsys, ["curves", d, "--format", "gif"]
    )
    assert "--figsize" in usage_error(capsys, ["variants", d, "--figsize", "3"])
    assert "--font-size" in usage_error(capsys, ["embed", "--font-size", "-2"])
    assert "is not KEY=NAME" in usage_error(capsys, ["strobe", d, "--names", "gcnt"])
    bad = tmp_path / "bad.yaml"
    bad.write_text("- a list\n")
    assert "not a mapping" in usage_error(capsys, ["curves", d, "--names", str(bad)])
    with pytest.raises(ValueError, match="format 'gif'"):
        FigureStyle(formats=("gif",))


# ----------------------------------------------------------------------------- curves


def test_curves_command_writes_pdf_and_svg_with_display_names(tmp_path: Path, capsys) -> None:
    runs = tmp_path / "runs"
    for method, level in (("gcnt", 2.0), ("metamorph_star", 1.0)):
        for seed in (0, 1):
            curve_run(runs, method, seed, [600, 1200], lambda s, a=level + seed: a * s / 100)
    out = tmp_path / "fig"
    argv = ["curves", str(runs), "--out", str(out), "--format", "pdf,svg", "--font-size", "7"]
    assert main([*argv, "--names", "gcnt=Ours", "--title", "Walker++ (tiny)"]) == 0
    printed = capsys.readouterr().out
    for name in ("curves.pdf", "curves.svg", "curves.csv"):
        assert f"written: {out / name}" in printed
    assert not (out / "curves.png").exists()
    assert (out / "curves.pdf").read_bytes()[:5] == b"%PDF-"
    text = _svg_text(out / "curves.svg")
    assert "Ours (n = 2)" in text and "MetaMorph* (n = 2)" in text  # display names in the legend
    assert "metamorph_star" not in text and "gcnt" not in text
    assert "mean ± 1 s.e. (n = 2 seeds)" in text  # the interval and its n
    assert "Walker++ (tiny)" in text
    assert re.search(r"font: 7px|font-size: ?7px", (out / "curves.svg").read_text())


def _media_box(pdf: Path) -> tuple[float, float]:
    """The page size of a one-page PDF, inches (its MediaBox, in points)."""
    (box,) = set(re.findall(rb"/MediaBox\s*\[\s*([-\d.\s]+)\]", pdf.read_bytes()))
    x0, y0, x1, y1 = map(float, box.split())
    return (x1 - x0) / 72, (y1 - y0) / 72


@pytest.mark.parametrize(("tasks", "size"), [(1, (3.4, 2.6)), (3, (7.0, 2.6))])
@pytest.mark.filterwarnings("error")  # everything drawn fits: nothing cut, no layout given up
def test_curves_figsize_is_the_pdf_page_legend_included(
    tmp_path: Path, tasks: int, size: tuple[float, float]
) -> None:
    runs = tmp_path / "runs"
    for t in range(tasks):
        for method, level in (("gcnt", 2.0), ("metamorph_star", 1.0)):
            run = curve_run(runs / f"t{t}", method, 0, [600, 1200], lambda s, a=level: a * s)
            recipe = run / "recipe.yaml"  # a task of its own
            recipe.write_text(recipe.read_text().replace("task: Walker++", f"task: Task{t}"))
    out = tmp_path / "fig"
    argv = [
        "curves",
        str(runs),
        "--out",
        str(out),
        "--format",
        "pdf",
        "--figsize",
        f"{size[0]},{size[1]}",
    ]
    assert main(argv) == 0
    width, height = _media_box(out / "curves.pdf")
    assert (width, height) == (pytest.approx(size[0], abs=1e-3), pytest.approx(size[1], abs=1e-3))


@pytest.mark.parametrize("metric", ["eval", "train_return/mean"])
@pytest.mark.filterwarnings("error")  # everything drawn fits the page
def test_a_column_figure_keeps_most_of_its_height_for_the_axes(tmp_path: Path, metric) -> None:
    """At ``--figsize 3.4,2.6`` (a paper's column) with three methods and the random phase's
    line: a one-line y label, and a legend below that leaves the axes over half the page."""
    from gcnt.analysis.plotting import fit_page

    for method in ("gcnt", "swat", "amorpheus"):
        for seed in (0, 1, 2):
            curve_run(tmp_path, method, seed, [600, 1200, 1800], lambda s, a=seed: s / 100 + a)
    runs = find_runs([tmp_path])
    style = FigureStyle(figsize=(3.4, 2.6))
    rows = curves.learning_curves(runs, metric)
    label = curves.metric_label(runs, metric)
    fig = curves.curves_figure(
        rows, metric, ylabel=label, random_until=curves.random_phase(runs), style=style
    )
    with style.context():
        page = fit_page(fig, style.figsize)
    (ax,) = fig.axes
    height = ax.get_window_extent().transformed(fig.dpi_scale_trans.inverted()).height
    assert height / page.height > 0.5, height / page.height
    head, details = curves.split_label(label)
    assert ax.get_ylabel() == head and "\n" not in head
    (legend,) = fig.legends
    title = " ".join(legend.get_title().get_text().split())
    assert all(d in title for d in details) and "n = 3 seeds" in title  # nothing said is lost
    assert [t.get_text() for t in legend.get_texts()][:3] == ["GCNT", "SWAT", "AMORPHEUS"]
    plt.close(fig)


def _rows(method: str, steps, means, stderr, seeds: int, task: str = "Walkerpp") -> list[dict]:
    return [
        {"task": task, "method": method, "env_steps": s, "mean": m, "stderr": e, "seeds": seeds,
         "robots": 1, "logged": seeds}
        for s, m, e in zip(steps, means, stderr, strict=True)
    ]  # fmt: skip


def test_curve_axes_hold_every_band_and_a_single_point_has_an_error_bar() -> None:
    rows = _rows("gcnt", [100, 200, 300], [0.0, 50.0, 10.0], [5.0, 400.0, 5.0], 3)
    rows += _rows("swat", [300], [20.0], [30.0], 3)  # one evaluation: a point, no band
    rows += _rows("smp", [100, 200, 300], [1.0, math.nan, 2.0], [1.0, math.nan, 70.0], 3)
    fig = curves.curves_figure(rows)
    try:
        (ax,) = fig.axes
        low, high = ax.get_ylim()
        ends = [r["mean"] + k * r["stderr"] for r in rows for k in (-1, 1)]
        ends = [v for v in ends if math.isfinite(v)]
        assert low < min(ends) and max(ends) < high
        errorbars = [c for c in ax.containers if type(c).__name__ == "ErrorbarContainer"]
        # swat's single point and smp's two points beside its gap (a band cannot show them)
        assert sorted(len(c.lines[2][0].get_segments()) for c in errorbars) == [1, 2]
        assert ax.get_title() == "Walker++"
        (legend,) = fig.legends  # one, beside the panels, never over the data
        assert legend.get_title().get_text() == "mean ± 1 s.e. (n = 3 seeds)"
        fig.canvas.draw()
        box, panel = legend.get_window_extent(), ax.get_window_extent()
        assert box.x0 >= panel.x1
        assert [t.get_text() for t in legend.get_texts()] == [
            "GCNT (n = 3)", "SWAT (n = 3)", "SMP (n = 3)"
        ]  # fmt: skip
    finally:
        plt.close(fig)
    one = curves.curves_figure(_rows("gcnt", [1, 2], [1.0, 2.0], [math.nan] * 2, 1))
    try:
        title = one.legends[0].get_title().get_text()
        assert title == "mean ± 1 s.e. (n = 1 seed); n = 1: the value alone, no interval"
    finally:
        plt.close(one)


def test_each_of_several_random_phase_ends_is_labelled_with_its_step() -> None:
    rows = _rows("gcnt", [100, 2000, 4000], [1.0, 2.0, 3.0], [0.1] * 3, 2)
    fig = curves.curves_figure(rows, random_until={"Walkerpp": [300, 1200]})
    try:
        (ax,) = fig.axes
        assert sorted(t.get_text() for t in ax.texts) == ["1,200", "300"]
        assert [t.get_text() for t in fig.legends[0].get_texts()][-1] == "end of random actions"
    finally:
        plt.close(fig)
    one = curves.curves_figure(rows, random_until={"Walkerpp": [300]})
    try:
        assert not one.axes[0].texts  # one line: the legend says what it is
    finally:
        plt.close(one)


def test_methods_evaluated_at_one_step_stand_side_by_side() -> None:
    rows = [*_rows("gcnt", [500], [8.0], [1.0], 3), *_rows("swat", [500], [8.2], [1.0], 3)]
    fig = curves.curves_figure(rows)
    try:
        (ax,) = fig.axes
        xs = [line.get_xdata()[0] for line in ax.lines if len(line.get_xdata())]
        assert len(set(xs)) == 2 and min(xs) < 500 < max(xs)  # no point hides another
        assert list(ax.get_xticks()) == [500]  # the step they were evaluated at
    finally:
        plt.close(fig)


# ----------------------------------------------------------------------------- intervals


def test_a_bootstrap_over_two_seeds_is_not_called_a_95_ci(tmp_path: Path, capsys) -> None:
    for seed in (0, 1):
        gcnt_eval(
            variant_run(tmp_path, "gcnt", seed), {"walker_3_main": 1.0 + seed, "walker_6_main": 3.0}
        )
    out = tmp_path / "fig"
    argv = ["variants", str(tmp_path), "--sets", "test", "--reps", "200", "--out", str(out)]
    assert main([*argv, "--format", "svg", "--panels"]) == 0
    printed = capsys.readouterr().out
    assert "95% CI" not in printed and "n = 2 seeds" in printed
    assert "range of the seeds' aggregates" in printed
    item = variants.variant_summary(find_runs([tmp_path]), ["test"])["test"]["gcnt"]
    assert (item["mean"]["low"], item["mean"]["high"]) == (2.0, 2.5)  # the seeds' range
    for svg in ("variants.svg", "variants-panels.svg"):
        text = " ".join(_svg_text(out / svg).split())
        assert "95% CI" not in text and "GCNT" in text  # the caption is beside the figure
    caption = (out / "variants.caption.txt").read_text()
    assert "95% CI" not in caption and "range of the seeds'" in caption
    # five seeds: a bootstrap CI, called so with its n
    for seed in range(2, 5):
        gcnt_eval(
            variant_run(tmp_path, "gcnt", seed), {"walker_3_main": seed, "walker_6_main": 3.0}
        )
    item = variants.variant_summary(find_runs([tmp_path]), ["test"])["test"]["gcnt"]
    assert item["interval"].startswith("95% CI (n = 5 seeds): stratified percentile bootstrap")


def test_seed_range_is_the_stratified_extremes() -> None:
    assert variants.seed_range([2.0, 10.0, 4.0]) == pytest.approx((16 / 3, 2.0, 10.0))
    # two tasks: each task's lowest (highest) seed in the mean
    p, lo, hi = variants.seed_range([1.0, 3.0, 10.0, 20.0], ["A", "A", "B", "B"])
    assert (p, lo, hi) == pytest.approx((8.5, (1 + 1 + 10 + 10) / 4, (3 + 3 + 20 + 20) / 4))
    assert math.isnan(variants.seed_range([1.0, 5.0], ["A", "B"])[1])
    x = [1.0, 4.0, 2.0, 8.0, 5.0]  # five seeds: the bootstrap
    assert variants.seed_interval(x) == variants.bootstrap_ci(x)
    assert variants.seed_interval(x[:4]) == (3.75, 1.0, 8.0)


def test_gcnt_eval_table_names_its_interval_over_robots() -> None:
    from gcnt.rl.evaluate import format_table, summarize

    two = {f"r{i}": summarize([float(i), float(i) + 2]) for i in range(2)}
    line = format_table(two).splitlines()[-1]
    assert "CI" not in line and "range [1.0, 2.0] over n = 2 robots" in line
    six = {f"r{i}": summarize([float(i), float(i) + 2]) for i in range(6)}
    line = format_table(six).splitlines()[-1]
    assert "95% CI [" in line and "(bootstrap over n = 6 robots)" in line


# ----------------------------------------------------------------------------- bold


def test_separated_best_needs_intervals_that_do_not_overlap() -> None:
    best = intervals.separated_best
    assert best({"a": (10.0, 9.0, 11.0), "b": (5.0, 4.0, 6.0)}) == "a"
    assert best({"a": (10.0, 8.0, 12.0), "b": (7.0, 5.0, 9.0)}) is None  # overlap
    assert best({"a": (10.0, 9.0, 11.0), "b": (8.0, 7.0, 9.0)}) is None  # touching
    assert best({"a": (10.0, math.nan, math.nan), "b": (1.0, 0.0, 2.0)}) is None  # no interval
    assert best({"a": (10.0, 9.0, 11.0)}) is None  # nothing to beat


def _cell(mean: float, se: float, seeds: int = 3) -> dict:
    return {"mean": mean, "stderr": se, "seeds": seeds, "protocol": "p"}


def test_zeroshot_bolds_only_separated_bests_in_markdown_and_latex(tmp_path: Path) -> None:
    rows = {
        "far": {"gcnt": _cell(100.0, 2.0), "metamorph_star": _cell(50.0, 2.0)},
        "close": {"gcnt": _cell(100.0, 20.0), "metamorph_star": _cell(90.0, 20.0)},
        "one_seed": {"gcnt": _cell(100.0, math.nan, 1), "metamorph_star": _cell(1.0, 0.5)},
    }
    best = {robot: max(row, key=lambda m, row=row: row[m]["mean"]) for robot, row in rows.items()}
    table = {"Walkerpp": {"robots": list(rows), "methods": ["gcnt", "metamorph_star"],
                          "cells": rows, "best": best, "protocol": "deterministic actions"}}  # fmt: skip
    md = zeroshot.to_markdown(table)
    assert "| robot | GCNT | MetaMorph* |" in md and "### Walker++" in md
    assert "| far | **100.0 ± 2.0** | 50.0 ± 2.0 |" in md
    assert "| close | 100.0 ± 20.0 | 90.0 ± 20.0 |" in md
    assert "| one_seed | 100.0 | 1.0 ± 0.5 |" in md
    assert "Cells: mean ± 1 s.e. (n = 1–3 seeds); n = 1: the value alone, no interval." in md
    tex = zeroshot.to_latex(table, FigureStyle(names={"gcnt": "Ours"}))
    assert r"Robot & Ours & MetaMorph* \\" in tex
    assert r"far & \textbf{100.0 $\pm$ 2.0} & 50.0 $\pm$ 2.0 \\" in tex
    assert r"close & 100.0 $\pm$ 20.0 & 90.0 $\pm$ 20.0 \\" in tex
    assert r"one\_seed & 100.0 & 1.0 $\pm$ 0.5 \\" in tex
    assert tex.count(r"\textbf") == 1 and "Walker++" in tex
    written = zeroshot.write(table, tmp_path)
    assert [p.name for p in written] == ["zeroshot.md", "zeroshot.tex", "zeroshot.json"]


# ----------------------------------------------------------------------------- variant sets


def _summary(name: str = "walker_*") -> dict:
    """A one-set summary of two methods; the set named by a robot name pattern."""
    scores = {"seed0": {"walker_2_main": 1.0, "walker_3_main": 2.0, "walker_7_main": 3.0,
                        "walker_4_main": 1.0}}  # fmt: skip
    entry = {}
    for m, p in (("gcnt", 10.0), ("metamorph_star", -40.0)):
        entry[m] = {"robots": 4, "seeds": 2, "scores": scores, "interval": "range (n = 2 seeds)",
                    "protocol": "p", "mean": {"point": p, "low": p - 100.0, "high": p + 300.0}}  # fmt: skip
    return {name: entry}


def test_a_pattern_is_never_a_title_and_panels_hold_every_interval() -> None:
    summary = _summary()
    fig = bars.bar_figure(summary, style=FigureStyle(figsize=(4.0, 3.0), title="Figure 8"))
    try:
        (ax,) = fig.axes
        assert "*" not in ax.get_title()
        assert ax.get_title().startswith("walker_2_main, walker_3_main, …, walker_7_main (4 robots")
        assert [t.get_text() for t in ax.get_xticklabels()] == ["GCNT", "MetaMorph*"]
        assert fig._suptitle.get_text() == "Figure 8"  # the caption goes beside the figure
        assert "Error bars: range (n = 2 seeds)." in bars.caption(summary)
        assert tuple(fig.get_size_inches()) == (4.0, 3.0)
    finally:
        plt.close(fig)
    fig = variants.panels_figure(summary, style=FigureStyle(names={"walker_*": "Walkers"}))
    try:
        (ax,) = fig.axes
        low, high = ax.get_xlim()
        assert low < -140.0 and 310.0 < high  # every interval, with a margin
        assert ax.get_title() == "Walkers: mean return"
        assert [t.get_text() for t in ax.get_yticklabels()] == ["GCNT", "MetaMorph*"]
    finally:
        plt.close(fig)
    md = variants.to_markdown(summary)
    assert "### walker_2_main, walker_3_main, …, walker_7_main" in md
    assert "| MetaMorph* | 4 | 2 |" in md and "mean [interval]" in md


# ----------------------------------------------------------------------------- others


def test_strobe_embed_and_tables_take_the_style(tmp_path: Path, capsys) -> None:
    images = [np.full((40, 160, 3), 200, dtype=np.uint8)] * 2
    style = FigureStyle(figsize=(5.0, 2.0), title="Figure 11", font_size=6)
    fig = strobe.strobe_figure(images, ["GCNT", "SWAT"], title="default", style=style)
    try:
        assert tuple(fig.get_size_inches()) == (5.0, 2.0)
        assert fig._suptitle.get_text() == "Figure 11"
        assert fig.axes[0].yaxis.label.get_fontsize() == pytest.approx(6.0)  # "medium" at 6 pt
    finally:
        plt.close(fig)
    from gcnt.analysis.tables import rows_to_markdown

    md = rows_to_markdown([{"method": "metamorph_star", "actor": 1, "critic": 2}], FigureStyle())
    assert "| MetaMorph* | 1 | 2 | 3 |" in md
    out = tmp_path / "fig"
    argv = ["embed", "--untrained", "gcnt,swat", "--robots", "Walker++:all", "--out", str(out)]
    assert main([*argv, "--format", "svg", "--names", "swat=SWAT (ours)"]) == 0
    text = _svg_text(out / "embed.svg")
    assert "GCNT (untrained)" in text and "SWAT (ours) (untrained)" in text
    assert f"written: {out / 'embed.svg'}" in capsys.readouterr().out
