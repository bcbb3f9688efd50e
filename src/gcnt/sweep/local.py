"""The local pool: ``jobs`` slots, each pinned to its own cores (CPU affinity and thread
counts), running each run's commands as subprocesses."""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from gcnt.files import NotRegularFileError, check_replaceable, open_append
from gcnt.sweep.manifest import Manifest
from gcnt.sweep.spec import NO_RECIPE_PLUGINS, RunSpec, commands, gcnt_command
from gcnt.sweep.status import ACTIVE, SweepError, now

log = logging.getLogger(__name__)


THREAD_VARS = (
    "OMP_NUM_THREADS",
    "MKL_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "NUMEXPR_NUM_THREADS",
    "VECLIB_MAXIMUM_THREADS",
)


def available_cores() -> list[int]:
    try:
        return sorted(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return list(range(os.cpu_count() or 1))


def pinned_env(threads: int, base: dict[str, str] | None = None) -> dict[str, str]:
    env = dict(os.environ if base is None else base)
    for var in THREAD_VARS:
        env[var] = str(threads)
    return env


def slot_cores(jobs: int, cpus_per_run: int, cores: Sequence[int] | None = None) -> list[list[int]]:
    """The cores of each of ``jobs`` slots: disjoint blocks while there are enough cores,
    wrapping around (shared) otherwise."""
    cores = list(cores if cores is not None else available_cores())
    return [
        [cores[(s * cpus_per_run + i) % len(cores)] for i in range(cpus_per_run)]
        for s in range(jobs)
    ]


def default_jobs(cpus_per_run: int, cores: Sequence[int] | None = None) -> int:
    n = len(cores if cores is not None else available_cores())
    return max(1, n // max(1, cpus_per_run))


def run_log_path(sweep_dir: Path, spec: RunSpec) -> Path:
    return sweep_dir / "logs" / f"{spec.id.replace('/', '__')}.log"


def finish_step(spec: RunSpec, what: str, rc: int) -> None:
    from gcnt.rl.stop import EXIT_STOPPED

    if what == "train":
        spec.returncode = rc
        files = spec.files_state()
        if rc == EXIT_STOPPED:  # stopped on request, its checkpoint written: not a failure
            spec.state = files
        elif rc != 0:
            spec.state = "failed"
        else:  # "partial": exited cleanly but short of total_frames
            spec.state = "done" if files == "done" else "partial"
    else:
        spec.eval_state[what.split(":", 1)[1]] = "done" if rc == 0 else "failed"


#: the exit code of ``gcnt train`` refusing its input (one error line): a stacked start refused
#: so trains its seeds one by one; a stopped or killed one (another code) is left as it is
REFUSED = 2

#: seconds a stopped child has to write its checkpoint before it is killed
STOP_WAIT_S = 120

#: overrides that differ between the seeds of one experiment in a sweep
_PER_SEED = ("seed=", "run_dir=", "logger.name=")


def _experiment_key(spec: RunSpec) -> tuple:
    """What the seeds of one experiment share: recipe, method, robot and the other overrides."""
    rest = tuple(o for o in spec.overrides if not o.startswith(_PER_SEED))
    return (spec.recipe, spec.method, spec.robot, rest)


def _stack_by_default(spec: RunSpec, stack: bool | None) -> bool:
    """Whether the seeds of ``spec``'s experiment train in one process: the stacked update
    needs the mixed schedule (every seed's mini-batch holds the same robots in the same places);
    by default (``stack`` None) only on a CUDA device. A recipe that cannot be read: alone."""
    from gcnt.recipes import RecipeError, load_recipe

    try:
        recipe = load_recipe(spec.recipe, spec.overrides)
    except (RecipeError, OSError):
        return False
    if recipe.td3.schedule != "mixed":
        if stack:
            log.warning(
                "%s: stacked seeds need td3.schedule=mixed (it is %s): its seeds train one by one",
                str(Path(spec.run_dir).parent),
                recipe.td3.schedule,
            )
        return False
    return bool(stack) or recipe.device.startswith("cuda")


def stacked_groups(specs: Sequence[RunSpec], stack: bool | None) -> list[list[RunSpec]]:
    """The runs to start, as groups that one process trains: the TD3 seeds of one experiment
    that have not started (``gcnt train --seeds``: one vmapped update, one process) when
    ``stack`` is True, or None and the runs train on a CUDA device (processes sharing one GPU
    take turns on it, so seeds gain only when they share a process), and their schedule is the
    mixed one; every other run alone.
    A run already begun continues alone (``--resume``)."""
    groups: dict[tuple, list[RunSpec]] = {}
    out: list[list[RunSpec]] = []
    for spec in specs:
        fresh = spec.algo == "td3" and spec.files_state() == "pending" and spec.state != "done"
        if not fresh or stack is False:
            out.append([spec])
            continue
        key = _experiment_key(spec)
        if key not in groups:
            groups[key] = []
            out.append(groups[key])
        groups[key].append(spec)
    split: list[list[RunSpec]] = []
    for group in out:
        if len(group) > 1 and _stack_by_default(group[0], stack):
            split.append(group)
        else:
            split.extend([s] for s in group)
    return split


def stacked_command(group: Sequence[RunSpec]) -> list[str]:
    """``gcnt train RECIPE ... run_dir=<parent> --seeds A,B,...``: the seeds' run directories
    are ``<parent>/seed<N>``, where the sweep put each of them."""
    first = group[0]
    parent = Path(first.run_dir).parent
    for spec in group:
        if Path(spec.run_dir) != parent / f"seed{spec.seed}":
            raise ValueError(f"{spec.id}: not a seed directory of {parent}")
    rest = [o for o in first.overrides if not o.startswith(_PER_SEED)]
    seeds = ",".join(str(s.seed) for s in group)
    return [
        *gcnt_command(),
        "train",
        first.recipe,
        *rest,
        NO_RECIPE_PLUGINS,
        f"run_dir={parent}",
        "--seeds",
        seeds,
    ]


def run_local(
    manifest: Manifest,
    *,
    jobs: int,
    cpus_per_run: int = 1,
    poll: float = 0.5,
    on_change: Callable[[RunSpec], None] | None = None,
    stack_seeds: bool | None = False,
) -> Manifest:
    """Run what is left of every run in a pool of ``jobs`` pinned slots; save the manifest on
    every change. A run another process trains (its lock is held) is left alone. Ctrl-C stops
    the children, which checkpoint first (``gcnt train`` on SIGINT/SIGTERM). ``stack_seeds``:
    the seeds of one TD3 experiment train in one process (:func:`stacked_groups`; None: on a
    CUDA device only); a stacked start that is refused before it made any run directory (a
    method the stacked update cannot vmap) runs its seeds one by one instead."""
    from gcnt.run.lock import holder

    fresh = [r for r in manifest.runs if r.state not in ACTIVE and commands(r)]
    for r in fresh:  # a FIFO or a link as a log: refused before any run starts
        try:
            check_replaceable(run_log_path(manifest.dir, r))
        except NotRegularFileError as e:
            raise SweepError(f"{e}; it is where the run's output is logged") from None
    todo: list[tuple[list[RunSpec], list]] = []
    for group in stacked_groups(fresh, stack_seeds):
        steps = commands(group[0]) if len(group) == 1 else [("train", stacked_command(group))]
        todo.append((group, steps))
    slots = slot_cores(jobs, cpus_per_run)
    free = list(range(jobs))
    active: dict[int, tuple[subprocess.Popen, list[RunSpec], list, Any, float]] = {}
    sweep_dir = manifest.dir

    def start(slot: int, group: list[RunSpec], steps: list) -> None:
        what, argv = steps[0]
        logf = run_log_path(sweep_dir, group[0])
        logf.parent.mkdir(parents=True, exist_ok=True)
        fh = open_append(logf)
        fh.write(f"\n# {now()} slot {slot} cores {slots[slot]}: {' '.join(argv)}\n")
        fh.flush()
        cores = set(slots[slot])
        proc = subprocess.Popen(
            argv,
            stdout=fh,
            stderr=subprocess.STDOUT,
            env=pinned_env(len(cores)),
            preexec_fn=(lambda: os.sched_setaffinity(0, cores))
            if hasattr(os, "sched_setaffinity")
            else None,
        )
        for spec in group:
            spec.log = str(logf)
            if what == "train":
                spec.state, spec.started, spec.returncode = "running", now(), None
        active[slot] = (proc, group, steps, fh, time.monotonic())
        manifest.save()
        if on_change and what == "train":  # an evaluation starting changes no state: the
            for spec in group:  # run's "done" line is reported once, when training ends
                on_change(spec)

    def refused_stack(group: list[RunSpec], what: str, rc: int) -> bool:
        """A stacked start refused before it made any run directory (exit code 2: the stacked
        update cannot take the method): its seeds are queued to run one by one."""
        if len(group) == 1 or what != "train" or rc != REFUSED:
            return False
        if any(spec.files_state() != "pending" for spec in group):
            return False
        log.warning(
            "%s: the seeds %s could not train in one process (see %s); training them one by one",
            str(Path(group[0].run_dir).parent),
            ",".join(str(spec.seed) for spec in group),
            group[0].log,
        )
        for spec in group:
            spec.state = "pending"
            todo.append(([spec], commands(spec)))
        return True

    def terminate(signum: int, _frame: object) -> None:  # as Ctrl-C: the children stop first
        raise KeyboardInterrupt(f"stopped by {signal.Signals(signum).name}")

    previous = signal.signal(signal.SIGTERM, terminate)
    try:
        while todo or active:
            while free and todo:
                group, steps = todo.pop(0)
                held = [(spec, holder(spec.run_dir)) for spec in group]
                for spec, who in held:
                    if who is not None:  # another process trains it
                        log.warning("%s: trained by %s; not started", spec.id, who)
                        spec.state = "running"
                if any(who is not None for _, who in held):
                    # the others of a stacked group start alone
                    todo[:0] = [([spec], commands(spec)) for spec, who in held if who is None]
                    continue
                start(free.pop(0), group, steps)
            time.sleep(poll)
            for slot in list(active):
                proc, group, steps, fh, t0 = active[slot]
                rc = proc.poll()
                if rc is None:
                    continue
                fh.close()
                del active[slot]
                what = steps[0][0]
                if refused_stack(group, what, rc):
                    manifest.save()
                    free.append(slot)
                    continue
                for spec in group:
                    finish_step(spec, what, rc)
                    if what == "train":
                        spec.finished, spec.seconds = now(), round(time.monotonic() - t0, 1)
                manifest.save()
                if on_change:
                    for spec in group:
                        on_change(spec)
                spec = group[0]
                if len(group) == 1 and (what != "train" or spec.state == "done") and steps[1:]:
                    start(slot, group, steps[1:])
                    continue
                if len(group) > 1:  # each seed's evaluations, as runs of their own
                    todo.extend(
                        ([s], commands(s)) for s in group if s.state == "done" and commands(s)
                    )
                free.append(slot)
    except KeyboardInterrupt:
        signal.signal(signal.SIGTERM, signal.SIG_IGN)  # a second SIGTERM: the children still end
        for proc, *_ in active.values():
            proc.send_signal(signal.SIGTERM)
        for proc, group, _, fh, _ in active.values():
            try:
                proc.wait(timeout=STOP_WAIT_S)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            fh.close()
            for spec in group:
                spec.state = spec.files_state()
        manifest.save()
        raise
    finally:
        signal.signal(signal.SIGTERM, previous)
    return manifest
