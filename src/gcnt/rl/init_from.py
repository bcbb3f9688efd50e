"""Fine-tuning: a run that starts from another run's trained networks (``init_from: RUN_DIR`` in a
recipe, or ``gcnt train RECIPE --init-from RUN_DIR``).

The new run builds its networks for its own robots (the robot table is static data, rebuilt for
any robots), then takes over the learnt weights of the source run's last checkpoint through
:meth:`gcnt.rl.algorithm.Algorithm.start_from`: for TD3 the actor, both critics and their target
copies; for PPO the actor, the critic and the observation statistics (with their counts, so the
normalisation the policy was trained with is kept and moves slowly). Optimisers, replay buffers,
the learning-rate schedule, the robot sampler, the reward scaler and every counter start fresh,
as in a run from scratch, and the run's own seed drives its envs and exploration.

The two runs must agree on what the weights mean: the algorithm, the benchmark and the network
(method, size preset and sizes); every tensor's shape is then checked, which covers the per-limb
token width and a height map present on one side only. A disagreement is one RecipeError naming
both sides. The new run's ``recipe.yaml`` records where it started, under ``resolved.init_from``:
the source run directory, its task and fingerprint (:attr:`gcnt.run.data.Run.fingerprint`:
fine-tunes of the seeds of one experiment are seeds of one fine-tune), the env steps of its
checkpoint and the checkpoint file's SHA-256.

A fine-tuned run is an experiment of its own, never a seed of the runs it started from: when its
recipe keeps the source run's task, its task becomes ``<source task>-ft`` (:func:`own_task`), so
that it is written under ``runs/<task>-ft/`` and analysed apart; a recipe that names another task
keeps it.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

from gcnt.recipes import Recipe, RecipeError
from gcnt.rl.algorithm import Algorithm
from gcnt.run.directory import RunDir
from gcnt.run.resolved import network_sizes, resolve_run
from gcnt.suggest import existing_path

#: the key of the record in the run's ``resolved:`` section
INIT_KEY = "init_from"
#: appended to the source run's task to name a fine-tuned run's task (:func:`own_task`)
FINE_TUNE_SUFFIX = "-ft"


def own_task(recipe: Recipe) -> None:
    """Give the new run of ``recipe``, when it starts from a trained run, a task of its own:
    ``<source task>-ft`` where the recipe's task is the source run's (another task is kept)."""
    if not recipe.init_from:
        return
    task = _source(recipe).load_recipe(anywhere=True).task
    if recipe.task == task:
        recipe.task = task + FINE_TUNE_SUFFIX


def origin(recipe: Recipe, algo: Algorithm, *, resume: bool = False) -> dict[str, Any]:
    """Where the run of ``recipe`` starts: ``{}`` from scratch; else ``{"init_from": record}``,
    with the source run's weights loaded into ``algo`` (a new run) or the record already in the
    recipe's ``resolved:`` section kept (a resumed run, whose checkpoint holds its weights)."""
    if not recipe.init_from:
        return {}
    if resume:
        record = recipe.resolved.get(INIT_KEY)
        if record is None:
            raise RecipeError(
                f"init_from={recipe.init_from}: this run was not started from a trained run and "
                "resumes its own checkpoint; start a new run with --init-from instead"
            )
        return {INIT_KEY: record}
    return {INIT_KEY: start_from(recipe, algo)}


def start_from(recipe: Recipe, algo: Algorithm) -> dict[str, Any]:
    """Load the trained networks of the run ``recipe.init_from`` into ``algo`` (built for
    ``recipe``); returns the record of where it started."""
    from gcnt.run.data import Run

    where = f"init_from {recipe.init_from}"
    source = _source(recipe)
    source_recipe = source.load_recipe(anywhere=True)
    check_compatible(recipe, source_recipe, where)
    state = source.load_checkpoint()
    if state.get("algo", recipe.algo) != recipe.algo:
        raise RecipeError(
            f"{where}: its checkpoint is a {state['algo']} learner, this recipe has "
            f"algo={recipe.algo}"
        )
    from gcnt.run.directory import CHECKPOINT_MISFITS, CheckpointError

    try:
        algo.start_from(state["learner"])
    except CHECKPOINT_MISFITS as e:
        if isinstance(e, RecipeError):
            raise
        detail = str(e).splitlines()[0] if str(e) else repr(e)
        if isinstance(e, ValueError | KeyError):  # a network of other sizes: the recipe's
            raise RecipeError(f"{where}: {detail} ({source.checkpoint_path})") from None
        raise CheckpointError(
            f"{source.checkpoint_path}: does not fit this recipe's networks ({where}): "
            f"{type(e).__name__}: {detail}"
        ) from None
    return {
        "run": str(source.path.resolve()),
        "task": source_recipe.task,
        "fingerprint": Run(source.path).fingerprint,
        "env_steps": int(state["env_steps"]),
        "checkpoint_sha256": file_sha256(source.checkpoint_path),
    }


def _source(recipe: Recipe) -> RunDir:
    return RunDir(existing_path(recipe.init_from, "init_from: run directory"))


def check_compatible(recipe: Recipe, source: Recipe, where: str = "init_from") -> None:
    """A RecipeError naming both sides when the trained run ``source`` and ``recipe`` differ in
    algorithm, benchmark or network (method, or any size its preset and overrides resolve to)."""
    for key, theirs, ours in (
        ("algo", source.algo, recipe.algo),
        ("env.benchmark", source.env.benchmark, recipe.env.benchmark),
        ("network.name", source.network.name, recipe.network.name),
    ):
        if theirs != ours:
            raise RecipeError(f"{where}: that run has {key}={theirs}, this recipe has {key}={ours}")
    theirs, ours = network_sizes(source), resolve_run(recipe).network
    for key in ours:
        if theirs.get(key) != ours[key]:
            raise RecipeError(
                f"{where}: that run's network has {key}={theirs.get(key)}, this recipe's has "
                f"{key}={ours[key]} (network.preset / network.kwargs)"
            )


def file_sha256(path: Path) -> str:
    from gcnt.files import open_regular
    from gcnt.run.directory import MAX_CHECKPOINT_BYTES, CheckpointError

    what = "a checkpoint is the file gcnt train writes"
    with open_regular(path, MAX_CHECKPOINT_BYTES, what, CheckpointError) as f:
        return hashlib.file_digest(f, "sha256").hexdigest()
