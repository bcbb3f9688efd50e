"""``gcnt strobe DIR... [--robot humanoid_2d_9_full]``: a strobe picture of one rollout per run
(paper figure 11): poses along the path in one image, rendered headless with MuJoCo (EGL).

In a sweep directory, one picture per method (its first seed) unless ``--all-seeds``.
Writes ``strobe-<robot>-<task>-<algo>-<method>-seed<N>.png``.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

log = logging.getLogger(__name__)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("paths", nargs="+", metavar="DIR", help="run or sweep directories")
    p.add_argument("--robot", default="humanoid_2d_9_full", help="robot name or file")
    p.add_argument("--steps", type=int, default=300, help="control steps at most (default 300)")
    p.add_argument("--frames", type=int, default=8, help="poses in the picture (default 8)")
    p.add_argument("--all-seeds", action="store_true", help="a picture per run")
    p.add_argument("--seed", type=int, default=0, help="env seed")
    p.add_argument("--out", type=Path, help="output folder (default: <DIR>/figures)")


def run(args: argparse.Namespace) -> int:
    from gcnt.analysis.runs import AnalysisError, default_out, find_runs, first_seed_per_method
    from gcnt.analysis.strobe import strobe_run

    try:
        runs = find_runs(args.paths)
        if not args.all_seeds:
            runs = first_seed_per_method(runs)
        out = args.out or default_out(args.paths)
        for r in runs:
            path = strobe_run(
                r, out, robot=args.robot, steps=args.steps, frames=args.frames, seed=args.seed
            )
            print(f"written: {path}")
    except AnalysisError as e:
        log.error("%s", e)
        return 2
    return 0
