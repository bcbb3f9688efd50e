"""``gcnt train RECIPE [key=value ...]``, ``gcnt train RECIPE --seeds 0,1,2 [key=value ...]`` and
``gcnt train --resume RUN_DIR [key=value ...]``; ``--init-from RUN_DIR`` starts a new run from a
trained one (options and overrides in any order)."""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import sys

from gcnt import plugins
from gcnt.suggest import existing_path

log = logging.getLogger(__name__)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("recipe", nargs="?", help="recipe YAML file (e.g. recipes/smpenv/walker.yaml)")
    p.add_argument(
        "overrides",
        nargs="*",
        help="dotted overrides, e.g. network.name=swat seed=2 td3.lr=3e-4 algo=ppo",
    )
    p.add_argument("--resume", metavar="RUN_DIR", help="continue the run in RUN_DIR")
    p.add_argument(
        "--seeds",
        metavar="S1,S2,...",
        help="train these seeds together in this process (TD3, td3.schedule=mixed): networks "
        "stacked and updated in one step; one run directory per seed (resume each on its own)",
    )
    p.add_argument(
        "--init-from",
        metavar="RUN_DIR",
        help="fine-tune: start from the trained networks of the run in RUN_DIR (and its "
        "observation statistics) with fresh optimisers and replay, on this recipe's robots "
        "(the recipe key init_from); a task of its own: <source task>-ft unless the recipe "
        "names another",
    )


def run(args: argparse.Namespace) -> int:
    """Train; SIGTERM, SIGINT and SIGUSR2 (from the start, so that processes started on the way
    inherit the blocked signals: :mod:`gcnt.rl.stop`) stop it after the current batch with a
    checkpoint: one line and exit code EXIT_STOPPED."""
    from gcnt.rl.stop import EXIT_STOPPED, TrainingStopped, stop_on_signals

    try:
        with stop_on_signals():
            return _run(args)
    except TrainingStopped as e:
        print(f"gcnt train: {e}", file=sys.stderr, flush=True)
        return EXIT_STOPPED


def _run(args: argparse.Namespace) -> int:
    from gcnt.recipes import RecipeError

    if args.init_from is not None:
        if args.resume:
            raise RecipeError(
                "--init-from starts a new run from a trained one; --resume continues a run "
                "from its own checkpoint: give one of them"
            )
        # the recipe key, as the last override (a quoted YAML string: any path stays text)
        args.overrides = [*args.overrides, f"init_from={json.dumps(args.init_from)}"]
    if args.seeds is not None:
        return _run_seeds(args)
    made: list = []  # a new run's directory (a RunDir), once this command created it
    try:
        return _train_one(args, made)
    except BaseException:
        if made and made[0].discard_failed_start():
            log.info("removed %s: the run failed before it logged anything", made[0].path)
        raise


def _train_one(args: argparse.Namespace, made: list) -> int:
    from gcnt.recipes import RecipeError, load_recipe
    from gcnt.run.lock import run_lock

    recipe = None
    if not args.resume:  # checked before torch is imported (by what follows): a bad recipe in ~1 s
        if not args.recipe:
            raise RecipeError("give a recipe file or --resume RUN_DIR")
        recipe = load_recipe(args.recipe, args.overrides)
    from gcnt.rl.init_from import own_task
    from gcnt.run.directory import RunDir

    with contextlib.ExitStack() as held:  # the run directory's lock, held until the end
        if args.resume:
            overrides = [args.recipe, *args.overrides] if args.recipe else args.overrides
            run_dir = RunDir(existing_path(args.resume))
            held.enter_context(run_lock(run_dir.path))
            recipe = run_dir.load_recipe(overrides)
            recipe.plugins = plugins.with_session(recipe.plugins)
            resume = run_dir.has_checkpoint()
            if not resume:
                log.info("%s has no checkpoint yet: training it from the start", run_dir.path)
        else:
            recipe.plugins = plugins.with_session(recipe.plugins)  # recorded by the run
            own_task(recipe)  # a fine-tuned run: <source task>-ft, never its source's task
            run_dir = RunDir.for_recipe(recipe)
            resume = False
            if run_dir.path.is_dir():  # a second writer stops before the build below
                run_dir.check_new()  # a run there is refused without a trace left
                held.enter_context(run_lock(run_dir.path))
        from gcnt.rl.loop import prepare, train

        if run_dir.path.is_dir():  # a link out of the run directory: refused before any work
            run_dir.check_links()
        # robots, env and networks are built (and bad input reported) before anything is written
        prepared = prepare(recipe, resume=resume)
        if not args.resume and run_dir.claim():  # made here: this process's to remove
            made.append(run_dir)
        held.enter_context(run_lock(run_dir.path))
        if not args.resume:
            run_dir.create(recipe)  # with the provenance of the code now running
        elif not resume:  # no checkpoint: trained again from step 0 (a resumed one: in train)
            run_dir.record_session()
        if args.resume and not resume:
            aside = run_dir.set_aside_metrics()  # rows of the killed attempt, kept but not mixed in
            if aside is not None:
                log.info("metrics of the attempt without a checkpoint moved to %s", aside)
        train(recipe, run_dir, resume=resume, prepared=prepared)
    print(f"run directory: {run_dir.path}")
    return 0


def _run_seeds(args: argparse.Namespace) -> int:
    from gcnt.recipes import RecipeError, load_recipe

    if args.resume:
        raise RecipeError(
            "--seeds starts new runs; resume each seed's run on its own: gcnt train --resume "
            "RUN_DIR"
        )
    if not args.recipe:
        raise RecipeError("--seeds: give a recipe file")
    recipe = load_recipe(args.recipe, args.overrides)
    from gcnt.rl.init_from import own_task
    from gcnt.rl.td3.stacked_loop import parse_seeds, seed_recipes, train_seeds

    recipe.plugins = plugins.with_session(recipe.plugins)  # recorded by the runs
    own_task(recipe)  # a fine-tuned run: <source task>-ft, never its source's task
    runs = train_seeds(seed_recipes(recipe, parse_seeds(args.seeds)))
    for run in runs:
        print(f"run directory: {run.path}")
    return 0
