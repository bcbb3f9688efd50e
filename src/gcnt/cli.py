"""The ``gcnt`` command: train and evaluate morphology-agnostic policies, and inspect robots,
networks, runs and speed.

Each sub-command lives in ``gcnt.commands.<name>`` and provides ``add_arguments(parser)`` and
``run(args) -> int``; register it in ``COMMANDS``. Only the chosen sub-command's module is
imported, so ``gcnt --help`` and a misspelt command answer at once (torch is not loaded).

A mistake in what the user gave (a recipe, robot file, override, checkpoint, directory) is one
line naming the culprit and exit code 2; ``-v`` adds the traceback. A sub-command's options and
its positional words (recipe, ``key=value`` overrides) may come in any order.

``--plugin MODULE`` (anywhere, repeatable), the variable GCNT_PLUGINS and the ``gcnt.plugins``
entry points name modules imported before the command runs (:mod:`gcnt.plugins`).
"""

from __future__ import annotations

import argparse
import errno
import importlib
import logging
import os
import sys

import gcnt
from gcnt import plugins
from gcnt.run import provenance
from gcnt.suggest import did_you_mean

#: sub-command name -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "robots": ("gcnt.commands.robots", "list, check and generate robots and benchmarks"),
    "import-unimal": (
        "gcnt.commands.import_unimal",
        "register MetaMorph's published UNIMAL-100 robots (the paper's) as a benchmark",
    ),
    "train": ("gcnt.commands.train", "train a policy from a recipe, or resume a run"),
    "eval": ("gcnt.commands.eval", "evaluate a run's policy per robot (zero-shot included)"),
    "params": ("gcnt.commands.params", "parameter counts of every method (paper tables 7-8)"),
    "bench-nn": ("gcnt.commands.bench_nn", "forward+backward time of GCNT vs its Transformer base"),
    "bench-learn": (
        "gcnt.commands.bench_learn",
        "learning check: a recipe beats the random policy",
    ),
    "bench-train": (
        "gcnt.commands.bench_train",
        "training env steps/s against the bare update",
    ),
    "bench-env": ("gcnt.commands.bench_env", "env steps/s against a raw mj_step loop"),
    "sweep": (
        "gcnt.commands.sweep",
        "run a grid of recipes x methods x seeds, locally or on Slurm",
    ),
    "curves": ("gcnt.commands.curves", "learning curves over seeds (paper figures 6, 7, 9)"),
    "zeroshot": ("gcnt.commands.zeroshot", "zero-shot table over seeds (paper table 1)"),
    "variants": ("gcnt.commands.variants", "returns on variant sets over seeds (figure 8)"),
    "embed": ("gcnt.commands.embed", "t-SNE of per-limb structural vectors (figure 10)"),
    "strobe": (
        "gcnt.commands.strobe",
        "one strobe picture of the runs' rollouts, a row per method (figure 11)",
    ),
    "tables": ("gcnt.commands.tables", "parameter tables as Markdown (tables 7-8)"),
}


def _user_errors() -> tuple[type[BaseException], ...]:
    """Exceptions that mean bad input (reported in one line, exit 2), imported lazily."""
    from gcnt.recipes import RecipeError

    errors: list[type[BaseException]] = [RecipeError, FileExistsError, FileNotFoundError]
    for module, names in (
        ("gcnt.morphology.robot", ("RobotFileError",)),
        (
            "gcnt.morphology.catalogues",
            ("UnknownRobotError", "BenchmarkFileError", "DuplicateRobotError"),
        ),
        ("gcnt.envs.robot_table", ("RobotTooLargeError",)),
        ("gcnt.run.directory", ("CheckpointError", "RunDirError")),
        ("gcnt.rl.loop", ("TrainingDivergedError",)),
        ("gcnt.rl.worker_watch", ("WorkerDiedError",)),
        ("gcnt.rl.evaluate", ("PolicyMismatchError",)),
        ("gcnt.analysis.runs", ("AnalysisError",)),
        ("gcnt.plugins", ("PluginError",)),
        ("gcnt.extras", ("MissingExtraError",)),
    ):
        mod = sys.modules.get(module)
        errors += [getattr(mod, n) for n in names if mod is not None and hasattr(mod, n)]
    return tuple(errors)


def _command_of(argv: list[str]) -> str | None:
    """The sub-command named in ``argv`` (the first word that is not an option)."""
    for word in argv:
        if not word.startswith("-"):
            return word
    return None


class IntermixedParser(argparse.ArgumentParser):
    """A sub-command's parser: options may come before, between or after the positional words
    (``gcnt train RECIPE --seeds 0,1 key=value``). Parsers with a REMAINDER positional (``gcnt
    sweep``, which sorts its words itself) parse as usual."""

    _inside = False

    def parse_known_args(self, args=None, namespace=None):
        remainder = any(
            a.nargs in (argparse.REMAINDER, argparse.PARSER) for a in self._get_positional_actions()
        )
        if self._inside or remainder:
            return super().parse_known_args(args, namespace)
        # parse_known_intermixed_args parses twice through parse_known_args
        self._inside = True
        try:
            return self.parse_known_intermixed_args(args, namespace)
        finally:
            self._inside = False


