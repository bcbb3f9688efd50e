"""SMPEnv: one batched TorchRL env stepping N SMPENV robots (any mix, padded to K limbs).

Output per step (the TensorDict contract of ``/work/shared/spec/design.md``, batch [N])::

    morph_id            [N]        int64    index into the run's robot table
    limbs/obs           [N,K,19]   float32  see gcnt.envs.featurize
    limbs/mask          [N,K]      bool
    limbs/type          [N,K]      int64
    limbs/action_mask   [N,K,1]    bool
    graph/adj           [N,K,K]    bool
    graph/dist          [N,K,K]    uint8
    graph/wl            [N,W]      float32
    reward, done, terminated, truncated   [N,1]

and the action ``limbs/action`` [N,K,1] in [-1, 1]. Rewards, terminations and reset noise follow
``gcnt.envs.tasks``; the time limit is a truncation, not a termination.

Speed: every sub-env owns an ``MjData`` (copies of a robot share one ``MjModel``). A step runs on
``num_threads`` threads (``mj_step`` releases the GIL): each thread pulls sub-envs from a shared
queue, most expensive first (by a running average of their physics time, so the threads finish
together), steps them, refreshes their kinematics and copies the rows the observation needs through
pre-bound array views (while one thread does this Python work, the others are in the physics); then
one vectorised featurisation covers all sub-envs. Nothing loops over limbs in Python.

Blow-ups: a sub-env whose state turns non-finite, or on which MuJoCo raises one of the
bad-qpos/qvel/qacc warnings (MuJoCo then resets that ``MjData`` by itself), ends its episode with
``terminated`` and a :class:`PhysicsBlowupWarning` naming the robot; its reward is 0 and its
observation is made finite. The other sub-envs go on; the next (partial) reset restarts it.

An SMPEnv holds threads and views into MuJoCo's memory and does not pickle: give multi-process
collectors a constructor (``functools.partial(SMPEnv, robots, ...)``), not an instance.
"""

from __future__ import annotations

import logging
import os
import threading
import time
import warnings
from collections import Counter, deque
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import mujoco
import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from gcnt.envs.featurize import OBS_DIM, LimbFeaturizer
from gcnt.envs.robot_table import robot_table
from gcnt.envs.tasks import (
    FRAME_SKIP,
    RootJoints,
    TaskRules,
    reset_noise,
    root_joints,
    task_rules,
)
from gcnt.morphology import GLOBAL_LIMB_TYPES, Robot

log = logging.getLogger(__name__)

#: Action slots per limb in SMPENV (one hinge per limb).
NUM_ACTIONS = 1

_BLOWUP_WARNINGS = np.array(
    [
        int(mujoco.mjtWarning.mjWARN_BADQPOS),
        int(mujoco.mjtWarning.mjWARN_BADQVEL),
        int(mujoco.mjtWarning.mjWARN_BADQACC),
    ]
)


# num_threads=None: see SMPEnv._threads_now
_TUNE_PERIOD = 100
_TUNE_MAX_PERIOD = 1600
_TUNE_PROBE = 8


def _median(values) -> float:
    return float(np.median(np.fromiter(values, float)))


class PhysicsBlowupWarning(RuntimeWarning):
    """The physics of a sub-env blew up; its episode was ended (terminated)."""


@dataclass
class _Sim:
    """One sub-env: its robot, MjData and cached views of the MjData arrays."""

    index: int
    robot: Robot
    model: mujoco.MjModel
    data: mujoco.MjData
    rules: TaskRules
    root: RootJoints
    ctrl_slice: slice  # this sub-env's motors in the flat control vector
    nq: int
    nv: int
    qpos: np.ndarray
    qvel: np.ndarray
    ctrl: np.ndarray
    warn: np.ndarray  # data.warning.number
    inv_dt: float  # 1 / control period
    rest: np.ndarray  # qpos addresses of s[2:] (all but root x and z), for the hopper's test
    # (destination, source) views that copy what the observation needs out of the MjData;
    # None: use LimbFeaturizer.gather (limbs that are not consecutive bodies)
    copies: list[tuple[np.ndarray, np.ndarray]] | None = None


