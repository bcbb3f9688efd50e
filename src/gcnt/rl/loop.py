"""The run loop every algorithm shares, read top to bottom.

``train(recipe, run)`` seeds everything, builds the benchmark's env over the training robots and
the recipe's algorithm (``gcnt.rl.algorithm``), then collects batches with a torchrl
``Collector`` and hands each to the algorithm, logging per-robot episode returns and the
algorithm's losses, checkpointing atomically (with RNG state), evaluating and rendering videos.
``train(recipe, run, resume=True)`` continues from the run's last checkpoint. Inside
:func:`gcnt.rl.stop.stop_on_signals` (as ``gcnt train`` runs it), SIGTERM, SIGINT and SIGUSR2 stop
the run after the current batch with a checkpoint (:func:`stop_here`).

Every collected environment step is counted (``env_steps``), over all robots.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import sys
import time
from collections import defaultdict
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NoReturn

import numpy as np
import torch
from tensordict import TensorDictBase
from torchrl.collectors import Collector, MultiSyncCollector
from torchrl.envs import EnvBase
from tqdm import tqdm
from tqdm.contrib.logging import logging_redirect_tqdm

from gcnt import keys as K
from gcnt.morphology import Robot
from gcnt.recipes import Recipe, RecipeError
from gcnt.rl import init_from, stop
from gcnt.rl.accelerate import choose_matmul_precision, collector_kwargs
from gcnt.rl.algorithm import Algorithm, CollectSettings, get_algorithm
from gcnt.rl.evaluate import check_eval_robots, evaluate, render_policy, write_eval
from gcnt.rl.factories import benchmark_of
from gcnt.rl.run_logger import RunLogger, check_logger, make_logger
from gcnt.rl.worker_watch import (
    StopWhileWaiting,
    Waiting,
    WorkerDiedError,
    dead_worker,
    end_workers,
    worker_watch,
)
from gcnt.run import provenance
from gcnt.run.directory import (
    CHECKPOINT_MISFITS,
    CheckpointError,
    RunDir,
    seed_everything,
    set_rng_state,
)
from gcnt.run.record import store_robots
from gcnt.run.resolved import RunRecord, network_sizes, resolve_run

log = logging.getLogger(__name__)


class TrainingDivergedError(FloatingPointError):
    """Losses or weights turned NaN or infinite; the last good checkpoint is kept."""


def check_network(recipe: Recipe) -> None:
    """The recipe's network name, preset and sizes (``network.kwargs``, or the method's entry of
    ``network.method_kwargs``): a RecipeError naming them."""
    network_sizes(recipe)


def check_recipe(recipe: Recipe, *, lookups: dict | None = None) -> RunRecord:
    """What a run of ``recipe`` would refuse before building anything: the logger, the run's
    record (:func:`gcnt.run.resolved.resolve_run`: the network's name, preset and sizes, the
    benchmark and world, the training and test robots, each known, of the benchmark, the two
    lists apart), the algorithm and the robots evaluated at the end. A RecipeError (or a robot
    error) naming the culprit; ``gcnt sweep`` checks every run so (``lookups``: the robot specs
    it looked up already). Returns the record."""
    check_logger(recipe)
    record = resolve_run(recipe, lookups=lookups)
    get_algorithm(recipe.algo)
    check_eval_robots(recipe, _eval_specs(recipe))  # evaluated at the end: check them first
    return record


class TrainStats:
    """Episode returns and lengths per robot, losses and rates between two log lines."""

    def __init__(self, names: list[str], env_steps: int, updates: int):
        self.names = names
        self.returns: dict[int, list[float]] = defaultdict(list)
        self.lengths: dict[int, list[int]] = defaultdict(list)
        self.losses: dict[str, list[float]] = defaultdict(list)
        self.t, self.env_steps, self.updates = time.perf_counter(), env_steps, updates

    def add_episodes(self, data: TensorDictBase) -> None:
        done = data["next", "done"].squeeze(-1)
        robots = data[K.MORPH_ID][done].tolist()
        rets = data["next", "episode_reward"].squeeze(-1)[done].tolist()
        for robot, ret in zip(robots, rets, strict=True):
            self.returns[robot].append(ret)
        steps = data.get(("next", "step_count"), None)  # torchrl's StepCounter, where tracked
        if steps is not None:
            for robot, n in zip(robots, steps.squeeze(-1)[done].tolist(), strict=True):
                self.lengths[robot].append(n)

    def add_losses(self, losses: dict[str, float]) -> None:
        for k, v in losses.items():
            self.losses[k].append(v)

    def row(self, env_steps: int, updates: int) -> dict:
        now = time.perf_counter()
        row = {
            "env_steps": env_steps,
            "updates": updates,
            "env_steps_per_s": (env_steps - self.env_steps) / (now - self.t),
            "updates_per_s": (updates - self.updates) / (now - self.t),
            **{k: float(np.mean(v)) for k, v in self.losses.items()},
        }
        per_robot = {
            f"train_return/{self.names[k]}": float(np.mean(v)) for k, v in self.returns.items()
        }
        if per_robot:
            row["train_return/mean"] = float(np.mean(list(per_robot.values())))
        row.update(per_robot)
        # the episode lengths beside the returns: a return made of survival bonuses is told
        # apart from one made of progress (SMPENV pays about 1 per step alive)
        lengths = {
            f"train_length/{self.names[k]}": float(np.mean(v)) for k, v in self.lengths.items()
        }
        if lengths:
            row["train_length/mean"] = float(np.mean(list(lengths.values())))
        row.update(lengths)
        self.returns.clear()
        self.lengths.clear()
        self.losses.clear()
        self.t, self.env_steps, self.updates = now, env_steps, updates
        return row


@dataclass
class Prepared:
    """A run's robots, training env and algorithm, built before its directory is touched."""

    robots: list[Robot]
    env: EnvBase
    algo: Algorithm
    #: the run's record, as ``recipe.resolved`` holds it
    record: RunRecord
    #: the settings chosen for the run and why (the algorithm's and the products' precision)
    choices: list[str] = field(default_factory=list)

    def log_choices(self) -> None:
        """One log line per choice, when training starts (not while its input is checked, so
        that a refused command's error stays its one line)."""
        for line in self.choices:
            log.info("%s", line)