def build_parser(only: str | None) -> argparse.ArgumentParser:
    """The parser; the arguments of sub-command ``only`` are added (its module is imported)."""
    parser = argparse.ArgumentParser(
        prog="gcnt",
        description="Train and evaluate morphology-agnostic policies (GCNT and its baselines) "
        "on SMPENV and UNIMAL robots.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging, tracebacks")
    parser.add_argument(
        "--plugin",
        action="append",
        metavar="MODULE",
        help="import MODULE (my_pkg.methods, or a .py file) before the command runs: the "
        "methods, benchmarks and algorithms it registers become names every command takes; "
        "repeatable, anywhere on the line; runs record it (also: GCNT_PLUGINS=a,b and the "
        "gcnt.plugins entry points)",
    )
    parser.add_argument(
        "--version",
        action="version",
        version=f"gcnt {gcnt.__version__}",
        help="show gcnt's version (with --verbose first: also the package versions it is tested "
        "with, beside this environment's)",
    )
    sub = parser.add_subparsers(
        dest="command", required=True, metavar="COMMAND", parser_class=IntermixedParser
    )
    for name, (module, help_) in COMMANDS.items():
        p = sub.add_parser(name, help=help_, description=help_)
        p.add_argument(  # taken out of the command line before parsing (see main)
            "--plugin", action="append", metavar="MODULE", help="import MODULE first (gcnt --help)"
        )
        if name == only:
            importlib.import_module(module).add_arguments(p)
        p.set_defaults(_module=module)
    return parser


def _configure_logging(verbose: bool) -> None:
    # Configure gcnt's own logger: libraries (absl via dm_control) may already have put a
    # handler on the root logger, which would make logging.basicConfig a no-op.
    handler = logging.StreamHandler()
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    gcnt_log = logging.getLogger("gcnt")
    gcnt_log.handlers[:] = [handler]
    gcnt_log.setLevel(logging.DEBUG if verbose else logging.INFO)
    gcnt_log.propagate = False
    # torchrl's info lines (a storage initialised, ...) stay out of the logs; torchrl sets its
    # logger's level from RL_LOGGING_LEVEL when it is imported
    level = "INFO" if verbose else os.environ.get("RL_LOGGING_LEVEL", "WARNING")
    os.environ["RL_LOGGING_LEVEL"] = level
    logging.getLogger("torchrl").setLevel(level)


def _plugin_words(argv: list[str]) -> tuple[list[str], list[str]]:
    """(``argv`` without its ``--plugin X`` / ``--plugin=X`` words, the plugins named)."""
    rest, named = [], []
    words = iter(argv)
    for word in words:
        if word == "--plugin":
            value = next(words, None)
            if value is None or value.startswith("-"):
                raise plugins.PluginError("--plugin needs a module name or a .py file")
            named.append(value)
        elif word.startswith("--plugin="):
            named.append(word.split("=", 1)[1])
        else:
            rest.append(word)
    return rest, named


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    given = list(argv)
    try:
        argv, named = _plugin_words(argv)
    except plugins.PluginError as e:
        print(f"gcnt: error: {e}", file=sys.stderr)
        return 2
    command = _command_of(argv)
    if command is None and "--version" in argv and ({"-v", "--verbose"} & set(argv)):
        print(provenance.versions_report())
        return 0
    if command is not None and command not in COMMANDS:
        print(
            f"gcnt: unknown command {command!r}{did_you_mean(command, COMMANDS)} "
            f"(commands: {', '.join(COMMANDS)}; see gcnt --help)",
            file=sys.stderr,
        )
        return 2
    if command is not None:
        try:  # before the command's options are built: they may list registered names
            plugins.start_session(named)
        except plugins.PluginError as e:
            if "-v" in argv or "--verbose" in argv:
                raise
            print(f"gcnt {command}: error: {_one_line(str(e))}", file=sys.stderr)
            return 2
    try:
        return _run(argv, given, command)
    finally:
        plugins.end_session()  # a later command of this process names its own


def _run(argv: list[str], given: list[str], command: str | None) -> int:
    args = build_parser(only=command).parse_args(argv)
    provenance.set_command(["gcnt", *given])  # the command runs and sweeps record
    _configure_logging(args.verbose)
    try:
        return int(importlib.import_module(args._module).run(args) or 0)
    except KeyboardInterrupt:
        print("gcnt: interrupted", file=sys.stderr)
        return 130
    except Exception as e:
        if args.verbose:
            raise
        if isinstance(e, OSError) and e.errno in _WRITE_ERRNOS:
            # a folder it cannot write (read-only, someone else's) or a full disk: one line
            full = e.errno in (errno.ENOSPC, errno.EDQUOT)  # else: read-only, not permitted
            if hasattr(args, "out"):
                hint = (
                    "; free space, or give --out DIR elsewhere"
                    if full
                    else ("; --out DIR writes elsewhere")
                )
            else:
                hint = "; free space" if full else "; work on a copy in a folder you can write"
            print(
                f"gcnt {args.command}: error: {e.filename or 'writing'}: cannot write "
                f"({e.strerror or e}){hint}",
                file=sys.stderr,
            )
            return 2
        if not isinstance(e, _user_errors()):
            raise
        print(f"gcnt {args.command}: error: {_one_line(str(e))}", file=sys.stderr)
        return 2


#: errors of writing output, reported in one line: permission denied, a read-only file system,
#: no space left, a disk quota exceeded
_WRITE_ERRNOS = (errno.EACCES, errno.EPERM, errno.EROFS, errno.ENOSPC, errno.EDQUOT)


def _one_line(message: str) -> str:
    """A message in one line (MuJoCo's and parsers' messages span several)."""
    return "; ".join(line.strip() for line in message.splitlines() if line.strip())


if __name__ == "__main__":
    sys.exit(main())
