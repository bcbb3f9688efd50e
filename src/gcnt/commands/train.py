"""``gcnt train RECIPE [key=value ...]`` and ``gcnt train --resume RUN_DIR``."""

from __future__ import annotations

import argparse
import logging

from gcnt.recipes import RecipeError, load_recipe
from gcnt.rl.run_dir import RunDir

log = logging.getLogger(__name__)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("recipe", nargs="?", help="recipe YAML file (e.g. recipes/smpenv/walker.yaml)")
    p.add_argument(
        "overrides", nargs="*", help="dotted overrides, e.g. network.name=swat seed=2 optim.lr=3e-4"
    )
    p.add_argument("--resume", metavar="RUN_DIR", help="continue the run in RUN_DIR")


def run(args: argparse.Namespace) -> int:
    from gcnt.rl.td3 import train

    try:
        if args.resume:
            overrides = [args.recipe, *args.overrides] if args.recipe else args.overrides
            run_dir = RunDir(args.resume)
            recipe = run_dir.load_recipe(overrides)
            train(recipe, run_dir, resume=True)
        else:
            if not args.recipe:
                log.error("give a recipe file or --resume RUN_DIR")
                return 2
            recipe = load_recipe(args.recipe, args.overrides)
            run_dir = RunDir.for_recipe(recipe)
            run_dir.create(recipe)
            train(recipe, run_dir)
    except (RecipeError, FileExistsError, FileNotFoundError) as e:
        log.error("%s", e)
        return 2
    print(f"run directory: {run_dir.path}")
    return 0
