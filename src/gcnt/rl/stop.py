"""Stopping a run on request: SIGTERM (Slurm's cancel and time limit, ``kill``), SIGINT (Ctrl-C)
and SIGUSR2 (submitit's warning before a Slurm time limit) set a flag; the training loop checks it
after each batch's update (:func:`requested`), writes a checkpoint and raises
:class:`TrainingStopped`, which ``gcnt train`` reports in one line with exit code
:data:`EXIT_STOPPED`.

A signal only sets the flag because a checkpoint written from inside a signal handler could
catch the learner in the middle of an update. A second SIGINT stops at once (KeyboardInterrupt).

The main thread also blocks the three signals while training, and every process it starts
inherits that mask (across ``fork`` and ``exec``): Slurm signals every process of a job step,
and a collector worker or multiprocessing's resource tracker killed by SIGUSR2 or SIGTERM would
break the run before it could checkpoint. A watcher thread takes the blocked signals
(``sigtimedwait``) and sets the flag.
"""

from __future__ import annotations

import _thread
import contextlib
import signal
import threading

#: ``gcnt train``'s exit code after a requested stop with its checkpoint written (sysexits'
#: EX_TEMPFAIL: try again later), so that a sweep tells an interrupted run from a failed one
EXIT_STOPPED = 75

#: seconds between two looks for a pending stop signal
POLL_S = 0.2

SIGNALS = tuple(
    s for s in (signal.SIGTERM, signal.SIGINT, getattr(signal, "SIGUSR2", None)) if s is not None
)


class TrainingStopped(Exception):
    """A stop was requested; the run's checkpoint at ``env_steps`` was written."""

    def __init__(self, signame: str, run_dirs: list[str], env_steps: list[int]) -> None:
        self.signame, self.run_dirs, self.env_steps = signame, run_dirs, env_steps
        where = ", ".join(f"{d} at {n} env steps" for d, n in zip(run_dirs, env_steps, strict=True))
        resume = "; ".join(f"gcnt train --resume {d}" for d in run_dirs)
        super().__init__(f"stopped by {signame}: checkpoint of {where} written; continue: {resume}")


#: the request of the innermost :func:`stop_on_signals` block (None outside one)
_ACTIVE: list[StopRequest] = []


def requested() -> str | None:
    """The signal that asked to stop (e.g. ``"SIGTERM"``), or None: train on."""
    return _ACTIVE[-1].signame if _ACTIVE else None


class StopRequest:
    """Which signal asked the process to stop (None: none yet)."""

    def __init__(self) -> None:
        self.signame: str | None = None
        self._closing = threading.Event()

    @property
    def requested(self) -> bool:
        return self.signame is not None

    def _handle(self, signum: int, frame) -> None:
        if signum == signal.SIGINT and self.signame == "SIGINT":
            raise KeyboardInterrupt
        if self.signame is None:
            self.signame = signal.Signals(signum).name

    def _watch(self) -> None:
        """Take the blocked signals as they arrive (a second SIGINT interrupts the main
        thread)."""
        wanted = {int(s) for s in SIGNALS}
        while not self._closing.is_set():
            # a poll (timeout 0), the sleep between polls on an event: a sigtimedwait that sleeps
            # and is cut short by another signal (the SIGALRM of training's timers, a SIGCONT)
            # as its time runs out returns a siginfo that was never filled in (CPython 3.11),
            # which may still hold an earlier signal's number
            try:
                info = signal.sigtimedwait(SIGNALS, 0)
            except OSError:
                info = None
            if info is None or info.si_signo not in wanted:
                self._closing.wait(POLL_S)
                continue
            if info.si_signo == signal.SIGINT and self.signame == "SIGINT":
                _thread.interrupt_main()
            elif self.signame is None:
                self.signame = signal.Signals(info.si_signo).name


@contextlib.contextmanager
def stop_on_signals():
    """A :class:`StopRequest` set by SIGTERM, SIGINT or SIGUSR2 while the block runs (the
    previous handlers back afterwards). Off the main thread, where Python cannot take signals,
    the request is never set."""
    stop = StopRequest()
    if threading.current_thread() is not threading.main_thread():
        yield stop
        return
    # a handler as well: a blocked signal must not meet SIG_IGN (inherited from a parent that
    # ignores it while this process starts), and a thread made before the block may receive one
    previous = {s: signal.signal(s, stop._handle) for s in SIGNALS}
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, SIGNALS)
    watcher = threading.Thread(target=stop._watch, name="gcnt-stop-signals", daemon=True)
    watcher.start()
    _ACTIVE.append(stop)
    try:
        yield stop
    finally:
        _ACTIVE.remove(stop)
        stop._closing.set()
        watcher.join()
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)  # a pending one reaches stop._handle
        for s, handler in previous.items():
            signal.signal(s, handler)
