"""The ``gcnt`` command. Each sub-command lives in ``gcnt.commands.<name>`` and provides
``add_arguments(parser)`` and ``run(args) -> int``; register it in ``COMMANDS``."""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

#: sub-command name -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "robots": (
        "gcnt.commands.robots",
        "list robots and benchmarks; rebuild the SMPENV robot files",
    ),
    "train": ("gcnt.commands.train", "train a policy from a recipe, or resume a run"),
    "eval": ("gcnt.commands.eval", "evaluate a run's deterministic policy per robot"),
    "params": ("gcnt.commands.params", "parameter counts of every method (paper tables 7-8)"),
    "bench-nn": ("gcnt.commands.bench_nn", "forward+backward time of GCNT vs AMORPHEUS (TD3)"),
    "bench-learn": (
        "gcnt.commands.bench_learn",
        "learning check: a recipe beats the random policy",
    ),
    "bench-train": (
        "gcnt.commands.bench_train",
        "training env steps/s against the bare TD3 update",
    ),
    "bench-env": ("gcnt.commands.bench_env", "measure SMPEnv steps/s against a raw mj_step loop"),
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="gcnt", description=__doc__.splitlines()[0])
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (module, help_) in COMMANDS.items():
        p = sub.add_parser(name, help=help_, description=help_)
        importlib.import_module(module).add_arguments(p)
        p.set_defaults(_module=module)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    # Configure gcnt's own logger: libraries imported above (absl via dm_control) may already
    # have put a handler on the root logger, which would make logging.basicConfig a no-op.
    handler = logging.StreamHandler()
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    gcnt_log = logging.getLogger("gcnt")
    gcnt_log.handlers[:] = [handler]
    gcnt_log.setLevel(logging.DEBUG if args.verbose else logging.INFO)
    gcnt_log.propagate = False
    return int(importlib.import_module(args._module).run(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
