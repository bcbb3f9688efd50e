"""Several seeds of one TD3 recipe trained in one process (``gcnt train RECIPE --seeds 0,1,2``).

Each seed is an ordinary run: its own recipe copy (``seed`` set), env, collector, replay,
schedule, global random state (:class:`gcnt.rl.td3.stacked.SeedRNG`) and run directory (the default
``runs/<task>/<algo>-<method>/seed<N>``, or ``<run_dir>/seed<N>`` when the recipe sets
``run_dir``), with its own metrics rows, checkpoints and evaluations, written by the helpers of
:mod:`gcnt.rl.loop`. The seeds advance in lockstep: each collects one batch, then the update phase
runs every seed's updates together (:class:`gcnt.rl.td3.stacked.StackedTD3`: networks stacked, one
vmapped step per update).

Only what keeps every seed's update count equal per batch is accepted: TD3 with
``td3.schedule=mixed`` (the paper schedule updates a seed when all its robots have finished an
episode, which differs between seeds), and networks without dropout. A checkpoint of a seed is an
ordinary single-run checkpoint: ``gcnt train --resume <seed's run dir>`` continues that seed on
its own.
"""

from __future__ import annotations

import copy
import logging
import time
from pathlib import Path

from tqdm.contrib.logging import logging_redirect_tqdm

from gcnt.recipes import Recipe, RecipeError
from gcnt.rl import stop
from gcnt.rl.loop import (
    Cadence,
    Prepared,
    TrainStats,
    after_update,
    checkpoint_since,
    finish,
    log_summary,
    make_collector,
    prepare,
    progress_bar,
    stop_here,
)
from gcnt.rl.run_logger import make_logger
from gcnt.rl.td3.stacked import SeedRNG, StackedTD3
from gcnt.run.directory import RunDir
from gcnt.run.lock import run_locks

log = logging.getLogger(__name__)


def parse_seeds(text: str) -> list[int]:
    """``"0,1,2"`` -> ``[0, 1, 2]``; a RecipeError naming the problem otherwise."""
    parts = [p.strip() for p in str(text).split(",")]
    try:
        seeds = [int(p) for p in parts]
    except ValueError:
        raise RecipeError(
            f"--seeds {text!r}: expected comma-separated integers, e.g. --seeds 0,1,2"
        ) from None
    dup = sorted({s for s in seeds if seeds.count(s) > 1})
    if dup:
        raise RecipeError(f"--seeds {text!r}: seed {dup[0]} is given twice")
    return seeds


def seed_recipes(recipe: Recipe, seeds: list[int]) -> list[Recipe]:
    """One copy of ``recipe`` per seed (``seed`` set; ``run_dir``, when set, becomes the parent
    folder of ``seed<N>``), after checking that the recipe can be stacked."""
    if not seeds:
        raise RecipeError("--seeds: give at least one seed, e.g. --seeds 0,1,2")
    if recipe.algo != "td3":
        raise RecipeError(
            f"--seeds trains TD3 recipes with stacked networks; this recipe has algo={recipe.algo}"
        )
    if recipe.td3.schedule != "mixed":
        raise RecipeError(
            f"--seeds needs td3.schedule=mixed (td3.schedule={recipe.td3.schedule} gives each "
            "seed its own number of updates per batch)"
        )
    out = []
    for seed in seeds:
        r = copy.deepcopy(recipe)
        r.seed = seed
        if recipe.run_dir:
            r.run_dir = str(Path(recipe.run_dir) / f"seed{seed}")
        out.append(r)
    return out


