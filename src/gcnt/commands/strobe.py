"""``gcnt strobe DIR... [--robot humanoid_2d_9_full]``: one strobe picture of the runs' rollouts
(paper figure 11): a row per run with its poses along the path over a floor marked in metres,
rendered headless with MuJoCo (EGL).

In a sweep directory, one row per method (its first seed) unless ``--all-seeds``. Poses are spaced
in time, or by the root's x position (at least ``--min-gap`` m apart) for a policy that barely
moves. Rows are labelled with the methods' display names. Writes ``strobe-<robot>-<task>.png``
(``--name`` to choose the stem; ``--format pdf,svg``: those; the figure options set size, fonts,
title and names).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from gcnt.commands.options import add_figure_options, check_names, figure_style


def add_arguments(p: argparse.ArgumentParser) -> None:
    from gcnt.analysis.strobe import MIN_GAP

    p.add_argument("paths", nargs="+", metavar="DIR", help="run or sweep directories")
    p.add_argument("--robot", default="humanoid_2d_9_full", help="robot name or file")
    p.add_argument("--steps", type=int, default=300, help="control steps at most (default 300)")
    p.add_argument("--frames", type=int, default=8, help="poses per row at most (default 8)")
    p.add_argument(
        "--min-gap",
        type=float,
        default=MIN_GAP,
        help=f"least root x distance (m) between poses of a barely moving robot (default {MIN_GAP})",
    )
    p.add_argument("--all-seeds", action="store_true", help="a row per run, not per method")
    p.add_argument("--seed", type=int, default=0, help="env seed")
    p.add_argument(
        "--out",
        type=Path,
        help="output folder (default: <DIR>/figures; a run directory's beside it, <RUN>-figures)",
    )
    p.add_argument("--name", help="file name stem (default: strobe-<robot>-<task>)")
    add_figure_options(p)


def run(args: argparse.Namespace) -> int:
    from gcnt.analysis.names import run_keys
    from gcnt.analysis.runs import AnalysisError, default_out, find_runs, first_seed_per_method
    from gcnt.analysis.strobe import strobe_runs

    style = figure_style(args)
    if args.frames < 1 or args.steps < 1 or args.min_gap < 0:
        raise AnalysisError(
            f"--frames and --steps must be positive and --min-gap not negative "
            f"(got {args.frames}, {args.steps}, {args.min_gap})"
        )
    runs = find_runs(args.paths)
    check_names(args, run_keys(runs))
    if not args.all_seeds:
        runs = first_seed_per_method(runs)
    out = args.out or default_out(args.paths)
    path = strobe_runs(
        runs,
        out,
        robot=args.robot,
        steps=args.steps,
        frames=args.frames,
        seed=args.seed,
        min_gap=args.min_gap,
        name=args.name,
        style=style,
    )
    for written in style.outputs(path):
        print(f"written: {written}")
    return 0
