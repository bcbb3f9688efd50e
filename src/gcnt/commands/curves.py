"""``gcnt curves DIR...``: learning curves (paper figures 6, 7, 9) from run directories.

One panel per task, one line per method: the mean over seeds with a band of ± 1 standard error
(the legend says so and gives each method's number of seeds) against environment steps, at the
logged steps (seeds that log at different steps interpolated onto the union of
their steps), each marked. ``--metric eval`` plots the return of the evaluations made during
training (``eval/step<N>.json``, the curve of the paper's figures) instead of the exploring
training return; a dotted line marks the end of TD3's random-action phase. Per-robot runs
(``gcnt sweep --per-robot``: SR-fair, SR-top) are averaged over the robots of each seed first; a
recipe's ``label`` names its line. Several directories go into the same figure (e.g. a world's
universal sweep and its SR sweep). Writes ``curves.png`` (``--format pdf,svg``: those files;
size, fonts, title and display names as the figure options say) and ``curves.csv`` (to
``--out``, default ``<DIR>/figures``, or beside a run directory given alone: ``<RUN>-figures``),
and ``curves.caption.txt``: the gcnt versions and commits
the runs come from (their ``provenance.json``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from gcnt.commands.options import add_figure_options, check_names, figure_style


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("paths", nargs="+", metavar="DIR", help="run or sweep directories")
    p.add_argument(
        "--metric",
        default="train_return/mean",
        help="a metrics.jsonl column (default train_return/mean, the exploring training "
        "return), or eval: the training evaluations' return over the training robots "
        "(eval/ROBOT: one robot)",
    )
    p.add_argument(
        "--points",
        type=int,
        help="an even grid of N steps per curve (default: the logged steps)",
    )
    p.add_argument("--smooth", type=int, default=1, help="moving average over N log rows (off)")
    p.add_argument(
        "--out",
        type=Path,
        help="output folder (default: <DIR>/figures; a run directory's beside it, <RUN>-figures)",
    )
    p.add_argument("--name", default="curves", help="file name stem (default: curves)")
    p.add_argument(
        "--per-seed",
        action="store_true",
        help="also <name>.seeds.csv: every run's own logged points (task, method, seed, "
        "env steps, the metric; for the exploring return also its episodes' mean length), "
        "what a verdict can be re-tested from",
    )
    add_figure_options(p)


def run(args: argparse.Namespace) -> int:
    from gcnt.analysis import curves as C
    from gcnt.analysis.names import run_keys
    from gcnt.analysis.runs import AnalysisError, default_out, find_runs

    if args.points is not None and args.points < 2:
        raise AnalysisError(f"--points must be >= 2, got {args.points}")
    runs = find_runs(args.paths)
    check_names(args, run_keys(runs))
    rows = C.learning_curves(runs, args.metric, args.points, max(1, args.smooth))
    out = args.out or default_out(args.paths)
    ylabel = C.metric_label(runs, args.metric)
    style = figure_style(args)
    C.plot_curves(
        rows,
        out / f"{args.name}.png",
        args.metric,
        ylabel=ylabel,
        random_until=C.random_phase(runs),
        style=style,
    )
    print(ylabel.replace("\n", "; "))
    csv = C.write_csv(rows, out / f"{args.name}.csv")
    groups = list(dict.fromkeys((r["task"], r["method"], r["seeds"], r["robots"]) for r in rows))
    for task, method, seeds, robots in groups:
        last = [r for r in rows if r["task"] == task and r["method"] == method][-1]
        se = f" ± {last['stderr']:.1f} (1 s.e.)" if last["stderr"] == last["stderr"] else ""
        per = f" x {robots} robots" if robots > 1 else ""
        length = last.get("length_mean")
        length = f", episodes of {length:.0f} steps" if length is not None else ""
        print(
            f"{task:<12} {method:<14} seeds {seeds}{per}  at {last['env_steps']:>9} steps: "
            f"{last['mean']:.1f}{se}{length}"
        )
    written = [*style.outputs(out / f"{args.name}.png"), csv]
    if args.per_seed:
        seeds = C.seeds_rows(runs, args.metric)
        written.append(C.write_seeds_csv(seeds, args.metric, out / f"{args.name}.seeds.csv"))
    for path in written:
        print(f"written: {path}")
    _caption(runs, out / f"{args.name}.caption.txt")
    return 0


def _caption(runs: list, path: Path) -> None:
    """Print and write the code the runs come from (gcnt versions and commits)."""
    from gcnt.run import provenance

    text = provenance.caption(r.path for r in runs)
    print(f"{text}\nwritten: {provenance.write_caption(text, path)}")
