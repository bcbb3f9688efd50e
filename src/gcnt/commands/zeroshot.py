"""``gcnt zeroshot DIR...``: the zero-shot table (paper table 1) from run directories.

Per test robot, mean ± 1 standard error over seeds of each seed's mean return; a row's best
mean in bold where its interval lies above the runner-up's; each table says which protocol (deterministic or sampled actions, episodes per
robot) its numbers come from. Reads the runs' evaluations (``eval/*.json``); ``--evaluate`` first
runs ``gcnt eval RUN --robots test`` (the recipe's protocol; ``--episodes N``) on every run that
has none. Writes ``zeroshot.md``, ``zeroshot.tex`` (methods by display name: ``--names``),
``zeroshot.json`` and ``zeroshot.caption.txt``: the gcnt versions and commits of the runs the
table shows (also the last line of the Markdown and a comment of the LaTeX).
"""

from __future__ import annotations

import argparse
import logging
import subprocess
from pathlib import Path

from gcnt.commands.options import add_names_option, check_names, table_style

log = logging.getLogger(__name__)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("paths", nargs="+", metavar="DIR", help="run or sweep directories")
    p.add_argument("--robots", nargs="+", help="rows (default: the recipes' test robots)")
    p.add_argument("--label", help="only evaluations with this label / robot spec (default: any)")
    p.add_argument(
        "--evaluate",
        action="store_true",
        help="first run `gcnt eval RUN --robots test` on runs without a test evaluation",
    )
    p.add_argument("--force", action="store_true", help="with --evaluate: evaluate every run")
    p.add_argument(
        "--episodes",
        type=int,
        help="with --evaluate: episodes per robot (default: 100 deterministic, 32 stochastic, "
        "as the recipe's eval.deterministic)",
    )
    p.add_argument(
        "--out",
        type=Path,
        help="output folder (default: <DIR>/figures; a run directory's beside it, <RUN>-figures)",
    )
    add_names_option(p)


def _evaluate(runs, episodes: int | None, force: bool) -> int:
    import os

    from gcnt.analysis.zeroshot import seed_score
    from gcnt.sweep import gcnt_command, pinned_env

    failures = 0
    for r in runs:
        names = r.test_robot_names()
        if not names:
            log.warning("%s: the recipe has no test robots; skipped", r.path)
            continue
        evals = r.evals()
        if (
            not force
            and all(seed_score(evals, n) for n in names)
            and any(e.matches("test") for e in evals)
        ):
            continue
        argv = [*gcnt_command(), "eval", str(r.path), "--robots", "test"]
        if episodes is not None:
            argv += ["--episodes", str(episodes)]
        print(f"evaluating {r.path} ...", flush=True)
        threads = int(os.environ.get("OMP_NUM_THREADS", "1"))
        rc = subprocess.run(argv, env=pinned_env(threads)).returncode
        failures += rc != 0
    return failures


def run(args: argparse.Namespace) -> int:
    from gcnt.analysis.names import run_keys
    from gcnt.analysis.runs import default_out, find_runs
    from gcnt.analysis.zeroshot import shown_runs, to_markdown, write, zero_shot_table
    from gcnt.run import provenance

    runs = find_runs(args.paths)
    check_names(args, run_keys(runs))
    if args.evaluate and _evaluate(runs, args.episodes, args.force):
        log.error("some evaluations failed (see above)")
        return 1
    table = zero_shot_table(runs, args.robots, args.label)
    out = args.out or default_out(args.paths)
    style = table_style(args)
    caption = provenance.caption(r.path for r in shown_runs(table, runs))  # the runs it shows
    written = write(table, out, style=style, caption=caption)
    print(to_markdown(table, style))
    print(caption)
    for path in [*written, provenance.write_caption(caption, out / "zeroshot.caption.txt")]:
        print(f"written: {path}")
    return 0
