"""Command-line options that several commands share."""

from __future__ import annotations

import argparse


def add_eval_protocol(p: argparse.ArgumentParser, dest: str, what: str = "") -> None:
    """``--deterministic`` / ``--stochastic`` (mutually exclusive) into ``dest``: True, False,
    or None (the run's recipe ``eval.deterministic`` decides). ``what`` prefixes the help."""
    mode = p.add_mutually_exclusive_group()
    mode.add_argument(
        "--deterministic",
        dest=dest,
        action="store_const",
        const=True,
        default=None,
        help=f"{what}the policy's mean action (default: the run's eval.deterministic)",
    )
    mode.add_argument(
        "--stochastic",
        dest=dest,
        action="store_const",
        const=False,
        help=f"{what}actions sampled from the policy (ModuMorph's PPO protocol; default: the "
        "run's eval.deterministic)",
    )
