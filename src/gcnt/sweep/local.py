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

from gcnt.sweep.manifest import Manifest
from gcnt.sweep.spec import RunSpec, commands
from gcnt.sweep.status import ACTIVE, now

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


def run_local(
    manifest: Manifest,
    *,
    jobs: int,
    cpus_per_run: int = 1,
    poll: float = 0.5,
    on_change: Callable[[RunSpec], None] | None = None,
) -> Manifest:
    """Run what is left of every run in a pool of ``jobs`` pinned slots; save the manifest on
    every change. A run another process trains (its lock is held) is left alone. Ctrl-C stops
    the children, which checkpoint first (``gcnt train`` on SIGINT/SIGTERM)."""
    from gcnt.rl.run_lock import holder

    todo = [r for r in manifest.runs if r.state not in ACTIVE and commands(r)]
    slots = slot_cores(jobs, cpus_per_run)
    free = list(range(jobs))
    active: dict[int, tuple[subprocess.Popen, RunSpec, list, Any, float]] = {}
    sweep_dir = manifest.dir

    def start(slot: int, spec: RunSpec, steps: list) -> None:
        what, argv = steps[0]
        logf = run_log_path(sweep_dir, spec)
        logf.parent.mkdir(parents=True, exist_ok=True)
        fh = logf.open("a")
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
        spec.log = str(logf)
        if what == "train":
            spec.state, spec.started, spec.returncode = "running", now(), None
        active[slot] = (proc, spec, steps, fh, time.monotonic())
        manifest.save()
        if on_change:
            on_change(spec)

    try:
        while todo or active:
            while free and todo:
                spec = todo.pop(0)
                if (who := holder(spec.run_dir)) is not None:  # another process trains it
                    log.warning("%s: trained by %s; not started", spec.id, who)
                    spec.state = "running"
                    continue
                start(free.pop(0), spec, commands(spec))
            time.sleep(poll)
            for slot in list(active):
                proc, spec, steps, fh, t0 = active[slot]
                rc = proc.poll()
                if rc is None:
                    continue
                fh.close()
                del active[slot]
                what = steps[0][0]
                finish_step(spec, what, rc)
                if what == "train":
                    spec.finished, spec.seconds = now(), round(time.monotonic() - t0, 1)
                rest = steps[1:] if (what != "train" or spec.state == "done") else []
                manifest.save()
                if on_change:
                    on_change(spec)
                if rest:
                    start(slot, spec, rest)
                else:
                    free.append(slot)
    except KeyboardInterrupt:
        for proc, *_ in active.values():
            proc.send_signal(signal.SIGTERM)
        for proc, spec, _, fh, _ in active.values():
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
            fh.close()
            spec.state = spec.files_state()
        manifest.save()
        raise
    return manifest