def prepare(recipe: Recipe, *, resume: bool = False, lookups: dict | None = None) -> Prepared:
    """Seed, then build the robots, the benchmark's env and the algorithm (bad input fails
    here, before anything is written); the derived sizes go to ``recipe.resolved``. A new run
    with ``init_from`` takes over that run's trained networks here (``gcnt.rl.init_from``);
    ``resume``: the run continues its own checkpoint instead. ``lookups``: robot specs this
    command looked up already (the seeds of one ``--seeds`` command share them)."""
    record = check_recipe(recipe, lookups=lookups)
    if recipe.compile.torch_threads is not None:
        torch.set_num_threads(recipe.compile.torch_threads)
    precision, why = choose_matmul_precision(recipe.compile, recipe.device)
    torch.set_float32_matmul_precision(precision)
    seed_everything(recipe.seed)
    robots = list(record.train_robots)
    algo_cls = get_algorithm(recipe.algo)
    env = algo_cls.make_train_env(recipe, robots)
    try:
        algo = algo_cls(recipe, env, robots)
        start = init_from.origin(recipe, algo, resume=resume)
    except BaseException as e:
        env.close()
        if type(e) is ValueError:  # what the network builder says about the robots it was given
            raise RecipeError(
                f"network {recipe.network.name!r} on {benchmark_of(recipe).name} robots: {e}"
            ) from None
        raise
    recipe.resolved = {
        **algo.resolved(),
        "matmul_precision": precision,
        **start,
        **record.resolved(),
    }
    choice = f"float32 matrix products: {precision} (compile.matmul_precision: {why})"
    return Prepared(robots, env, algo, record, [choice, *algo.choices])


