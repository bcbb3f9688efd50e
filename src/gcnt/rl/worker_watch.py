"""Watching a multi-process collector's workers from the run loop's main thread.

A worker process can end (the OOM killer, ``kill -9``) or be stopped (SIGSTOP) while the main
thread waits inside torchrl for its batch, its acknowledgement of new weights or its start-up;
torchrl would then wait without end. :func:`worker_watch` checks the workers on a SIGALRM timer,
which also interrupts such a wait, and raises :class:`WorkerDiedError` (one line, naming the
worker and ``gcnt train --resume``); :func:`end_workers` ends the ones still alive beside it.
"""

from __future__ import annotations

import contextlib
import signal
import time
from collections.abc import Iterator
from typing import Any

from torchrl.collectors import MultiSyncCollector

from gcnt.files import KiB, read_text
from gcnt.rl import stop
from gcnt.run.directory import RunDir


class WorkerDiedError(RuntimeError):
    """A collector worker process ended during the run (killed: the OOM killer, ``kill -9``);
    the last checkpoint is kept and the run resumes from it."""


def _worker_procs(collector: Any, launching: Any = None) -> list[Any]:
    """``collector``'s worker processes (``multiprocessing.Process``), then ``launching``: the
    ``Popen`` of a worker that the collector is starting now (not among them yet)."""
    procs = list(getattr(collector, "procs", None) or [])
    return procs + ([launching] if launching is not None else [])


def _exit_code(proc: Any) -> int | None:
    """How a worker process ended (None: it runs); a Process, or the Popen of one being
    started (reaped here: no Process will own it once its start fails)."""
    if hasattr(proc, "exitcode"):
        return proc.exitcode
    return proc.poll()


def dead_worker(collector: Any, run: RunDir, launching: Any = None) -> WorkerDiedError | None:
    """The error to report when one of ``collector``'s worker processes (or ``launching``, one
    it is starting) has ended (None: all live, or the collector has no workers)."""
    for i, proc in enumerate(_worker_procs(collector, launching)):
        try:
            code = _exit_code(proc)
        except ValueError:  # closed by the collector as it stopped the others
            continue
        if code is None or code == 0:
            continue
        how = f"killed by {signal.Signals(-code).name}" if code < 0 else f"exit code {code}"
        hint = " (out of memory?)" if code == -signal.SIGKILL else ""
        return WorkerDiedError(
            f"collector worker {i} ended ({how}){hint}; what was checkpointed is kept: "
            f"continue with gcnt train --resume {run.path}"
        )
    return None


#: how long a collector worker may stay stopped (SIGSTOP, SIGTSTP) before the run ends
STOPPED_WORKER_S = 10.0
#: how long a requested stop waits for a batch before it checkpoints without it (below Slurm's
#: default 30 s between SIGTERM and SIGKILL); with a stopped worker it waits no longer
STOP_WAIT_S = 20.0


class StopWhileWaiting(Exception):
    """A stop was requested while the main thread waits for a batch that does not come (a
    worker is stopped, or :data:`STOP_WAIT_S` passed): checkpoint without it."""


class Waiting:
    """Whether the main thread waits for the collector's workers now (not in an update)."""

    def __init__(self) -> None:
        self.on = False

    def batches(self, collector: Any) -> Iterator[Any]:
        """``collector``'s batches, marked as waited for while each is awaited."""
        it = iter(collector)
        while True:
            with self:
                try:
                    data = next(it)
                except StopIteration:
                    return
            yield data

    def __enter__(self) -> Waiting:
        self.on = True
        return self

    def __exit__(self, *exc: object) -> None:
        self.on = False


def _stopped_workers(collector: Any, launching: Any = None) -> list[int]:
    """The indices of ``collector``'s worker processes (and ``launching``'s, see
    :func:`_worker_procs`) that are stopped (state ``T``)."""
    out = []
    for i, proc in enumerate(_worker_procs(collector, launching)):
        try:
            text = read_text(f"/proc/{proc.pid}/stat", 4 * KiB, "a worker's state", OSError)
        except (OSError, ValueError, TypeError):
            continue
        state = text.rpartition(")")[2].split()[:1]
        if state and state[0] in ("T", "t"):
            out.append(i)
    return out