class _StepQueue:
    """The sub-envs of one step, handed out in order to the threads; the thread that finishes
    the last one (or fails) wakes the caller of :meth:`wait`."""

    __slots__ = ("_done", "_error", "_finished", "_items", "_lock", "_next", "_total")

    def __init__(self, items: list[int]):
        self._items, self._total = items, len(items)
        self._next = self._finished = 0
        self._lock = threading.Lock()
        self._done = threading.Event()
        self._error: BaseException | None = None
        if not items:
            self._done.set()

    def take(self, limit: int) -> int:
        """The next sub-env if its queue position is below ``limit``, else -1."""
        with self._lock:
            j = self._next
            if j >= limit or self._error is not None:
                return -1
            self._next = j + 1
        return self._items[j]

    def finish(self) -> None:
        with self._lock:
            self._finished += 1
            if self._finished == self._total:
                self._done.set()

    def fail(self, error: BaseException) -> None:
        with self._lock:
            self._error = error
        self._done.set()

    def wait(self) -> None:
        """Return when every sub-env is done; re-raise a helper thread's error."""
        self._done.wait()
        if self._error is not None:
            raise self._error


def _robot_key(r: Robot) -> tuple[str, str]:
    return (r.name, r.xml)


def _cost_guess(model: mujoco.MjModel, frame_skip: int) -> float:
    """A first guess of a sub-env's physics time per control step (seconds), to order the work
    queue until measured times replace it."""
    evals = 4 if model.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4 else 1
    return frame_skip * evals * model.nv * 1e-6