def train(
    recipe: Recipe, run: RunDir, *, resume: bool = False, prepared: Prepared | None = None
) -> RunDir:
    """Train per ``recipe`` into ``run`` (continuing its checkpoint when ``resume``).

    ``prepared`` is :func:`prepare`'s result for this recipe (built here when not given). Called
    from Python without logging set up for gcnt, it shows its progress lines on stderr all the
    same, and torchrl's info lines stay out (:func:`console_output`).
    """
    with console_output():
        return _train(recipe, run, resume, prepared)


@contextlib.contextmanager
def console_output() -> Iterator[None]:
    """What a run shows when its caller set up no logging (the Python API, a notebook), for its
    duration: gcnt's info lines (progress, evaluations, the summary) on stderr, and torchrl's
    info lines left out. Whatever the caller chose wins: a level or handler set on the ``gcnt``
    logger, a handler that already shows its info lines (``logging.basicConfig(level=INFO)``, the
    ``gcnt`` command), a level set for torchrl (``RL_LOGGING_LEVEL``)."""
    gcnt_log = logging.getLogger("gcnt")
    own = gcnt_log.level == logging.NOTSET and not gcnt_log.handlers
    own = own and not gcnt_log.isEnabledFor(logging.INFO)
    torchrl_log = logging.getLogger("torchrl")
    torchrl_level = torchrl_log.level
    saved = (gcnt_log.level, gcnt_log.propagate)
    handler = logging.StreamHandler()
    if own:
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
        gcnt_log.addHandler(handler)
        gcnt_log.setLevel(logging.INFO)
        gcnt_log.propagate = False  # not twice through a handler of the root logger
    if "RL_LOGGING_LEVEL" not in os.environ and torchrl_level < logging.WARNING:
        torchrl_log.setLevel(logging.WARNING)
    try:
        yield
    finally:
        if own:
            gcnt_log.removeHandler(handler)
            gcnt_log.setLevel(saved[0])
            gcnt_log.propagate = saved[1]
        torchrl_log.setLevel(torchrl_level)