@contextlib.contextmanager
def worker_watch(
    collector: Any, run: RunDir, every: float = 1.0, waiting: Waiting | None = None
) -> Iterator[None]:
    """While the block runs, check ``collector``'s worker processes every ``every`` seconds (a
    SIGALRM timer, which also interrupts a wait inside the collector) and raise the
    :class:`WorkerDiedError` of one that ended there, or that has been stopped (SIGSTOP) for
    :data:`STOPPED_WORKER_S`, wherever the main thread waits for it (its batch, or its
    acknowledgement of new weights). A stop requested while the main thread waits (per
    ``waiting``) for a stopped worker, or for :data:`STOP_WAIT_S`, raises
    :class:`StopWhileWaiting`. Only in the main thread.

    ``collector`` None: the block builds the collector (:func:`start_collector`); its workers
    are found in the main thread's frames as they start (:func:`_building`), the one being
    launched included, whose launch would otherwise wait forever for a worker killed before
    it read its start-up data. A worker being launched when the block fails is ended here: no
    collector owns it."""
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    stopped_since: dict[int, float] = {}
    stop_seen: list[float] = []
    raised: list[WorkerDiedError] = []  # once found, the same error at every tick
    launched: list[Any] = []  # the Popen of each worker seen being launched

    def check(signum, frame):
        now = time.monotonic()
        target, launching = (collector, None) if collector is not None else _building(frame)
        if launching is not None and all(p is not launching for p in launched):
            launched.append(launching)
        dead = raised[0] if raised else dead_worker(target, run, launching)
        stopped = _stopped_workers(target, launching)
        for i in list(stopped_since):
            if i not in stopped:
                del stopped_since[i]
        for i in stopped:
            since = stopped_since.setdefault(i, now)
            if dead is None and now - since >= STOPPED_WORKER_S:
                dead = WorkerDiedError(
                    f"collector worker {i} has been stopped (SIGSTOP?) for "
                    f"{STOPPED_WORKER_S:.0f} s; what was checkpointed is kept: continue with "
                    f"gcnt train --resume {run.path}"
                )
        # The timer stays armed after a raise: code the main thread is in may catch and log the
        # error (torchrl's wait for a worker's acknowledgement catches every Exception, its
        # constructor's clean-up waits for the workers), so it is raised again at every tick
        # until it leaves the block (whose exit disarms the timer)
        if dead is not None:
            raised[:1] = [dead]
            raise dead
        if stop.requested() and waiting is not None and waiting.on:
            stop_seen.append(now)
            if stopped or now - stop_seen[0] >= STOP_WAIT_S:
                raise StopWhileWaiting

    previous = signal.signal(signal.SIGALRM, check)
    signal.setitimer(signal.ITIMER_REAL, every, every)
    try:
        yield
    except BaseException:
        signal.setitimer(signal.ITIMER_REAL, 0)
        for popen in launched:  # started by a launch that failed: no collector ends it
            with contextlib.suppress(OSError, ValueError, AttributeError):
                if popen.poll() is None:
                    popen.kill()
                    popen.wait(10)
        raise
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def _building(frame: Any) -> tuple[Any, Any]:
    """From the main thread's ``frame`` up: the multi-process collector being built there
    (None: none), and the ``Popen`` of the worker process it is launching (None: none, or its
    pid is not known yet)."""
    from multiprocessing.popen_fork import Popen

    collector = launching = None
    # no error of its own may leave the handler: torchrl's worker start swallows a TypeError
    with contextlib.suppress(Exception):
        while frame is not None:
            me = frame.f_locals.get("self")
            if isinstance(me, MultiSyncCollector) and collector is None:
                collector = me  # (its truth value is its length, undefined while it is built)
            elif frame.f_code.co_name == "_launch" and isinstance(me, Popen):
                launching = me if getattr(me, "pid", None) else None
            frame = frame.f_back
    return collector, launching


def end_workers(collector: Any) -> None:
    """End the worker processes still alive beside a dead one (SIGTERM, then SIGKILL; a
    stopped one, which SIGTERM would not reach, SIGKILL at once)."""
    procs = [p for p in getattr(collector, "procs", None) or [] if not getattr(p, "_closed", False)]
    stopped = set(_stopped_workers(collector))
    for i, proc in enumerate(procs):
        with contextlib.suppress(ValueError, OSError):
            if proc.is_alive():
                proc.kill() if i in stopped else proc.terminate()
    for proc in procs:
        with contextlib.suppress(ValueError, OSError):
            proc.join(10)
            if proc.is_alive():
                proc.kill()
                proc.join(10)
