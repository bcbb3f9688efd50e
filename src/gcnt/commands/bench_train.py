"""``gcnt bench-train``: what an update costs, and what the training pipeline adds to it.

The measurements live with their algorithm: :mod:`gcnt.bench.td3` (the bare update with its
operators per step and the previous layout's time, end to end, the replay sample, stacked seeds),
:mod:`gcnt.bench.td3_parts` (the update part by part), :mod:`gcnt.bench.td3_processes` (two
processes at once) and :mod:`gcnt.bench.ppo` (the bare iteration, end to end, collection with
worker processes); :mod:`gcnt.bench.common` holds the matmul peak, FLOP and launch counts they
share. Default recipe: the quick start.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from gcnt.recipes import QUICKSTART, default_recipe


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "recipe",
        nargs="?",
        default=None,
        # written out: argparse's intermixed parsing hides a positional's default while it
        # prints --help, so "%(default)s" would fail there
        help=f"recipe file (default: {QUICKSTART}, found from any folder)",
    )
    p.add_argument("overrides", nargs="*", help="dotted recipe overrides")
    p.add_argument("--updates", type=int, default=30, help="bare updates to time")
    p.add_argument("--steps", type=int, default=400, help="env steps to time end to end")
    p.add_argument("--warmup", type=int, default=200, help="random-action steps before timing")
    p.add_argument(
        "--iterations",
        type=int,
        default=3,
        help="PPO: iterations to run end to end (the first is warm-up)",
    )
    p.add_argument(
        "--stacked-seeds",
        type=int,
        metavar="S",
        help="TD3 instead: bare update time of 1..S seeds stacked (gcnt train --seeds) against "
        "one seed's own update, mixed schedule",
    )
    p.add_argument(
        "--workers",
        metavar="W1,W2,...",
        help="PPO instead: collection alone (no update), env steps/s of the single collector "
        "and of torchrl's multi-process collector with each of these worker counts, in one run",
    )
    p.add_argument(
        "--compiled",
        action="store_true",
        help="TD3: also the bare update compiled (compile.compile=true) against eager, "
        "alternate rounds, and the compile time (minutes on a CPU)",
    )
    p.add_argument(
        "--against",
        action="append",
        metavar="KEY=VALUE",
        help="TD3: also the bare update with this override (repeatable, e.g. "
        "td3.trim_padding=false), in alternate rounds with the recipe's: the ratio recipe ÷ it",
    )
    p.add_argument(
        "--commits",
        metavar="A,B",
        help="TD3 instead: the bare update of two commits of this checkout (git worktrees), "
        "alternate rounds in fresh processes, B ÷ A (e.g. --commits b9623ac,HEAD)",
    )
    p.add_argument(
        "--parts",
        action="store_true",
        help="TD3 instead: the bare update of the recipe's schedule part by part (target actor, "
        "target critics, critics, optimiser tails, actor, soft update), and where the twin "
        "critics run on two threads the same operators in turn on one, alternate rounds",
    )
    p.add_argument(
        "--processes",
        action="store_true",
        help="TD3 instead: the bare update (twin critics in turn, one thread) alone, then in two "
        "processes at once: what a second process gets from the second core",
    )
    p.add_argument("--rounds", type=int, default=5, help="alternate rounds (median of them)")
    p.add_argument("--json", action="store_true", help="print JSON only")


def recipe_and_overrides(recipe: str, overrides: list[str]) -> tuple[str, list[str]]:
    """``gcnt bench-train key=value ...`` without a recipe: the quick start with those
    overrides (argparse takes the first word for the optional recipe); no recipe at all: the
    quick start (:func:`gcnt.recipes.default_recipe`: from any folder)."""
    if recipe is None:
        return default_recipe(), list(overrides)
    if "=" in recipe and not Path(recipe).exists():
        return default_recipe(), [recipe, *overrides]
    return recipe, list(overrides)


#: the options that measure something else instead of the default report, at most one per run
INSTEAD = ("stacked_seeds", "commits", "parts", "processes", "workers")
#: the options each algorithm's measurements read (the rest would be ignored without a word)
ONLY_FOR = {
    "td3": ("stacked_seeds", "commits", "parts", "processes", "compiled", "against"),
    "ppo": ("workers",),
}
#: the options that add to the default TD3 report, not to an INSTEAD measurement
ADD_TO_DEFAULT = ("compiled", "against")


def _option(name: str) -> str:
    return "--" + name.replace("_", "-")


def _given(args: argparse.Namespace, name: str) -> bool:
    value = getattr(args, name)
    return value is not None if name == "stacked_seeds" else bool(value)


def check_options(args: argparse.Namespace, algo: str) -> None:
    """A one-line RecipeError for options that this recipe's measurement would ignore: two
    INSTEAD options, an option of the other algorithm, or an ADD_TO_DEFAULT option beside an
    INSTEAD one."""
    from gcnt.recipes import RecipeError

    instead = [n for n in INSTEAD if _given(args, n)]
    if len(instead) > 1:
        raise RecipeError(
            f"{' and '.join(map(_option, instead))} each measure something else; give one"
        )
    for other, names in ONLY_FOR.items():
        given = [n for n in names if _given(args, n)]
        if other != algo and algo in ONLY_FOR and given:
            raise RecipeError(
                f"{_option(given[0])} measures {other.upper()} recipes; "
                f"{args.recipe} is a {algo.upper()} recipe"
            )
    extra = [n for n in ADD_TO_DEFAULT if _given(args, n)]
    if instead and extra:
        raise RecipeError(
            f"{_option(extra[0])} adds to the default report, not to {_option(instead[0])}"
        )


def run(args: argparse.Namespace) -> int:
    from gcnt.recipes import load_recipe

    args.recipe, args.overrides = recipe_and_overrides(args.recipe, args.overrides)
    recipe = load_recipe(args.recipe, args.overrides)
    check_options(args, recipe.algo)
    # the report alone on the terminal: the training it times logs warnings only
    logger = logging.getLogger("gcnt")
    level = logger.level
    logger.setLevel(logging.WARNING)
    try:
        return _measure(args, recipe)
    finally:
        logger.setLevel(level)


def _measure(args: argparse.Namespace, recipe) -> int:
    from gcnt.recipes import RecipeError

    if not args.json:
        print(f"recipe: {args.recipe} ({recipe.algo}, {recipe.network.name})")
    if recipe.algo == "ppo":
        from gcnt.bench.ppo import run_collect, run_ppo

        if args.workers:
            return run_collect(args, recipe)
        return run_ppo(args, recipe)
    if recipe.algo != "td3":
        raise RecipeError(
            f"bench-train measures TD3 and PPO recipes; {args.recipe} has algo {recipe.algo}"
        )
    from gcnt.bench.td3 import run_commits, run_stacked, run_td3, training_threads

    if args.commits:
        return run_commits(args)

    training_threads(recipe)
    if args.parts:
        from gcnt.bench.td3_parts import run_parts

        return run_parts(args, recipe)
    if args.processes:
        from gcnt.bench.td3_processes import run_processes

        return run_processes(args, recipe)

    if args.stacked_seeds is not None:
        return run_stacked(args, recipe)
    return run_td3(args, recipe)