def _train(recipe: Recipe, run: RunDir, resume: bool, prepared: Prepared | None) -> RunDir:
    prepared = prepared or prepare(recipe, resume=resume)
    robots, env, algo = prepared.robots, prepared.env, prepared.algo
    t0 = time.perf_counter()

    env_steps = resume_checkpoint(run, algo) if resume else 0
    start, total = env_steps, recipe.collector.total_frames
    prepared.log_choices()
    if not resume or env_steps < total:  # a finished run's recipe is left as it was
        # before the record names them
        store_robots(run.path, [*robots, *prepared.record.test_robots])
        run.save_recipe(recipe)  # after the checkpoint was found to fit it
    if resume and env_steps < total:  # the code now running continues the run: recorded
        run.record_session()
    if resume:
        env.set_seed(recipe.seed + env_steps)  # fresh episodes, a seed that differs per resume
    cadence = Cadence(recipe, env_steps)
    logger = make_logger(recipe, run, robots)
    stats = TrainStats([robot.name for robot in robots], env_steps, algo.updates)
    if env_steps < total:
        settings = algo.collect_settings(env_steps)
        multi = settings.env_makers is not None
        collector = start_collector(recipe, env, settings, run)
        if multi:
            env.close()  # the workers build their own envs
        bar = progress_bar(recipe, total, env_steps)
        # log lines go above the progress bar instead of through it
        with logging_redirect_tqdm(loggers=[logging.getLogger("gcnt")]):
            try:
                # a worker that dies while the loop waits for it ends the wait (worker_watch)
                waiting = Waiting()
                watch = worker_watch(collector, run, waiting=waiting)
                with watch if multi else contextlib.nullcontext():
                    for data in waiting.batches(collector):
                        data = algo.admit(data)  # the steps the run counts (it may store more)
                        env_steps += data.numel()
                        stats.add_episodes(data)
                        row = after_update(
                            recipe, run, algo, logger, stats, cadence,
                            algo.process(data, env_steps), env_steps,
                        )  # fmt: skip
                        bar.update(data.numel())  # 100% once the last batch's update is done
                        follow_algorithm(collector, settings, algo, env_steps)
                        if stop.requested():
                            stop_here(recipe, [run], [algo], [logger], [cadence], [env_steps])
                        if multi:  # a dead worker would never acknowledge the new weights
                            if (dead := dead_worker(collector, run)) is not None:
                                raise dead
                            with waiting:
                                collector.update_policy_weights_()
                        if row is not None:
                            bar.set_postfix(ret=f"{row.get('train_return/mean', float('nan')):.1f}")
                        if env_steps >= total:
                            break
            except StopWhileWaiting:  # a worker that does not answer: its batch is not awaited
                end_workers(collector)
                collector = None
                stop_here(recipe, [run], [algo], [logger], [cadence], [env_steps])
            except Exception as e:  # a worker that died: one line, not the collector's traceback
                dead = e if isinstance(e, WorkerDiedError) else None
                dead = dead or (dead_worker(collector, run) if multi else None)
                if dead is None:
                    raise
                end_workers(collector)
                collector = None  # its shutdown would wait for the dead worker's answer
                raise dead from None
            finally:
                bar.close()
                if collector is not None:
                    collector.shutdown()
    else:
        log.info(
            "%s already trained %d of %d env steps; nothing to do (a video: gcnt eval %s "
            "--video)", run.path, env_steps, total, run.path,
        )  # fmt: skip
        env.close()
        if run.step_file("eval", env_steps).exists():  # its final evaluation is kept as it is
            finish(recipe, run, algo, logger, env_steps, evaluate_now=False)
            return run
    train_s = time.perf_counter() - t0
    results = finish(recipe, run, algo, logger, env_steps)
    log_summary(
        run, env_steps - start, train_s, time.perf_counter() - t0, results, [r.name for r in robots]
    )
    return run


def progress_bar(recipe: Recipe, total: int, env_steps: int) -> tqdm:
    """The terminal progress bar (``logger.progress``); off when stderr is not a terminal, so
    that a log file gets the log lines (one per ``logger.log_interval``) and no carriage
    returns."""
    on = recipe.logger.progress and sys.stderr.isatty()
    return tqdm(total=total, initial=env_steps, unit="step", disable=not on)


def log_summary(
    run: RunDir,
    env_steps: int,
    train_s: float,
    wall_s: float,
    results: dict | None,
    train_robots: Iterable[str] = (),
) -> None:
    """The end of training in a few lines: wall time, env steps/s (while training, the final
    evaluation left out), final evaluation per robot, each marked as a training robot (one of
    ``train_robots``) or a test robot; a standard error only where there are several
    episodes."""
    log.info(
        "finished %s: %d env steps, wall time %.1f min, %.0f env steps/s",
        run.path,
        env_steps,
        wall_s / 60,
        env_steps / max(train_s, 1e-9),
    )
    trained = set(train_robots)
    for name, r in (results or {}).items():
        spread = f" ± {r['stderr']:.1f}" if r["episodes"] > 1 else ""
        log.info(
            "final evaluation %s (%s): %.1f%s (%s)",
            name,
            "training robot" if name in trained else "test robot",
            r["mean"],
            spread,
            f"{r['episodes']} episode{'s' if r['episodes'] != 1 else ''}",
        )


