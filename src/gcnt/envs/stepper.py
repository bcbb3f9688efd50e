"""The physics thread stepper of :class:`gcnt.envs.base.BatchedMujocoEnv` and its tuning.

A step runs on ``num_threads`` threads (``mj_step`` releases the GIL): the sub-envs are queued
most expensive first (by a running average of their physics time, :class:`StepQueue`), the
helper threads take them from the front and the calling thread from the back (so that the
threads finish together); each thread steps its sub-envs, refreshes the kinematics the
featuriser needs, copies the rows the observation needs, and applies the task rules (while one
thread does this Python work, the others are in the physics); then one vectorised featurisation
covers all sub-envs. With ``num_threads=None`` the env probes now and then whether one thread
or all of them step faster (:meth:`ThreadedPhysics._threads_now`).
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections import Counter, deque
from concurrent.futures import ThreadPoolExecutor

import mujoco
import numpy as np

import gcnt

log = logging.getLogger(__name__)

#: MuJoCo's bad qpos/qvel/qacc warnings: a sub-env that raises one has blown up
BLOWUP_WARNINGS = np.array(
    [
        int(mujoco.mjtWarning.mjWARN_BADQPOS),
        int(mujoco.mjtWarning.mjWARN_BADQVEL),
        int(mujoco.mjtWarning.mjWARN_BADQACC),
    ]
)

# num_threads=None: see BatchedMujocoEnv._threads_now
TUNE_PERIOD = 100
TUNE_MAX_PERIOD = 1600
TUNE_PROBE = 8


def usable_cpus() -> int:
    """The CPUs this process may run on (its affinity set; all of them where there is none)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def median(values) -> float:
    return float(np.median(np.fromiter(values, float)))


def cost_guess(model: mujoco.MjModel, frame_skip: int) -> float:
    """A first guess of a sub-env's physics time per control step (seconds), to order the work
    queue until measured times replace it."""
    evals = 4 if model.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4 else 1
    return frame_skip * evals * model.nv * 1e-6


class StepQueue:
    """The sub-envs of one step, most expensive first, shared by the threads without a lock:
    helper threads take from the front (:meth:`take_first`), the calling thread from the back
    (:meth:`take_last`; a deque's pops are atomic), so that the threads meet where their shares
    of the work are about equal. The caller's :meth:`close` then waits only for helpers that
    are inside (one that starts later finds nothing left and leaves); a lock is taken twice per
    helper and step, not per sub-env (a lock taken per sub-env by two threads made a step of 25
    sub-envs half again as long as its physics on two threads)."""

    __slots__ = ("_closed", "_done", "_error", "_inside", "_items", "_lock")

    def __init__(self, items: list[int]):
        self._items = deque(items)
        self._lock = threading.Lock()
        self._done = threading.Event()
        self._inside = 0
        self._closed = False
        self._error: BaseException | None = None

    def take_first(self) -> int:
        """The most expensive sub-env left (a helper's next), or -1."""
        try:
            return self._items.popleft()
        except IndexError:
            return -1

    def take_last(self) -> int:
        """The cheapest sub-env left (the calling thread's next), or -1."""
        try:
            return self._items.pop()
        except IndexError:
            return -1

    def enter(self) -> bool:
        """A helper starts on this step: False once the caller has closed it (nothing left)."""
        with self._lock:
            if self._closed:
                return False
            self._inside += 1
            return True

    def leave(self) -> None:
        """A helper that entered is done (wakes the caller of :meth:`close` if it waits)."""
        with self._lock:
            self._inside -= 1
            if self._closed and not self._inside:
                self._done.set()

    def fail(self, error: BaseException) -> None:
        """Stop handing out sub-envs; the caller of :meth:`close` raises ``error``."""
        self._error = error
        self._items.clear()

    def close(self) -> None:
        """Return when every helper that entered is done; re-raise a helper thread's error."""
        with self._lock:
            self._closed = True
            wait = self._inside > 0
        if wait:
            self._done.wait()
        if self._error is not None:
            raise self._error


def physics_error(robot, model: mujoco.MjModel, error: BaseException) -> BaseException:
    """``error`` from MuJoCo while stepping or resetting ``robot``, as the error to report: a
    ``mujoco.FatalError`` for an arena too small for the robot (``mj_stackAlloc``) becomes a
    one-line RobotTooLargeError naming the robot and the fix (a larger ``<size memory=.../>``
    in its file: MuJoCo sizes the arena from the model, and only the robot's file can say that a
    robot needs more); anything else is returned as it is."""
    from gcnt.envs.robot_table import RobotTooLargeError

    text = str(error)
    if not isinstance(error, mujoco.FatalError) or "mj_stackAlloc" not in text:
        return error
    return RobotTooLargeError(
        f"robot {robot.name!r} ({robot.source}): MuJoCo's arena of {_size(model.narena)} bytes "
        f"is too small for its {model.nbody} bodies ({text.splitlines()[0]}); give the robot "
        f'file a larger <size memory="{_size(2 * model.narena)}"/> (or simplify the robot)'
    )


def _size(n: int) -> str:
    """``n`` bytes as MuJoCo's ``memory`` attribute writes sizes (``512K``, ``866M``), rounded
    up."""
    for unit, scale in (("G", 1 << 30), ("M", 1 << 20), ("K", 1 << 10)):
        if n >= scale:
            return f"{-(-int(n) // scale)}{unit}"
    return str(int(n))


_openmp_warned = False


def warn_if_openmp_spins() -> None:
    """Log once per process when torch's OpenMP workers spin (see ``gcnt.OPENMP_SPINS``): they
    take the cores the physics threads need, which can make a step several times slower."""
    global _openmp_warned
    if _openmp_warned or not gcnt.OPENMP_SPINS:
        return
    _openmp_warned = True
    log.warning(
        "torch was imported before gcnt: torch's OpenMP threads spin long after each op on the "
        "cores the physics threads use (env steps can be several times slower); import gcnt "
        "first, or set GOMP_SPINCOUNT=10000 before starting Python"
    )


