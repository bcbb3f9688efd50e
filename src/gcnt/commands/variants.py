"""``gcnt variants DIR... --sets variants-kinematics,variants-dynamics``: returns on robot variant sets (paper
figure 8) per method, with 95% stratified bootstrap confidence intervals (scipy).

A set name matches an evaluation's label or part of its robot spec (``gcnt eval RUN --robots
SPEC``). ``--iqm`` adds the interquartile mean, ``--profile`` performance profiles. Writes
``variants.png``, ``variants.md`` and ``variants.json``.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

log = logging.getLogger(__name__)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("paths", nargs="+", metavar="DIR", help="run or sweep directories")
    p.add_argument(
        "--sets",
        default="variants-kinematics,variants-dynamics",
        help="comma-separated evaluation labels / robot specs (default: variants-kinematics,variants-dynamics, the UNIMAL splits)",
    )
    p.add_argument("--iqm", action="store_true", help="also the interquartile mean (IQM)")
    p.add_argument("--profile", action="store_true", help="also performance profiles")
    p.add_argument("--reps", type=int, default=2000, help="bootstrap resamples (default 2000)")
    p.add_argument("--confidence", type=float, default=0.95, help="interval level (0.95)")
    p.add_argument("--out", type=Path, help="output folder (default: <DIR>/figures)")
    p.add_argument("--name", default="variants", help="file name stem (default: variants)")


def run(args: argparse.Namespace) -> int:
    from gcnt.analysis import variants as V
    from gcnt.analysis.runs import AnalysisError, default_out, find_runs

    stats = ("mean", "iqm") if args.iqm else ("mean",)
    sets = [s.strip() for s in args.sets.split(",") if s.strip()]
    try:
        runs = find_runs(args.paths)
        summary = V.variant_summary(runs, sets, stats, args.confidence, args.reps)
    except AnalysisError as e:
        log.error("%s", e)
        return 2
    out = args.out or default_out(args.paths)
    png = V.plot(summary, out / f"{args.name}.png", stats, args.profile)
    md = out / f"{args.name}.md"
    md.write_text(V.to_markdown(summary, stats))
    js = V.write_json(summary, out / f"{args.name}.json")
    print(V.to_markdown(summary, stats))
    missing = [s for s in sets if s not in summary]
    if missing:
        print(f"no evaluations for: {', '.join(missing)}")
    print(f"written: {png}\nwritten: {md}\nwritten: {js}")
    return 0