def resume_checkpoint(run: RunDir, algo: Algorithm) -> int:
    """Load the run's checkpoint into ``algo`` (learner state, global RNG state, buffers), drop
    the metrics rows logged after it and set aside the evaluations and videos written after it
    (:meth:`RunDir.set_aside_after`); returns its env steps."""
    state = run.load_checkpoint()
    try:
        algo.load_state_dict(state["learner"])
    except CHECKPOINT_MISFITS as e:
        raise CheckpointError(
            f"{run.checkpoint_path} does not fit the recipe's networks (was the recipe "
            f"changed since training?): {str(e).splitlines()[0] if str(e) else repr(e)}"
        ) from None
    env_steps = state["env_steps"]
    try:
        set_rng_state(state["rng"])
    except CHECKPOINT_MISFITS as e:
        raise CheckpointError(
            f"{run.checkpoint_path}: its random state is not one gcnt wrote "
            f"({type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''})"
        ) from None
    if state.get("has_buffers"):
        algo.load_buffers(run.buffers_dir)
    run.truncate_metrics(env_steps)
    for path in run.set_aside_after(env_steps):
        log.info("written after the checkpoint, set aside: %s", path)
    log.info("resuming %s at %d env steps, %d updates", run.path, env_steps, algo.updates)
    return env_steps


def follow_algorithm(collector, settings: CollectSettings, algo: Algorithm, env_steps: int):
    """After a batch: end the collector's random phase once the algorithm counted its random
    steps (``settings.random_steps``), and start a new episode in every sub-env when the
    algorithm asks for it."""
    if settings.random_steps is not None and env_steps >= settings.random_steps:
        collector.init_random_frames = 0
    if algo.reset_due():
        collector.reset()


def start_collector(recipe: Recipe, env: EnvBase, settings: CollectSettings, run: RunDir):
    """:func:`make_collector`; a worker process that dies while the collector starts, at any
    moment (watched by :func:`worker_watch`: torchrl waits for each worker's word that its envs
    are built, and multiprocessing's launch of a worker waits for it to read its start-up
    data), is a :class:`WorkerDiedError`, not torchrl's traceback or a wait without end. The
    half-built collector is ended here, its workers and its weight channels, while new threads
    can still start: left to the garbage collector at exit, its channels' clean-up would wait
    forever for a thread that can no longer start."""
    if settings.env_makers is None:
        return make_collector(recipe, env, settings)
    try:
        with worker_watch(None, run):
            return make_collector(recipe, env, settings)
    except Exception as e:  # noqa: BLE001 - which worker failed, and how, is said below
        half_built = _collector_in(e.__traceback__)
        detail = str(e).splitlines()[0] if str(e) else type(e).__name__
        dead = e if isinstance(e, WorkerDiedError) else None
    if half_built is not None:
        end_workers(half_built)
        for scheme in (getattr(half_built, "_weight_sync_schemes", None) or {}).values():
            with contextlib.suppress(Exception):
                scheme.shutdown()
        dead = dead or dead_worker(half_built, run)
    del half_built
    import gc

    gc.collect()  # the collector and what it holds, now rather than at exit
    then = (
        f"what was checkpointed is kept: continue with gcnt train --resume {run.path}"
        if run.has_checkpoint()
        else "nothing was trained yet: run the same command again"
    )
    if dead is not None:
        raise WorkerDiedError(f"{str(dead).split(';')[0]} while starting up; {then}")
    raise WorkerDiedError(f"a collector worker failed to start ({detail}); {then}")


def _collector_in(tb: Any) -> Any:
    """The collector whose construction raised, from the traceback's frames (None: none)."""
    found = None
    while tb is not None:
        candidate = tb.tb_frame.f_locals.get("self")
        if isinstance(candidate, MultiSyncCollector):
            found = candidate
        tb = tb.tb_next
    return found


