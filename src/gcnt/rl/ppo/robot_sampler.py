"""Which robot an environment runs next: PPO's sampling against "the rich get richer".

A robot that learns to walk gets long episodes, so with a fixed robot per environment it would
also get most of the data. :class:`RobotSampler` counters that: for the first
``uniform_iterations`` iterations every robot is equally likely; afterwards robot i is drawn with
probability proportional to ``1000 / ema_i``, where ``ema_i`` is the mean of robot i's first
``warmup_episodes`` episode lengths, then ``ema_i <- alpha * length + (1 - alpha) * ema_i`` per
episode. A robot with fewer episodes uses the mean of those it has; one with none, the mean of
the others' (no evidence either way).

The probabilities live in a small memory-mapped file (:func:`shared_probs`); the env draws
through :class:`RobotDraw` (its own random stream), which pickles as the file's path, so envs in
worker processes (a multi-process collector) read the updates made in the trainer process.
"""

from __future__ import annotations

import os
import re
import tempfile
import weakref

import numpy as np


def _unlink(path: str) -> None:
    """Remove ``path`` if it can be: one gone already, or that cannot be removed (a folder of
    that name, another user's file in a shared ``/dev/shm``), stops no run."""
    try:
        os.unlink(path)
    except OSError:
        pass


#: the probabilities file of process <pid>: ``gcnt-robot-probs-<pid>-<random>.f64``
PROBS_PREFIX = "gcnt-robot-probs-"
_PROBS_FILE = re.compile(rf"^{PROBS_PREFIX}(?P<pid>[0-9]+)-[^/]*\.f64$")


def remove_stale_probs(folder: str | None) -> None:
    """Remove the probabilities files of processes that are gone (a run killed with SIGKILL
    cannot remove its own): the pid in a file's name is its trainer's, on this host."""
    for entry in os.listdir(folder or tempfile.gettempdir()):
        m = _PROBS_FILE.match(entry)
        if m is None:
            continue
        try:
            os.kill(int(m.group("pid")), 0)
        except ProcessLookupError:
            _unlink(os.path.join(folder or tempfile.gettempdir(), entry))
        except (PermissionError, OverflowError):
            pass  # another user's live process


def shared_probs(num_robots: int) -> np.memmap:
    """Uniform probabilities in a memory-mapped file named after this process, removed when
    the array is collected (and by the next run, if this process is killed first)."""
    folder = "/dev/shm" if os.path.isdir("/dev/shm") else None
    remove_stale_probs(folder)
    prefix = f"{PROBS_PREFIX}{os.getpid()}-"
    fd, path = tempfile.mkstemp(prefix=prefix, suffix=".f64", dir=folder)
    os.close(fd)
    probs = np.memmap(path, np.float64, "w+", shape=(num_robots,))
    probs[:] = 1.0 / num_robots
    weakref.finalize(probs, _unlink, path)
    return probs


class RobotDraw:
    """Draws one robot index per reset sub-env from the shared probabilities (env side)."""

    def __init__(self, probs: np.ndarray, seed: int):
        self.probs = probs
        self.rng = np.random.default_rng(seed)

    def __call__(self, rows: np.ndarray) -> np.ndarray:
        p = np.array(self.probs, dtype=np.float64)
        return self.rng.choice(len(p), size=len(rows), p=p / p.sum())

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        if isinstance(self.probs, np.memmap):  # share the file, not a copy of its values
            state["probs"] = ("memmap", self.probs.filename, len(self.probs))
        return state

    def __setstate__(self, state: dict) -> None:
        p = state["probs"]
        if isinstance(p, tuple) and p[0] == "memmap":
            state["probs"] = np.memmap(p[1], np.float64, "r", shape=(p[2],))
        self.__dict__.update(state)


class RobotSampler:
    """Robot probabilities from episode lengths (trainer side)."""

    def __init__(
        self,
        num_robots: int,
        *,
        uniform_iterations: int = 30,
        warmup_episodes: int = 10,
        alpha: float = 0.1,
        weight: float = 1000.0,
        probs: np.ndarray | None = None,
    ):
        self.num_robots = num_robots
        self.uniform_iterations = uniform_iterations
        self.warmup_episodes = warmup_episodes
        self.alpha, self.weight = alpha, weight
        #: the current probabilities (a shared file; ``probs``: share an existing array)
        self.probs = shared_probs(num_robots) if probs is None else probs
        if self.probs.shape != (num_robots,):
            raise ValueError(
                f"probs must have shape ({num_robots},), got {tuple(self.probs.shape)}"
            )
        self.episodes = np.zeros(num_robots, np.int64)
        self.ema = np.zeros(num_robots)  # the warm-up mean until warmup_episodes episodes
        self.iteration = 0

    def drawer(self, seed: int) -> RobotDraw:
        return RobotDraw(self.probs, seed)

    def add_episodes(self, robots, lengths) -> None:
        """Record finished episodes: robot indices and their lengths (in steps)."""
        for i, n in zip(np.asarray(robots).tolist(), np.asarray(lengths).tolist(), strict=True):
            k = self.episodes[i]
            if k < self.warmup_episodes:
                self.ema[i] = (self.ema[i] * k + n) / (k + 1)
            else:
                self.ema[i] = self.alpha * n + (1 - self.alpha) * self.ema[i]
            self.episodes[i] = k + 1

    def end_iteration(self) -> None:
        """Count an iteration; past the uniform phase, set the probabilities from the EMAs."""
        self.iteration += 1
        if self.iteration >= self.uniform_iterations:
            self.probs[:] = self.target_probs()

    def target_probs(self) -> np.ndarray:
        """p_i proportional to weight / ema_i (robots without episodes get the mean EMA)."""
        seen = self.episodes > 0
        if not seen.any():
            return np.full(self.num_robots, 1.0 / self.num_robots)
        ema = np.where(seen, self.ema, self.ema[seen].mean())
        w = self.weight / np.maximum(ema, 1.0)
        return w / w.sum()

    def stats(self) -> dict[str, float]:
        """The spread of the current probabilities (logged)."""
        p = np.asarray(self.probs)
        entropy = float(-(p * np.log(np.maximum(p, 1e-12))).sum())
        return {
            "robot_p_min": float(p.min()),
            "robot_p_max": float(p.max()),
            # 1.0: uniform
            "robot_p_entropy_ratio": entropy / np.log(self.num_robots)
            if self.num_robots > 1
            else 1.0,
        }

    def state_dict(self) -> dict:
        return {
            "probs": np.array(self.probs),
            "episodes": self.episodes.copy(),
            "ema": self.ema.copy(),
            "iteration": self.iteration,
        }

    def load_state_dict(self, state: dict) -> None:
        if len(state["episodes"]) != self.num_robots:
            raise ValueError(
                f"the checkpoint's robot sampler has {len(state['episodes'])} robots, the run "
                f"{self.num_robots}"
            )
        self.probs[:] = np.asarray(state["probs"])
        self.episodes[:] = state["episodes"]
        self.ema[:] = state["ema"]
        self.iteration = int(state["iteration"])