class SMPEnv(EnvBase):
    """N SMPENV robots in lockstep, batch [N]; the same robot may appear several times.

    Args:
        robots: one :class:`~gcnt.morphology.Robot` per sub-env.
        max_limbs: K, the padded limb count (default: the largest robot). A larger robot raises
            :class:`~gcnt.envs.RobotTooLargeError`.
        max_episode_steps: control steps before an episode is truncated.
        device: where the output tensors live (the simulation runs on the CPU).
        seed: seed of the reset noise (see :meth:`set_seed`).
        num_threads: threads stepping the physics, at most N. Default (None): the CPUs this
            process may use, or 1 whenever that steps faster (the env times both settings now
            and then; on a machine shared with other busy processes a second thread can cost
            more than it gains). Results do not depend on it.
        robot_ids: each sub-env's index into a run-wide robot table, emitted as ``morph_id``
            (default: the index of its robot in :attr:`table`).
        frame_skip: physics steps per control step (SMPENV: 4).

    Attributes:
        robots, max_limbs (K), table (``robot_table`` of the distinct robots, batch [R]),
        local_ids ([N] into ``table``), morph_ids ([N], the emitted ``morph_id``: equal to
        ``local_ids`` unless ``robot_ids`` was given), dt (control period per sub-env, [N]).
    """

    batch_locked = True
    # We skip frames ourselves. Without this flag, torchrl 0.14 sees the ``frame_skip`` attribute
    # and silently wraps the env in a TransformedEnv(FrameSkipTransform) that steps 4x again.
    _has_frame_skip = True

    def __init__(
        self,
        robots: Sequence[Robot],
        max_limbs: int | None = None,
        *,
        max_episode_steps: int = 1000,
        device: torch.device | str = "cpu",
        seed: int | None = None,
        num_threads: int | None = None,
        robot_ids: Sequence[int] | None = None,
        frame_skip: int = FRAME_SKIP,
    ):
        robots = tuple(robots)
        if not robots:
            raise ValueError("SMPEnv needs at least one robot")
        if max_episode_steps < 1:
            raise ValueError(f"max_episode_steps must be >= 1, got {max_episode_steps}")
        n = len(robots)
        super().__init__(device=device, batch_size=torch.Size([n]))
        self.robots = robots
        self.max_episode_steps = int(max_episode_steps)
        self.frame_skip = int(frame_skip)

        # Distinct robots, their table, compiled models.
        distinct: dict[tuple[str, str], int] = {}
        for r in robots:
            distinct.setdefault(_robot_key(r), len(distinct))
        self.distinct_robots = tuple(
            next(r for r in robots if _robot_key(r) == key) for key in distinct
        )
        self.local_ids = torch.tensor([distinct[_robot_key(r)] for r in robots], dtype=torch.int64)
        self.table = robot_table(self.distinct_robots, max_limbs, num_actions=NUM_ACTIONS)
        self.max_limbs = k = int(self.table["limbs", "mask"].shape[1])
        if robot_ids is None:
            self.morph_ids = self.local_ids.clone()
        else:
            ids = torch.as_tensor(list(robot_ids), dtype=torch.int64)
            if ids.shape != (n,):
                raise ValueError(
                    f"robot_ids must give one id per robot ({n}), got {tuple(ids.shape)}"
                )
            if (ids < 0).any():
                raise ValueError(f"robot_ids must be >= 0, got {ids.tolist()}")
            owner: dict[int, str] = {}
            for r, i in zip(robots, ids.tolist(), strict=True):
                if owner.setdefault(i, r.name) != r.name:
                    raise ValueError(
                        f"robot_ids gives robots {owner[i]!r} and {r.name!r} the same id {i}"
                    )
            self.morph_ids = ids
        models = [r.compile() for r in self.distinct_robots]
        rules = [task_rules(r) for r in self.distinct_robots]

        # Sub-envs.
        self._sims: list[_Sim] = []
        ctrl_rows, ctrl_cols, offset = [], [], 0
        for i, r in enumerate(robots):
            lid = int(self.local_ids[i])
            model = models[lid]
            data = mujoco.MjData(model)
            src = np.full(model.nu, -1, np.int64)
            for limb, acts in enumerate(r.actuator_ids):
                for a in acts:
                    src[a] = limb
            if (src < 0).any():
                raise ValueError(
                    f"robot {r.name!r}: actuators {np.nonzero(src < 0)[0].tolist()} drive no limb joint"
                )
            root = root_joints(r, model)
            ctrl_rows.append(np.full(model.nu, i))
            ctrl_cols.append(src)
            self._sims.append(
                _Sim(
                    index=i,
                    robot=r,
                    model=model,
                    data=data,
                    rules=rules[lid],
                    root=root,
                    ctrl_slice=slice(offset, offset + model.nu),
                    nq=model.nq,
                    nv=model.nv,
                    qpos=data.qpos,
                    qvel=data.qvel,
                    ctrl=data.ctrl,
                    warn=data.warning.number,
                    inv_dt=1.0 / (model.opt.timestep * self.frame_skip),
                    rest=np.setdiff1d(np.arange(model.nq), [root.x, root.z]),
                )
            )
            offset += model.nu
        self._ctrl_rows = np.concatenate(ctrl_rows)
        self._ctrl_cols = np.concatenate(ctrl_cols)
        self.dt = np.array([1.0 / s.inv_dt for s in self._sims])
        self._x_prev = np.zeros(n)
        self._elapsed = np.zeros(n, np.int64)
        self._blown = np.zeros(n, bool)
        self._last_terminated = np.zeros(n, bool)
        self._last_truncated = np.zeros(n, bool)
        self._featurizer = LimbFeaturizer(robots, [s.model for s in self._sims], k)
        for s in self._sims:
            s.copies = self._featurizer.bind(s.index, s.data)
        # Written per sub-env by the physics threads: reward, healthy test, squared actions.
        self._reward = np.zeros(n)
        self._healthy = np.ones(n, bool)
        self._sq = np.zeros(n)
        self._obs = np.zeros((n, k, OBS_DIM), np.float32)
        self._limb_batch = torch.Size([n, k])

        # Static per-sub-env tensors (the graph half of the contract).
        local = self.local_ids
        self._static = {
            ("limbs", "mask"): self.table["limbs", "mask"][local],
            ("limbs", "type"): self.table["limbs", "type"][local],
            ("limbs", "action_mask"): self.table["limbs", "action_mask"][local],
            ("graph", "adj"): self.table["graph", "adj"][local],
            ("graph", "dist"): self.table["graph", "dist"][local],
            ("graph", "wl"): self.table["graph", "wl"][local],
        }
        self._static = {key: v.to(self.device) for key, v in self._static.items()}
        self._morph_id_dev = self.morph_ids.to(self.device)
        self._amask_np = self.table["limbs", "action_mask"][local][..., 0].numpy()
        self._no_motor = ~self._amask_np

        # Threads: all of them pull sub-envs from one queue, the slowest first.
        self._auto = num_threads is None
        if num_threads is None:
            try:
                num_threads = len(os.sched_getaffinity(0))
            except AttributeError:  # not on Linux
                num_threads = os.cpu_count() or 1
        self.num_threads = max(1, min(int(num_threads), n))
        self._auto = self._auto and self.num_threads > 1
        self._use, self._tick = self.num_threads, 0
        self._period = _TUNE_PERIOD
        self._probe_at = _TUNE_PERIOD
        self._times = {k: deque(maxlen=_TUNE_PROBE) for k in {1, self.num_threads}}
        #: how many steps ran with how many physics threads
        self.thread_use: Counter[int] = Counter()
        # Python lists: the hot loop reads and writes single items, which numpy makes slow.
        self._cost = [_cost_guess(s.model, self.frame_skip) for s in self._sims]
        self._order = sorted(range(n), key=lambda i: -self._cost[i])
        self._reserve = max(1, n // 12)  # sub-envs the helpers leave to the calling thread
        self._pool = (
            ThreadPoolExecutor(self.num_threads - 1, thread_name_prefix="smpenv")
            if self.num_threads > 1
            else None
        )

        self._make_specs()
        self._rng = np.random.default_rng(seed)
        if seed is not None:
            self.set_seed(seed)

    # ------------------------------------------------------------------ specs
    def _make_specs(self) -> None:
        n, k = self.batch_size[0], self.max_limbs
        w = int(self.table["graph", "wl"].shape[-1])
        dev = self.device
        bool_spec = lambda *shape: Categorical(2, shape=shape, dtype=torch.bool, device=dev)  # noqa: E731
        self.observation_spec = Composite(
            morph_id=Unbounded(shape=(n,), dtype=torch.int64, device=dev),
            limbs=Composite(
                obs=Unbounded(shape=(n, k, OBS_DIM), dtype=torch.float32, device=dev),
                mask=bool_spec(n, k),
                type=Categorical(
                    len(GLOBAL_LIMB_TYPES), shape=(n, k), dtype=torch.int64, device=dev
                ),
                action_mask=bool_spec(n, k, NUM_ACTIONS),
                shape=(n, k),
                device=dev,
            ),
            graph=Composite(
                adj=bool_spec(n, k, k),
                dist=Bounded(0, 255, shape=(n, k, k), dtype=torch.uint8, device=dev),
                wl=Unbounded(shape=(n, w), dtype=torch.float32, device=dev),
                shape=(n,),
                device=dev,
            ),
            shape=(n,),
            device=dev,
        )
        self.action_spec = Composite(
            limbs=Composite(
                action=Bounded(
                    -1.0, 1.0, shape=(n, k, NUM_ACTIONS), dtype=torch.float32, device=dev
                ),
                shape=(n, k),
                device=dev,
            ),
            shape=(n,),
            device=dev,
        )
        self.reward_spec = Unbounded(shape=(n, 1), dtype=torch.float32, device=dev)
        self.full_done_spec = Composite(
            done=bool_spec(n, 1),
            terminated=bool_spec(n, 1),
            truncated=bool_spec(n, 1),
            shape=(n,),
            device=dev,
        )

    # ------------------------------------------------------------------ seeding
    def _set_seed(self, seed: int | None) -> None:
        self._rng = np.random.default_rng(seed)

    # ------------------------------------------------------------------ physics helpers
    def _refresh(self, s: _Sim) -> None:
        """Kinematics of the current qpos/qvel, then copy what the observation needs.

        (Inlined in :meth:`_work`, the hot loop.)
        """
        m, d = s.model, s.data
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_comVel(m, d)
        self._featurizer.gather(s.index, d)

    def _work(self, queue: _StepQueue, ctrl: np.ndarray, limit: int) -> None:
        """One thread's share of a step: take sub-envs from ``queue`` (up to position ``limit``),
        step them, copy out what the observation needs, and apply the task rules (reward and
        healthy test, scalar arithmetic that overlaps with the other threads' physics)."""
        try:
            fs, clock, cost, blown = self.frame_skip, time.perf_counter, self._cost, self._blown
            sims, gather = self._sims, self._featurizer.gather
            reward, healthy, x_prev, sq = self._reward, self._healthy, self._x_prev, self._sq
            qpos_w, qvel_w, qacc_w = (int(w) for w in _BLOWUP_WARNINGS)
            step, kinematics = mujoco.mj_step, mujoco.mj_kinematics
            com_pos, com_vel = mujoco.mj_comPos, mujoco.mj_comVel
            take, finish = queue.take, queue.finish
            while (i := take(limit)) >= 0:
                s = sims[i]
                m, d = s.model, s.data
                s.ctrl[:] = ctrl[s.ctrl_slice]
                t = clock()
                step(m, d, fs)
                cost[i] += 0.2 * (clock() - t - cost[i])
                w = s.warn
                if w[qpos_w] or w[qvel_w] or w[qacc_w]:
                    blown[i] = True
                    w[_BLOWUP_WARNINGS] = 0
                kinematics(m, d)
                com_pos(m, d)
                com_vel(m, d)
                if s.copies is not None:
                    for dst, src in s.copies:
                        dst[...] = src
                else:
                    gather(i, d)
                q, rules, root = s.qpos, s.rules, s.root
                x = float(q[root.x])
                if rules.state_check:
                    ok = rules.healthy(q[root.z], q[root.pitch], q[s.rest], s.qvel)
                else:
                    ok = rules.healthy(q[root.z], q[root.pitch])
                healthy[i] = ok
                reward[i] = (
                    (x - x_prev[i]) * s.inv_dt + rules.healthy_reward - rules.ctrl_cost * sq[i]
                )
                x_prev[i] = x
                finish()
        except BaseException as e:
            queue.fail(e)
            raise

    def _threads_now(self) -> int:
        """How many threads step the physics this time (see ``num_threads`` in the class doc).

        With ``num_threads=None``: now and then, step ``_TUNE_PROBE`` times with the other setting
        (1 thread or all), and switch if its median physics time was 5% lower. The pause between
        probes doubles (up to ``_TUNE_MAX_PERIOD`` steps) while the choice holds.
        """
        if not self._auto:
            return self.num_threads
        self._tick += 1
        other = 1 if self._use == self.num_threads else self.num_threads
        left = self._probe_at - self._tick
        if 0 <= left < _TUNE_PROBE:
            return other  # probing
        if left < 0:  # a probe just ended
            mine, theirs = self._times[self._use], self._times[other]
            if theirs and mine and _median(theirs) < 0.95 * _median(mine):
                self._use, self._period = other, _TUNE_PERIOD
            else:
                self._period = min(2 * self._period, _TUNE_MAX_PERIOD)
            self._probe_at = self._tick + self._period
        return self._use

    def _run_all(self, ctrl: np.ndarray, active: np.ndarray | None) -> None:
        """Step and featurise every (active) sub-env on all threads."""
        items = self._order if active is None else [i for i in self._order if active[i]]
        queue = _StepQueue(items)
        threads = self._threads_now()
        t0 = time.perf_counter()
        if threads > 1 and len(items) > 1:
            # Helpers leave the cheapest few sub-envs (queued last) to this thread, so that it
            # is usually the one to finish and need not wait to be woken up; and it never waits
            # for a helper that has not started (under CPU contention it just does all the work).
            limit = len(items) - self._reserve
            for _ in range(threads - 1):
                self._pool.submit(self._work, queue, ctrl, limit)
        self._work(queue, ctrl, len(items))
        queue.wait()
        if self._auto:
            self._times[threads].append(time.perf_counter() - t0)
        self.thread_use[threads] += 1
        # One vectorised featurisation of all sub-envs (its cost is per numpy call, not per row).
        self._obs[:] = self._featurizer.compute()
        cost = self._cost
        self._order = sorted(range(len(cost)), key=cost.__getitem__, reverse=True)

    # ------------------------------------------------------------------ output
    def _output(
        self, reward: np.ndarray | None, terminated: np.ndarray, truncated: np.ndarray
    ) -> TensorDictBase:
        n, dev, st = self.batch_size[0], self.device, self._static
        # ``_new_unsafe`` skips the per-value checks of the public constructor (a third of the
        # cost of building the output): the keys, shapes and devices below are fixed and match the
        # specs, which check_env_specs verifies in the tests.
        new = TensorDict._new_unsafe
        flags = np.empty((3, n, 1), bool)  # terminated, truncated, done
        flags[0, :, 0] = terminated
        flags[1, :, 0] = truncated
        np.logical_or(flags[0], flags[1], out=flags[2])
        obs = torch.from_numpy(self._obs.copy())
        term, trunc, done = torch.from_numpy(flags).unbind(0)
        if dev.type != "cpu":
            obs, term, trunc, done = (
                x.to(dev, non_blocking=True) for x in (obs, term, trunc, done)
            )
        limbs = new(
            {
                "obs": obs,
                "mask": st["limbs", "mask"].clone(),
                "type": st["limbs", "type"].clone(),
                "action_mask": st["limbs", "action_mask"].clone(),
            },
            batch_size=self._limb_batch,
            device=dev,
        )
        graph = new(
            {
                "adj": st["graph", "adj"].clone(),
                "dist": st["graph", "dist"].clone(),
                "wl": st["graph", "wl"].clone(),
            },
            batch_size=self.batch_size,
            device=dev,
        )
        out = {
            "morph_id": self._morph_id_dev.clone(),
            "limbs": limbs,
            "graph": graph,
            "terminated": term,
            "truncated": trunc,
            "done": done,
        }
        if reward is not None:
            r = torch.from_numpy(reward.astype(np.float32).reshape(n, 1))
            out["reward"] = r if dev.type == "cpu" else r.to(dev, non_blocking=True)
        return new(out, batch_size=self.batch_size, device=dev)

    # ------------------------------------------------------------------ reset
    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        n = self.batch_size[0]
        mask = None
        if tensordict is not None:
            mask = tensordict.get("_reset", None)
        if mask is None:
            which = np.ones(n, bool)
        else:
            which = mask.reshape(n).cpu().numpy().astype(bool)
        for i in np.nonzero(which)[0]:
            s = self._sims[i]
            m, d = s.model, s.data
            mujoco.mj_resetData(m, d)  # qpos = qpos0: every joint at its ref
            dq, dv = reset_noise(s.rules, self._rng, m.nq, m.nv)
            d.qpos[:] += dq
            d.qvel[:] += dv
            self._x_prev[i] = d.qpos[s.root.x]
        self._elapsed[which] = 0
        self._blown[which] = False
        self._last_terminated[which] = False
        self._last_truncated[which] = False
        # Refresh the reset sub-envs (the others keep their state and observation).
        rows = np.nonzero(which)[0]
        for i in rows:
            self._refresh(self._sims[i])
        self._obs[rows] = self._featurizer.compute(rows)
        return self._output(None, self._last_terminated.copy(), self._last_truncated.copy())

    # ------------------------------------------------------------------ step
    def _actions(self, tensordict: TensorDictBase) -> np.ndarray:
        """The action as float64 [N, K], clipped to [-1, 1] and zeroed on torso and padding."""
        a = tensordict.get(("limbs", "action")).detach()
        if a.device.type != "cpu":
            a = a.cpu()
        a = a.numpy().reshape(self.batch_size[0], self.max_limbs)
        if not np.isfinite(a).all():
            bad = ~np.isfinite(a) & self._amask_np
            if bad.any():
                rows = np.nonzero(bad.any(1))[0]
                names = ", ".join(f"{self.robots[i].name!r} (sub-env {i})" for i in rows)
                raise ValueError(f"SMPEnv: non-finite (NaN/inf) action for robot {names}")
        out = np.clip(a, -1.0, 1.0, dtype=np.float64)
        out[self._no_motor] = 0.0  # torso and padding (even NaN there is ignored)
        return out

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        n = self.batch_size[0]
        a = self._actions(tensordict)
        partial = tensordict.get("_step", None)
        active = None if partial is None else partial.reshape(n).cpu().numpy().astype(bool)
        ctrl = a[self._ctrl_rows, self._ctrl_cols]
        np.einsum("nk,nk->n", a, a, out=self._sq)
        with np.errstate(invalid="ignore"):
            self._run_all(ctrl, active)
        reward = self._reward.copy()
        blown = self._blown.copy()
        # Any non-finite qpos or qvel shows up in the observation (positions, rotations, cvel).
        if not np.isfinite(self._obs).all():
            blown |= ~np.isfinite(self._obs).all(axis=(1, 2))
        ok = self._healthy
        terminated = ~ok | blown
        self._elapsed += 1
        truncated = (self._elapsed >= self.max_episode_steps) & ~terminated
        if blown.any():
            for i in np.nonzero(blown & (active if active is not None else True))[0]:
                warnings.warn(
                    f"SMPEnv: the physics of robot {self.robots[i].name!r} (sub-env {i}) blew up "
                    f"(non-finite state or a MuJoCo bad-qpos/qvel/qacc warning); its episode is "
                    f"terminated and will restart at the next reset",
                    PhysicsBlowupWarning,
                    stacklevel=3,
                )
            reward[blown] = 0.0
            self._obs[blown] = np.nan_to_num(self._obs[blown], nan=0.0, posinf=0.0, neginf=0.0)
            self._blown[:] = False
        if active is not None:  # sub-envs not stepped keep their state and flags
            keep = ~active
            reward[keep] = 0.0
            terminated[keep] = self._last_terminated[keep]
            truncated[keep] = self._last_truncated[keep]
            self._elapsed[keep] -= 1
        self._last_terminated = terminated
        self._last_truncated = truncated
        return self._output(reward, terminated, truncated)

    # ------------------------------------------------------------------ misc
    def close(self, *, raise_if_closed: bool = True) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None
        super().close(raise_if_closed=raise_if_closed)

    def set_state(
        self, i: int, qpos: np.ndarray | None = None, qvel: np.ndarray | None = None
    ) -> None:
        """Put sub-env ``i`` into a given state (tests, debugging, replaying a start state).

        The next step's reward measures progress from this state; the episode clock is unchanged.
        """
        s = self._sims[i]
        if qpos is not None:
            s.qpos[:] = qpos
        if qvel is not None:
            s.qvel[:] = qvel
        self._x_prev[i] = s.qpos[s.root.x]
        self._refresh(s)
        self._obs[[i]] = self._featurizer.compute(np.array([i]))

    def observe(self) -> TensorDictBase:
        """The current observation of all sub-envs (no step, no reset; reward left out)."""
        return self._output(None, self._last_terminated.copy(), self._last_truncated.copy())

    def sim(self, i: int) -> tuple[mujoco.MjModel, mujoco.MjData]:
        """The MjModel and MjData of sub-env ``i`` (for tests, rendering and debugging)."""
        s = self._sims[i]
        return s.model, s.data

    def __repr__(self) -> str:
        names = sorted({r.name for r in self.robots})
        return f"SMPEnv(n={self.batch_size[0]}, K={self.max_limbs}, robots={names})"