def make_collector(recipe: Recipe, env: EnvBase, settings: CollectSettings):
    """The torchrl collector of ``settings`` over ``env`` (or over its worker env makers)."""
    multi = settings.env_makers is not None
    # torchrl's multi-process collectors lower this process's torch threads to the cores left
    # over by the workers (none on 2 cores: one thread). A sync collector's workers wait while
    # this process updates, so the update keeps its threads (on 2 cores, PPO's update on one
    # thread took 1.67-1.76 s per iteration against 1.13-1.38 s on two).
    threads = {"num_threads": torch.get_num_threads()} if multi else {}
    return (MultiSyncCollector if multi else Collector)(
        settings.env_makers if multi else env,
        settings.policy,
        frames_per_batch=settings.frames_per_batch,
        total_frames=-1,
        init_random_frames=settings.init_random_frames,
        policy_device=recipe.device,  # networks on the recipe's device, MuJoCo on the CPU
        env_device="cpu",
        storing_device="cpu",
        auto_register_policy_transforms=False,  # the policies need no InitTracker
        **collector_kwargs(recipe.compile),  # compile.policy_compile / policy_cudagraphs
        **threads,
    )


def after_update(
    recipe: Recipe,
    run: RunDir,
    algo: Algorithm,
    logger,
    stats: TrainStats,
    cadence: Cadence,
    rows: Iterable[dict[str, float]],
    env_steps: int,
) -> dict | None:
    """What follows a batch's update phase (``rows``: its loss rows, as ``Algorithm.process``
    yields them): the rows counted and checked, the policy checked before it acts again (a run
    stops at a non-finite loss or weight), then logging, checkpoint and evaluation when due.
    Returns the logged row, if one was."""
    for losses in rows:
        stats.add_losses(losses)
        _check_losses(run, losses, env_steps, algo.updates)
    check_policy(run, algo, env_steps)
    return cadence.after_batch(recipe, run, algo, logger, stats, env_steps)


def check_policy(run: RunDir, algo: Algorithm, env_steps: int) -> None:
    """Stop (TrainingDivergedError) when the policy's weights are not all finite."""
    policy = algo.policy_state()
    if not _all_finite(policy):
        raise _diverged(run, f"non-finite policy weights in {_non_finite(policy)}", env_steps)


class Cadence:
    """When a run logs, checkpoints and evaluates next (env-step thresholds from the recipe)."""

    def __init__(self, recipe: Recipe, env_steps: int) -> None:
        self.total = recipe.collector.total_frames
        self.next_log = _next_multiple(env_steps, recipe.logger.log_interval)
        self.next_ckpt = _next_multiple(env_steps, recipe.checkpoint_interval)
        self.checkpointed = env_steps  # the env steps of the run's last checkpoint
        self.next_eval = (
            _next_multiple(env_steps, recipe.eval.interval) if recipe.eval.interval else None
        )

    def after_batch(
        self,
        recipe: Recipe,
        run: RunDir,
        algo: Algorithm,
        logger,
        stats: TrainStats,
        env_steps: int,
    ) -> dict | None:
        """Log, checkpoint and evaluate, each when due, after a batch that brought the run to
        ``env_steps`` (the last batch logs and checkpoints; its evaluation is
        :func:`finish`'s); returns the logged row, if one was."""
        last = env_steps >= self.total
        row = None
        if env_steps >= self.next_log or last:
            row = {**stats.row(env_steps, algo.updates), **algo.log_extras()}
            _log_row(run, logger, row)
            self.next_log = _next_multiple(env_steps, recipe.logger.log_interval)
        if env_steps >= self.next_ckpt or last:
            _checkpoint(run, algo, env_steps)
            self.checkpointed = env_steps
            self.next_ckpt = _next_multiple(env_steps, recipe.checkpoint_interval)
        if self.next_eval is not None and env_steps >= self.next_eval and not last:
            _evaluate(recipe, run, algo, logger, env_steps)
            self.next_eval = _next_multiple(env_steps, recipe.eval.interval)
        if logger is not None and not last:  # the last row waits for the final evaluation
            logger.flush()
        return row


