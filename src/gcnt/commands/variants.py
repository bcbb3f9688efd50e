r"""``gcnt variants DIR... --sets variants-kinematics,variants-dynamics``: returns on robot variant
sets (paper figure 8) per method, with intervals over seeds of each seed's aggregate over the
set's robots: a 95% confidence interval from a stratified bootstrap (rliable's interval for few
runs) where every task has at least 5 seeds, else the range of the seeds' aggregates, called so.
Every table and figure names its interval and its n.

A set name is an evaluation's label, its robot spec or the spec's split (``gcnt eval RUN --robots
SPEC``); inside a larger evaluation it selects the robots of the spec it names, never more.
Tables say which protocol (deterministic or sampled actions, episodes per robot) the numbers come
from. The figure is the paper's figure 8: a group of bars per method with those intervals as error
bars, one panel per set (:mod:`gcnt.analysis.bars`); ``--panels`` also writes the rliable-style panels
(point estimates with intervals, ``--profile``: and performance profiles) as
``variants-panels.png``. ``--iqm`` adds the interquartile mean. Writes ``variants.png``
(``--format pdf,svg``: those; the figure options set size, fonts, title and display names; a
robot name pattern as a set is shown as the robots it matched), ``variants.md``,
``variants.json``, and the figure's caption beside it (never in its title): what the error bars
are, the evaluation protocol and the gcnt versions and commits of the runs, as
``variants.caption.txt``, as ``variants.caption.tex`` (``\caption{...}``) and as the last line
of the Markdown.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from gcnt.commands.options import add_figure_options, check_names, figure_style
from gcnt.files import write_text


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("paths", nargs="+", metavar="DIR", help="run or sweep directories")
    p.add_argument(
        "--sets",
        default="variants-kinematics,variants-dynamics",
        help="comma-separated evaluation labels / robot specs (default: variants-kinematics,variants-dynamics, the UNIMAL splits)",
    )
    p.add_argument("--iqm", action="store_true", help="also the interquartile mean (IQM)")
    p.add_argument(
        "--panels",
        action="store_true",
        help="also the rliable-style interval panels (<name>-panels.png)",
    )
    p.add_argument(
        "--profile", action="store_true", help="with --panels: also performance profiles"
    )
    p.add_argument("--reps", type=int, default=2000, help="bootstrap resamples (default 2000)")
    p.add_argument("--seed", type=int, default=0, help="seed of the bootstrap's draws (0)")
    p.add_argument(
        "--confidence",
        type=float,
        default=0.95,
        help="bootstrap interval level (0.95; with 5 or more seeds per task)",
    )
    p.add_argument(
        "--out",
        type=Path,
        help="output folder (default: <DIR>/figures; a run directory's beside it, <RUN>-figures)",
    )
    p.add_argument("--name", default="variants", help="file name stem (default: variants)")
    add_figure_options(p)


def run(args: argparse.Namespace) -> int:
    from gcnt.analysis import variants as V
    from gcnt.analysis.names import run_keys
    from gcnt.analysis.runs import AnalysisError, default_out, find_runs
    from gcnt.run import provenance

    stats = ("mean", "iqm") if args.iqm else ("mean",)
    sets = [s.strip() for s in args.sets.split(",") if s.strip()]
    runs = find_runs(args.paths)
    check_names(args, run_keys(runs) | set(sets))
    if args.reps < 1 or not 0 < args.confidence < 1:
        raise AnalysisError(
            f"--reps must be >= 1 and --confidence in (0, 1); got {args.reps}, {args.confidence}"
        )
    summary = V.variant_summary(runs, sets, stats, args.confidence, args.reps, args.seed)
    out = args.out or default_out(args.paths)
    from gcnt.analysis.bars import caption as figure_caption
    from gcnt.analysis.bars import plot_bars
    from gcnt.analysis.zeroshot import tex_text

    style = figure_style(args)
    plot_bars(summary, out / f"{args.name}.png", stats, style=style)
    figures = style.outputs(out / f"{args.name}.png")
    if args.panels or args.profile:
        V.plot(summary, out / f"{args.name}-panels.png", stats, args.profile, style)
        figures += style.outputs(out / f"{args.name}-panels.png")
    code = provenance.caption(r.path for r in runs)
    caption = f"{figure_caption(summary)} {code[0].upper()}{code[1:]}."
    md = out / f"{args.name}.md"
    write_text(md, f"{V.to_markdown(summary, stats, style)}\n_{caption}_\n")
    tex = out / f"{args.name}.caption.tex"
    write_text(tex, f"\\caption{{{tex_text(caption)}}}\n")
    js = V.write_json(summary, out / f"{args.name}.json")
    print(V.to_markdown(summary, stats, style))
    missing = [s for s in sets if s not in summary]
    if missing:
        print(f"no evaluations for: {', '.join(missing)}")
    print(caption)
    cap = provenance.write_caption(caption, out / f"{args.name}.caption.txt")
    for path in [*figures, md, js, cap, tex]:
        print(f"written: {path}")
    return 0