def train_seeds(recipes: list[Recipe]) -> list[RunDir]:
    """Train the seeds' recipes (from :func:`seed_recipes`) together into fresh run
    directories; returns them."""
    rng = SeedRNG(len(recipes))
    prepared: list[Prepared] = []
    lookups: dict = {}  # the seeds' robot specs, each looked up once
    try:
        # each seed is built as its own run would be (seeded globally, then its state kept)
        for i, recipe in enumerate(recipes):
            prepared.append(prepare(recipe, lookups=lookups))
            rng.capture(i)
        try:
            stacked = StackedTD3([p.algo for p in prepared], rng)
        except ValueError as e:
            raise RecipeError(f"--seeds: {e}") from None
        runs = [RunDir.for_recipe(r) for r in recipes]
        paths = [run.path.resolve() for run in runs]
        if len(set(paths)) < len(paths):
            raise RecipeError("--seeds: two seeds would share one run directory")
        for run in runs:  # a run already there is refused before any directory is made
            if run.path.is_dir():
                run.check_new()
        made = [run for run in runs if run.claim()]  # only these are this command's to remove
        held = run_locks([run.path for run in runs])  # one writer per run directory
        try:
            held.__enter__()
        except BaseException:
            _discard(made)
            raise
        try:
            for run, recipe in zip(runs, recipes, strict=True):
                run.create(recipe)
        except BaseException:
            held.__exit__(None, None, None)
            _discard(made)
            raise
    except BaseException:
        for p in prepared:
            p.env.close()
        raise
    prepared[0].log_choices()  # the same for every seed
    try:
        _lockstep(recipes, runs, prepared, stacked, rng)
    finally:
        held.__exit__(None, None, None)
    return runs


def _discard(made: list[RunDir]) -> None:
    """Remove the run directories this command made before it was refused (they hold no
    more than the lock file and what ``create`` began)."""
    for run in made:
        run.discard_failed_start()


def _lockstep(
    recipes: list[Recipe],
    runs: list[RunDir],
    prepared: list[Prepared],
    stacked: StackedTD3,
    rng: SeedRNG,
) -> None:
    n = len(recipes)
    algos = [p.algo for p in prepared]
    env_steps = [0] * n
    total = recipes[0].collector.total_frames
    cadences = [Cadence(r, 0) for r in recipes]
    loggers = [
        make_logger(r, run, p.robots, concurrent=True)
        for r, run, p in zip(recipes, runs, prepared, strict=True)
    ]
    stats = [TrainStats([robot.name for robot in p.robots], 0, p.algo.updates) for p in prepared]
    collectors = []
    t0 = time.perf_counter()
    try:
        for i, (recipe, p) in enumerate(zip(recipes, prepared, strict=True)):
            with rng.active(i):
                settings = p.algo.collect_settings(0)
                collectors.append(make_collector(recipe, p.env, settings))
        batches = [iter(c) for c in collectors]
        bar = progress_bar(recipes[0], total * n, 0)
        with logging_redirect_tqdm(loggers=[logging.getLogger("gcnt")]):
            try:
                while min(env_steps) < total:
                    datas = []
                    for i in range(n):
                        with rng.active(i):
                            datas.append(next(batches[i]))
                    for i, data in enumerate(datas):
                        env_steps[i] += data.numel()
                        stats[i].add_episodes(data)
                    rows = stacked.process(datas, env_steps)
                    for i in range(n):
                        with rng.active(i):  # its checkpoint keeps its own random state
                            after_update(
                                recipes[i], runs[i], algos[i], loggers[i], stats[i],
                                cadences[i], rows[i], env_steps[i],
                            )  # fmt: skip
                    # 100% once the last batch's update is done
                    bar.update(sum(d.numel() for d in datas))
                    if stop.requested():  # each seed checkpointed with its own random state
                        for i in range(n):
                            with rng.active(i):
                                checkpoint_since(runs[i], algos[i], cadences[i], env_steps[i])
                        stop_here(recipes, runs, algos, loggers, cadences, env_steps)
            finally:
                bar.close()
    finally:
        for c in collectors:
            c.shutdown()
    train_s = time.perf_counter() - t0
    for i in range(n):
        with rng.active(i):
            results = finish(recipes[i], runs[i], algos[i], loggers[i], env_steps[i])
        trained = [r.name for r in prepared[i].robots]
        log_summary(runs[i], env_steps[i], train_s, time.perf_counter() - t0, results, trained)