def checkpoint_since(run: RunDir, algo: Algorithm, cadence: Cadence, env_steps: int) -> None:
    """Checkpoint at ``env_steps`` unless the run's last checkpoint is there already."""
    if cadence.checkpointed != env_steps:
        _checkpoint(run, algo, env_steps)
        cadence.checkpointed = env_steps


def stop_here(
    recipe: Recipe | list[Recipe],
    runs: list[RunDir],
    algos: list[Algorithm],
    loggers: list,
    cadences: list[Cadence],
    env_steps: list[int],
) -> NoReturn:
    """A stop was requested (:mod:`gcnt.rl.stop`): checkpoint each run where its last
    checkpoint is older, close its logger, raise TrainingStopped. ``recipe``: one per run, or
    one for all. Called between batches, where the learner's state is whole."""
    recipes = recipe if isinstance(recipe, list) else [recipe] * len(runs)
    for r, run, algo, logger, cadence, steps in zip(
        recipes, runs, algos, loggers, cadences, env_steps, strict=True
    ):
        checkpoint_since(run, algo, cadence, steps)
        finish(r, run, algo, logger, steps, evaluate_now=False)
    raise stop.TrainingStopped(
        stop.requested() or "a stop request", [str(r.path) for r in runs], list(env_steps)
    )


def finish(
    recipe: Recipe,
    run: RunDir,
    algo: Algorithm,
    logger,
    env_steps: int,
    *,
    evaluate_now: bool = True,
) -> dict | None:
    """The final evaluation (unless not ``evaluate_now``; in the W&B run's summary), and the
    logger's run closed; returns the evaluation's results per robot (None when none ran)."""
    results = _evaluate(recipe, run, algo, logger, env_steps) if evaluate_now else None
    if logger is not None and results is not None:
        logger.summarize(results, env_steps)
    signame = stop.requested()
    if signame is not None and evaluate_now:
        # training was already complete and checkpointed; the evaluation is not cut short
        log.warning(
            "%s arrived during the final evaluation of %s: the run had finished training (its "
            "last checkpoint is written), so the evaluation was completed before stopping",
            signame, run.path,
        )  # fmt: skip
    if logger is not None:
        logger.save_files(run.recipe_path, run.path / provenance.PROVENANCE_FILE, base=run.path)
        logger.close()
    return results


