"""The stop-signal watcher survives whatever a timer does to its wait: flooded with SIGALRM (the
signal of training's own timers) it stays alive and still takes a SIGTERM."""

import os
import signal
import threading
import time

from gcnt.rl.stop import stop_on_signals


def test_the_watcher_outlives_a_sigalrm_flood_and_still_takes_sigterm():
    alarms = []
    previous = signal.signal(signal.SIGALRM, lambda *_: alarms.append(1))
    try:
        with stop_on_signals() as stop:
            signal.setitimer(signal.ITIMER_REAL, 0.0005, 0.0005)  # 2,000 SIGALRMs per second
            time.sleep(1.5)
            signal.setitimer(signal.ITIMER_REAL, 0, 0)
            watcher = [t for t in threading.enumerate() if t.name == "gcnt-stop-signals"]
            assert watcher and watcher[0].is_alive() and len(alarms) > 100
            assert not stop.requested
            os.kill(os.getpid(), signal.SIGTERM)
            deadline = time.monotonic() + 10
            while not stop.requested and time.monotonic() < deadline:
                time.sleep(0.01)
            assert stop.signame == "SIGTERM"
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0, 0)
        signal.signal(signal.SIGALRM, previous)


def test_an_unfilled_siginfo_or_an_interrupted_wait_leaves_the_watcher_taking_signals(
    monkeypatch,
):
    """What a wait cut short by a timer's signal was seen to return (a siginfo never filled in:
    ``si_signo`` -307623856) or raise: the watcher waits again, and the SIGTERM after it is
    taken."""
    from types import SimpleNamespace

    import gcnt.rl.stop as stop_module

    answers = [
        SimpleNamespace(si_signo=-307623856),
        OSError(4, "Interrupted system call"),
        SimpleNamespace(si_signo=int(signal.SIGALRM)),
        SimpleNamespace(si_signo=int(signal.SIGTERM)),
    ]

    def fake_wait(signals, timeout):
        if not answers:
            time.sleep(timeout)
            return None
        answer = answers.pop(0)
        if isinstance(answer, Exception):
            raise answer
        return answer

    monkeypatch.setattr(stop_module.signal, "sigtimedwait", fake_wait)
    with stop_on_signals() as stop:
        deadline = time.monotonic() + 10
        while not stop.requested and time.monotonic() < deadline:
            time.sleep(0.01)
        watcher = [t for t in threading.enumerate() if t.name == "gcnt-stop-signals"]
        assert stop.signame == "SIGTERM" and watcher and watcher[0].is_alive()


def test_the_watcher_polls_and_never_sleeps_inside_sigtimedwait(monkeypatch):
    """A sigtimedwait that sleeps can be cut short as its time runs out and then returns a
    siginfo never filled in, which may hold an earlier stop signal's number (a second SIGINT that
    was never sent): the watcher only polls (timeout 0) and sleeps on its own event."""
    import gcnt.rl.stop as stop_module

    timeouts: list[float] = []
    real_wait = signal.sigtimedwait

    def recording_wait(signals, timeout):
        timeouts.append(timeout)
        return real_wait(signals, timeout)

    monkeypatch.setattr(stop_module.signal, "sigtimedwait", recording_wait)
    with stop_on_signals() as stop:
        time.sleep(0.5)
        os.kill(os.getpid(), signal.SIGTERM)
        deadline = time.monotonic() + 10
        while not stop.requested and time.monotonic() < deadline:
            time.sleep(0.01)
    assert stop.signame == "SIGTERM"
    assert len(timeouts) >= 2 and set(timeouts) == {0}