class ThreadedPhysics:
    """The stepping half of :class:`~gcnt.envs.base.BatchedMujocoEnv` (a base class of it).

    Reads the env's ``_sims``, ``frame_skip``, ``name``, ``_featurizer``, ``_kinematics`` and
    writes its per-sub-env ``_reward``, ``_term``, ``_blown`` (``_sq`` holds the actions' Σa²);
    :meth:`_run_all` steps every (active) sub-env and calls the env's ``_featurize``.
    """

    def _setup_threads(self, num_threads: int | None) -> None:
        """Threads: all of them pull sub-envs from one queue, the slowest first."""
        n = len(self._sims)
        self._auto = num_threads is None
        if num_threads is None:
            num_threads = usable_cpus()
        self.num_threads = max(1, min(int(num_threads), n))
        self._auto = self._auto and self.num_threads > 1
        if self.num_threads > 1:
            warn_if_openmp_spins()
        self._use, self._tick = self.num_threads, 0
        self._period = TUNE_PERIOD
        self._probe_at = TUNE_PERIOD
        self._times = {c: deque(maxlen=TUNE_PROBE) for c in {1, self.num_threads}}
        #: how many steps ran with how many physics threads
        self.thread_use: Counter[int] = Counter()
        # Python lists: the hot loop reads and writes single items, which numpy makes slow.
        self._cost = [cost_guess(s.model, self.frame_skip) for s in self._sims]
        self._order = sorted(range(n), key=lambda i: -self._cost[i])
        self._pool = (
            ThreadPoolExecutor(self.num_threads - 1, thread_name_prefix=self.name.lower())
            if self.num_threads > 1
            else None
        )
        self._featurizer.pool = self._pool

    def _help(self, queue: StepQueue, ctrl: np.ndarray) -> None:
        """A helper thread's share of a step: the most expensive sub-envs left (:meth:`_work`),
        unless the calling thread has already done them all."""
        if not queue.enter():
            return
        try:
            self._work(queue, ctrl, queue.take_first)
        finally:
            queue.leave()

    def _work(self, queue: StepQueue, ctrl: np.ndarray, take) -> None:
        """One thread's share of a step: take sub-envs with ``take`` until none is left, step
        them, copy out what the observation needs, and apply the task rules (Python work that
        overlaps with the other threads' physics)."""
        try:
            fs, clock, cost, blown = self.frame_skip, time.perf_counter, self._cost, self._blown
            sims, gather, kin = self._sims, self._featurizer.gather, self._kinematics
            reward, term, sq = self._reward, self._term, self._sq
            qpos_w, qvel_w, qacc_w = (int(w) for w in BLOWUP_WARNINGS)
            step = mujoco.mj_step
            while (i := take()) >= 0:
                s = sims[i]
                m, d = s.model, s.data
                s.ctrl[:] = ctrl[s.ctrl_slice]
                t = clock()
                step(m, d, fs)
                cost[i] += 0.2 * (clock() - t - cost[i])
                w = s.warn
                if w[qpos_w] or w[qvel_w] or w[qacc_w]:
                    blown[i] = True
                    w[BLOWUP_WARNINGS] = 0
                for fn in kin:
                    fn(m, d)
                if s.copies is not None:
                    for dst, src in s.copies:
                        dst[...] = src
                else:
                    gather(i, d)
                reward[i], term[i] = s.rules.step(d, sq[i])
        except BaseException as e:
            if isinstance(e, mujoco.FatalError):
                e = physics_error(s.robot, s.model, e)
            queue.fail(e)
            raise e from None

    def _threads_now(self) -> int:
        """How many threads step the physics this time (see ``num_threads`` in the class doc).

        With ``num_threads=None``: now and then, step ``TUNE_PROBE`` times with the other setting
        (1 thread or all), and switch if its median physics time was 5% lower. The pause between
        probes doubles (up to ``TUNE_MAX_PERIOD`` steps) while the choice holds.
        """
        if not self._auto:
            return self.num_threads
        self._tick += 1
        other = 1 if self._use == self.num_threads else self.num_threads
        left = self._probe_at - self._tick
        if 0 <= left < TUNE_PROBE:
            return other  # probing
        if left < 0:  # a probe just ended
            mine, theirs = self._times[self._use], self._times[other]
            if theirs and mine and median(theirs) < 0.95 * median(mine):
                self._use, self._period = other, TUNE_PERIOD
            else:
                self._period = min(2 * self._period, TUNE_MAX_PERIOD)
            self._probe_at = self._tick + self._period
        return self._use

    def _run_all(self, ctrl: np.ndarray, active: np.ndarray | None) -> None:
        """Step and featurise every (active) sub-env on all threads."""
        items = self._order if active is None else [i for i in self._order if active[i]]
        queue = StepQueue(items)
        threads = self._threads_now()
        t0 = time.perf_counter()
        if threads > 1 and len(items) > 1:
            for _ in range(threads - 1):
                self._pool.submit(self._help, queue, ctrl)
        try:
            self._work(queue, ctrl, queue.take_last)
        finally:
            queue.close()
        if self._auto:
            self._times[threads].append(time.perf_counter() - t0)
        self.thread_use[threads] += 1
        # One vectorised featurisation of all sub-envs (its cost is per numpy call, not per row).
        self._featurize()
        cost = self._cost
        # in place (no env __setattr__); the step's queue is done with the list
        self._order[:] = sorted(range(len(cost)), key=cost.__getitem__, reverse=True)