def _next_multiple(x: int, every: int) -> int:
    return (x // every + 1) * every if every > 0 else 2**62


def _log_row(run: RunDir, logger: RunLogger | None, row: dict) -> None:
    run.log_metrics(row)
    if logger is not None:
        logger.add(row["env_steps"], {k: v for k, v in row.items() if k != "env_steps"})
    log.info(
        "env_steps %d  updates %d  return %.1f  %.0f steps/s",
        row["env_steps"],
        row["updates"],
        row.get("train_return/mean", float("nan")),
        row["env_steps_per_s"],
    )


def _diverged(run: RunDir, what: str, env_steps: int) -> TrainingDivergedError:
    kept = (
        f"the last good checkpoint ({run.checkpoint_path}) was kept"
        if run.has_checkpoint()
        else "no checkpoint had been written yet"
    )
    return TrainingDivergedError(
        f"training diverged at {env_steps} env steps: {what}; stopped, {kept}. Lower the "
        "learning rate or clip the gradients, and train again"
    )


def _check_losses(run: RunDir, losses: dict, env_steps: int, updates: int) -> None:
    """Stop at the first update whose losses (keys ``loss*``) are NaN or infinite; other
    diagnostics (explained variance, clip fractions) may be NaN legitimately."""
    for key, value in losses.items():
        if key.startswith("loss") and not math.isfinite(float(value)):
            raise _diverged(run, f"{key} is {float(value)} at update {updates}", env_steps)


def _checkpoint(run: RunDir, algo: Algorithm, env_steps: int) -> None:
    """Write the checkpoint, unless the weights went non-finite (the last good one stays)."""
    learner = algo.state_dict()
    if not _all_finite(learner):  # one check; the slow per-tensor search only to name the culprit
        raise _diverged(run, f"non-finite values in {_non_finite(learner)}", env_steps)
    has_buffers = algo.buffers_state(run.buffers_dir)
    run.save_checkpoint(
        {
            "algo": algo.name,
            "learner": learner,
            "policy": algo.policy_state(),  # for `gcnt eval` without rebuilding the learner
            "env_steps": env_steps,
            "has_buffers": has_buffers,
        }
    )


def _all_finite(state) -> bool:
    """Whether every floating-point tensor of a (nested) state dict is finite (one device sync
    per device: a learner's state mixes the networks' device with CPU counters and buffers).

    Per device and dtype, first one fused norm per tensor (``torch._foreach_norm``: a non-finite
    element makes its norm non-finite, so finite norms prove every element finite); only when a
    norm is not finite (a NaN, an inf, or finite weights so large that the norm overflows) each
    tensor is checked element by element, which decides. Tensors on the ``meta`` device hold no
    values and are skipped."""
    groups: dict[tuple[torch.device, torch.dtype], list[torch.Tensor]] = defaultdict(list)
    stack = [state]
    while stack:
        x = stack.pop()
        if isinstance(x, torch.Tensor):
            if x.is_floating_point() and x.numel() and x.device.type != "meta":
                groups[(x.device, x.dtype)].append(x)
        elif isinstance(x, dict):
            stack.extend(x.values())
        elif isinstance(x, (list, tuple)):
            stack.extend(x)
    for tensors in groups.values():
        norms = torch._foreach_norm(tensors)
        if bool(torch.isfinite(torch.stack(norms)).all()):
            continue
        if not bool(torch.stack([torch.isfinite(t).all() for t in tensors]).all()):
            return False
    return True


def _non_finite(state, prefix: str = "") -> str | None:
    """The first floating-point tensor in a (nested) state dict that holds NaN or inf."""
    if isinstance(state, torch.Tensor):
        if state.is_floating_point() and not bool(torch.isfinite(state).all()):
            return prefix or "a tensor"
        return None
    if isinstance(state, dict):
        items = state.items()
    elif isinstance(state, (list, tuple)):
        items = enumerate(state)
    else:
        return None
    for k, v in items:
        found = _non_finite(v, f"{prefix}.{k}" if prefix else str(k))
        if found:
            return found
    return None


def _eval_specs(recipe: Recipe) -> list[str]:
    return recipe.eval.robots or [*recipe.env.robots, *recipe.env.test_robots]


def _evaluate(
    recipe: Recipe, run: RunDir, algo: Algorithm, logger, env_steps: int
) -> dict[str, dict] | None:
    specs = _eval_specs(recipe)
    if recipe.eval.episodes <= 0 or not specs:
        return None
    policy = algo.policy_state()
    results = evaluate(
        recipe,
        policy,
        specs,
        episodes=recipe.eval.episodes,
        deterministic=recipe.eval.deterministic,
    )
    path = write_eval(
        run.step_file("eval", env_steps),
        results,
        env_steps,
        meta={
            "robots_spec": list(specs),
            "episodes": recipe.eval.episodes,
            "deterministic": recipe.eval.deterministic,
        },
    )
    if logger is not None:
        row = {f"eval_return/{name}": res["mean"] for name, res in results.items()}
        row["eval_return/mean"] = float(np.mean([res["mean"] for res in results.values()]))
        row |= {f"eval_length/{name}": res["length_mean"] for name, res in results.items()
                if "length_mean" in res}  # fmt: skip
        logger.add(env_steps, row)
    log.info("eval at %d steps written to %s", env_steps, Path(path))
    if recipe.eval.video:
        out = render_policy(recipe, policy, run.step_file("videos", env_steps))
        log.info("video written to %s", out)
        if logger is not None:
            logger.add_video(env_steps, out)
    return results
