"""One batched TorchRL env over MuJoCo for any benchmark: N robots in lockstep, padded to K limbs.

A benchmark plugs in a :class:`~gcnt.envs.plugins.Featurizer` and
:class:`~gcnt.envs.plugins.TaskRules` (:mod:`gcnt.envs.plugins`); everything else (threads,
partial resets, blow-ups, seeding, specs, the output TensorDict, rendering hooks) is
:class:`BatchedMujocoEnv`'s. Its output per step and its action are the TensorDict contract
written out once in :mod:`gcnt.keys`. Actions on slots without a motor (torso, padding, missing
joints) are ignored, even NaN. The time limit is a truncation, not a termination.

Output tensors: every output holds tensors of its own, the static entries (``morph_id``, the
limbs' mask, type, action mask and context, the graph) included, copied from the layout's each
time: consumers write into outputs in place (TorchRL's collector zeroes its carrier, the last
output, when it resets), which must not reach the next output.

Speed: every sub-env owns an ``MjData`` (copies of a robot share one ``MjModel`` unless the rules
edit the model per episode); the physics threads and their tuning are in
:mod:`gcnt.envs.stepper`. Nothing loops over limbs in Python.

Blow-ups: a sub-env whose observation turns non-finite, or on which MuJoCo raises one of its
bad-qpos/qvel/qacc warnings (MuJoCo then resets that ``MjData`` by itself), ends its episode with
``terminated``, reward 0 and a finite observation; one :class:`PhysicsBlowupWarning` per episode
names the robot and sub-env. The other sub-envs go on; the next (partial) reset restarts it.
MuJoCo's own "Nan, Inf or huge value" messages are not printed (see
:func:`quiet_mujoco_instability_messages`).

Robot pool: :meth:`BatchedMujocoEnv.use_robot_pool` turns the N sub-envs into slots that any
robot of a pool can occupy; a sampler picks each slot's robot at every reset and ``morph_id``
follows (PPO's robot sampling draws a new robot per episode this way).

An env holds threads and views into MuJoCo's memory and does not pickle: give multi-process
collectors a constructor (``functools.partial(SMPEnv, robots, ...)``), not an instance.
"""

from __future__ import annotations

import copy
import logging
import threading
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import mujoco
import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from gcnt import keys as K
from gcnt.envs.plugins import FeaturizerFactory, RulesFactory, TaskRules
from gcnt.envs.robot_table import RobotTooLargeError, robot_table
from gcnt.envs.stepper import ThreadedPhysics, cost_guess, physics_error
from gcnt.morphology import GLOBAL_LIMB_TYPES, Robot

log = logging.getLogger(__name__)

#: How MuJoCo's messages for the warnings above begin.
_BLOWUP_MESSAGE = "Nan, Inf or huge value in Q"


class PhysicsBlowupWarning(RuntimeWarning):
    """The physics of a sub-env blew up; its episode was ended (terminated)."""


# --------------------------------------------------------------------------- MuJoCo messages

_quiet_lock = threading.Lock()
_quiet_installed = False
_mujoco_log = logging.getLogger("gcnt.mujoco")


def _mujoco_warning(message: str) -> None:
    if isinstance(message, bytes):
        message = message.decode(errors="replace")
    if not message.startswith(_BLOWUP_MESSAGE):
        _mujoco_log.warning("%s", message)


def quiet_mujoco_instability_messages() -> None:
    """Route MuJoCo's warning messages (process-wide) to the ``gcnt.mujoco`` logger, without its
    "Nan, Inf or huge value in QPOS/QVEL/QACC" messages: a blow-up prints a line each time it
    recurs, while the env reports it once per episode as a :class:`PhysicsBlowupWarning`.

    Called when the first env is built; idempotent. It replaces any earlier MuJoCo warning
    callback (dm_control installs one that logs through absl).
    """
    global _quiet_installed
    with _quiet_lock:
        if not _quiet_installed:
            mujoco.set_mju_user_warning(_mujoco_warning)
            _quiet_installed = True


# --------------------------------------------------------------------------- internals


@dataclass
class _Sim:
    """One sub-env: its robot, MjData, rules and cached views of the MjData arrays."""

    index: int
    robot: Robot
    model: mujoco.MjModel
    data: mujoco.MjData
    rules: TaskRules
    ctrl_slice: slice  # this sub-env's motors in the flat control vector
    ctrl: np.ndarray
    warn: np.ndarray  # data.warning.number
    # (destination, source) views that copy what the observation needs out of the MjData;
    # None: use Featurizer.gather
    copies: list[tuple[np.ndarray, np.ndarray]] | None = None


def _robot_key(r: Robot) -> tuple[str, str]:
    return (r.name, r.xml)


def _actuator_slots(r: Robot, model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    """The limb and action slot of each of ``model``'s actuators (robot ``r``)."""
    limb_of = np.full(model.nu, -1, np.int64)
    slot_of = np.zeros(model.nu, np.int64)
    for limb, acts in enumerate(r.actuator_ids):
        for act, slot in zip(acts, r.action_slots(limb), strict=True):
            limb_of[act], slot_of[act] = limb, slot
    if (limb_of < 0).any():
        raise ValueError(
            f"robot {r.name!r}: actuators {np.nonzero(limb_of < 0)[0].tolist()} drive no limb joint"
        )
    return limb_of, slot_of


# --------------------------------------------------------------------------- the env


class BatchedMujocoEnv(ThreadedPhysics, EnvBase):
    """N robots in lockstep, batch [N]; the same robot may appear several times.

    Args:
        robots: one :class:`~gcnt.morphology.Robot` per sub-env.
        max_limbs: K, the padded limb count (default: the largest robot). A larger robot raises
            :class:`~gcnt.envs.RobotTooLargeError`.
        featurizer: builds the :class:`Featurizer` (``featurizer(robots, models, k)``).
        rules: builds one sub-env's :class:`TaskRules` (``rules(robot, model, dt)``).
        action_slots: A, action slots per limb.
        frame_skip: physics steps per control step.
        max_episode_steps: control steps before an episode is truncated.
        device: where the output tensors live (the simulation runs on the CPU).
        seed: seed of the reset noise (see :meth:`set_seed`).
        num_threads: threads stepping the physics, at most N. Default (None): the CPUs this
            process may use, or 1 whenever that steps faster (the env times both settings now
            and then; on a machine shared with other busy processes a second thread can cost
            more than it gains). Results do not depend on it.
        robot_ids: each sub-env's index into a run-wide robot table, emitted as ``morph_id``
            (default: the index of its robot in :attr:`table`).
        name: the env's name in error messages and warnings.
        compile_model: builds the MjModel of a robot (default ``Robot.compile``), e.g. the robot
            inside a benchmark's world (floor, terrain, obstacles). It must keep the robot's body,
            joint and actuator ids (add world geoms, not bodies before the robot's).

    Attributes:
        robots, max_limbs (K), action_slots (A), table (``robot_table`` of the distinct robots,
        batch [R], with ``limbs/context`` if the featuriser has one), distinct_robots, local_ids
        ([N] into ``table``), morph_ids ([N], the emitted ``morph_id``: equal to ``local_ids``
        unless ``robot_ids`` was given), dt (control period per sub-env, [N]), thread_use (how
        many steps ran on how many threads).
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
        featurizer: FeaturizerFactory,
        rules: RulesFactory,
        action_slots: int,
        frame_skip: int,
        max_episode_steps: int = 1000,
        device: torch.device | str = "cpu",
        seed: int | None = None,
        num_threads: int | None = None,
        robot_ids: Sequence[int] | None = None,
        name: str | None = None,
        compile_model: Callable[[Robot], mujoco.MjModel] | None = None,
    ):
        self.name = name or type(self).__name__
        robots = tuple(robots)
        if not robots:
            raise ValueError(f"{self.name} needs at least one robot")
        if max_episode_steps < 1:
            raise ValueError(f"max_episode_steps must be >= 1, got {max_episode_steps}")
        if action_slots < 1:
            raise ValueError(f"action_slots must be >= 1, got {action_slots}")
        if frame_skip < 1:
            raise ValueError(f"frame_skip must be >= 1, got {frame_skip}")
        n = len(robots)
        super().__init__(device=device, batch_size=torch.Size([n]))
        quiet_mujoco_instability_messages()
        self.robots = robots
        self.max_episode_steps = int(max_episode_steps)
        self.frame_skip = int(frame_skip)
        self.action_slots = a_slots = int(action_slots)
        #: builds one sub-env's TaskRules, ``rules_factory(robot, model, dt)`` (e.g. for a loop
        #: that steps the same robots outside the env)
        self.rules_factory = rules
        self._featurizer_factory = featurizer
        #: the ``sample`` given to :meth:`use_robot_pool` (None: each sub-env keeps its robot)
        self.robot_pool_sampler: Callable[[np.ndarray], np.ndarray] | None = None
        self._pool_models: list[mujoco.MjModel] = []
        self._actuator_cache: dict[tuple[str, str], tuple[np.ndarray, np.ndarray]] = {}

        # Distinct robots and their models.
        distinct: dict[tuple[str, str], int] = {}
        for r in robots:
            distinct.setdefault(_robot_key(r), len(distinct))
        self.distinct_robots = tuple(
            next(r for r in robots if _robot_key(r) == key) for key in distinct
        )
        self.local_ids = torch.tensor([distinct[_robot_key(r)] for r in robots], dtype=torch.int64)
        self.morph_ids = self._check_robot_ids(robot_ids)
        #: builds a sub-env's MjModel from its robot (default ``Robot.compile``; a benchmark may
        #: add its world to the robot's model here)
        self.compile_model = compile_model or Robot.compile
        build = self.compile_model
        shared = [build(r) for r in self.distinct_robots]
        dts = [float(m.opt.timestep) * self.frame_skip for m in shared]
        # One TaskRules per sub-env; copies of a robot share its MjModel unless the rules edit it.
        models: list[mujoco.MjModel] = []
        sub_rules: list[TaskRules] = []
        first: dict[int, TaskRules] = {}
        for r, lid in zip(robots, self.local_ids.tolist(), strict=True):
            if lid not in first:
                model = shared[lid]
            else:
                model = build(r) if first[lid].edits_model else shared[lid]
            rl = rules(r, model, dts[lid])
            first.setdefault(lid, rl)
            models.append(model)
            sub_rules.append(rl)
        #: whether the task rules edit their sub-env's model (each sub-env then has its own)
        self._edits_model = any(rl.edits_model for rl in sub_rules)
        k_table = max_limbs or max(r.num_limbs for r in robots)
        self._check_sizes(k_table)
        self._featurizer = featurizer(robots, models, k_table)
        f = self._featurizer
        context = None
        if f.context_dim > 0:
            context = [
                np.asarray(f.limb_context(r, shared[i]), np.float32)
                for i, r in enumerate(self.distinct_robots)
            ]
        self.table = robot_table(self.distinct_robots, max_limbs, a_slots, context=context)
        self.max_limbs = k = int(self.table[K.MASK].shape[1])

        # Sub-envs (their control layout and the featuriser's copies: see _layout).
        self._sims: list[_Sim] = []
        for i, r in enumerate(robots):
            data = mujoco.MjData(models[i])
            self._sims.append(
                _Sim(
                    i, r, models[i], data, sub_rules[i], slice(0, 0), data.ctrl, data.warning.number
                )
            )
        self._elapsed = np.zeros(n, np.int64)
        self._blown = np.zeros(n, bool)
        self._warned = np.zeros(n, bool)  # a blow-up was reported this episode
        self._last_terminated = np.zeros(n, bool)
        self._last_truncated = np.zeros(n, bool)
        self._kinematics = tuple(f.kinematics)
        # Written per sub-env by the physics threads: reward and termination.
        self._reward = np.zeros(n)
        self._term = np.zeros(n, bool)
        self._sq = np.zeros(n)
        self._obs = np.zeros((n, k, f.obs_dim), np.float32)
        reserved = {K.MORPH_ID, "limbs", "graph", K.REWARD, K.DONE, K.TERMINATED, K.TRUNCATED}
        clash = sorted(set(f.root_outputs) & reserved)
        if clash or any(k.startswith("_") for k in f.root_outputs):
            raise ValueError(
                f"{type(f).__name__}: root output names {sorted(f.root_outputs)} may not be one of "
                f"{sorted(reserved)} or start with '_'"
            )
        self._root_out = {
            key: np.zeros((n, int(d)), np.float32) for key, d in f.root_outputs.items()
        }
        self._limb_batch = torch.Size([n, k])

        # Static per-sub-env tensors (the graph half of the contract), filled by _layout.
        keys = [K.MASK, K.TYPE, K.ACTION_MASK]
        if context is not None:
            keys.append(K.CONTEXT)
        keys += [K.ADJ, K.DIST, K.WL]
        self._static = dict.fromkeys(keys)
        self._layout()

        self._setup_threads(num_threads)
        self._make_specs()
        self._rng = np.random.default_rng(seed)
        if seed is not None:
            self.set_seed(seed)

    # ------------------------------------------------------------------ construction helpers
    def _check_robot_ids(self, robot_ids: Sequence[int] | None) -> torch.Tensor:
        n = len(self.robots)
        if robot_ids is None:
            return self.local_ids.clone()
        ids = torch.as_tensor(list(robot_ids), dtype=torch.int64)
        if ids.shape != (n,):
            raise ValueError(f"robot_ids must give one id per robot ({n}), got {tuple(ids.shape)}")
        if (ids < 0).any():
            raise ValueError(f"robot_ids must be >= 0, got {ids.tolist()}")
        owner: dict[int, str] = {}
        for r, i in zip(self.robots, ids.tolist(), strict=True):
            if owner.setdefault(i, r.name) != r.name:
                raise ValueError(
                    f"robot_ids gives robots {owner[i]!r} and {r.name!r} the same id {i}"
                )
        return ids

    def _check_sizes(self, k: int) -> None:
        """Raise the table's RobotTooLargeError before a featuriser sees an oversized robot."""
        for r in self.robots:
            if r.num_limbs > k:
                raise RobotTooLargeError(
                    f"robot {r.name!r} ({r.source}) has {r.num_limbs} limbs; {self.name} allows "
                    f"at most {k} (raise max_limbs)"
                )

    # ------------------------------------------------------------------ specs
    def _make_specs(self) -> None:
        n, k, a = self.batch_size[0], self.max_limbs, self.action_slots
        w = int(self.table[K.WL].shape[-1])
        dev = self.device
        bool_spec = lambda *shape: Categorical(2, shape=shape, dtype=torch.bool, device=dev)  # noqa: E731
        f = self._featurizer
        limbs = {
            "obs": Unbounded(shape=(n, k, f.obs_dim), dtype=torch.float32, device=dev),
            "mask": bool_spec(n, k),
            "type": Categorical(
                len(GLOBAL_LIMB_TYPES), shape=(n, k), dtype=torch.int64, device=dev
            ),
            "action_mask": bool_spec(n, k, a),
        }
        if K.CONTEXT in self._static:
            c = f.context_dim
            limbs["context"] = Unbounded(shape=(n, k, c), dtype=torch.float32, device=dev)
        root = {
            key: Unbounded(shape=(n, v.shape[1]), dtype=torch.float32, device=dev)
            for key, v in self._root_out.items()
        }
        self.observation_spec = Composite(
            morph_id=Unbounded(shape=(n,), dtype=torch.int64, device=dev),
            limbs=Composite(limbs, shape=(n, k), device=dev),
            graph=Composite(
                adj=bool_spec(n, k, k),
                dist=Bounded(0, 255, shape=(n, k, k), dtype=torch.uint8, device=dev),
                wl=Unbounded(shape=(n, w), dtype=torch.float32, device=dev),
                shape=(n,),
                device=dev,
            ),
            **root,
            shape=(n,),
            device=dev,
        )
        self.action_spec = Composite(
            limbs=Composite(
                action=Bounded(-1.0, 1.0, shape=(n, k, a), dtype=torch.float32, device=dev),
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
        """Kinematics of the current qpos/qvel, then copy what the observation needs."""
        m, d = s.model, s.data
        for fn in self._kinematics:
            fn(m, d)
        self._featurizer.gather(s.index, d)

    def _featurize(self, rows: np.ndarray | None = None) -> None:
        """Compute the observation of all sub-envs (or ``rows``) from what was gathered."""
        f = self._featurizer
        if rows is None:
            self._obs[:] = f.compute()
        else:
            self._obs[rows] = f.compute(rows)
        if self._root_out:
            for key, v in f.compute_root(rows).items():
                if rows is None:
                    self._root_out[key][:] = v
                else:
                    self._root_out[key][rows] = v

    # ------------------------------------------------------------------ output
    def _output(
        self, reward: np.ndarray | None, terminated: np.ndarray, truncated: np.ndarray
    ) -> TensorDictBase:
        n, dev = self.batch_size[0], self.device
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
        extra = {key: torch.from_numpy(v.copy()) for key, v in self._root_out.items()}
        if dev.type != "cpu":
            obs, term, trunc, done = (
                x.to(dev, non_blocking=True) for x in (obs, term, trunc, done)
            )
            extra = {key: v.to(dev, non_blocking=True) for key, v in extra.items()}
        limbs = {"obs": obs}
        for key, v in self._static_limbs.items():
            limbs[key] = v.clone()
        out = {
            K.MORPH_ID: self._morph_id_dev.clone(),
            "limbs": new(limbs, batch_size=self._limb_batch, device=dev),
            "graph": new(
                {key: v.clone() for key, v in self._static_graph.items()},
                batch_size=self.batch_size,
                device=dev,
            ),
            **extra,
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
        rows = np.nonzero(which)[0]
        if self.robot_pool_sampler is not None and len(rows):
            self._reassign(rows, self.robot_pool_sampler(rows))
        for i in rows:
            s = self._sims[i]
            mujoco.mj_resetData(s.model, s.data)  # qpos = qpos0: every joint at its ref
            try:
                s.rules.reset(s.model, s.data, self._rng)
                s.rules.begin(s.data)
            except mujoco.FatalError as e:  # an arena too small for the robot: one line
                raise physics_error(s.robot, s.model, e) from None
        self._elapsed[which] = 0
        self._blown[which] = False
        self._warned[which] = False
        self._last_terminated[which] = False
        self._last_truncated[which] = False
        # Refresh the reset sub-envs (the others keep their state and observation).
        for i in rows:
            self._refresh(self._sims[i])
        self._featurize(rows)
        return self._output(None, self._last_terminated.copy(), self._last_truncated.copy())

    def _reset_proc_data(self, tensordict, tensordict_reset):
        """Merge a partial reset into ``tensordict`` with one ``update``.

        :meth:`_reset` returns every sub-env's current observation and flags, not only those of
        the reset ones, so its rows that were not reset equal the input's: TorchRL's default
        merge (a masked ``where`` per entry, graph and height map included) would rebuild the
        same values. Profiled (cProfile) on UNIMAL FT with random actions, a few resets per
        batched step: that merge took 0.70 ms of a 9.4 ms profiled step.
        """
        self._complete_done(self.full_done_spec, tensordict_reset)
        self._reset_check_done(tensordict, tensordict_reset)
        if tensordict is None:
            return tensordict_reset
        reset = tensordict.pop("_reset", None)  # this env's only reset key
        if reset is not None and not reset.all():
            # as TorchRL does: an entry the reset does not produce (a policy's action, say) is
            # zeroed in the reset rows, in a new tensor (the step's output may share the old one)
            keep = ~reset.reshape(-1)
            produced = set(tensordict_reset.keys(True, True))
            for key in list(tensordict.keys(True, True)):
                if key not in produced:
                    v = tensordict.get(key)
                    mask = keep.reshape(-1, *([1] * (v.dim() - 1)))
                    tensordict.set(key, torch.where(mask, v, torch.zeros((), dtype=v.dtype)))
        return tensordict.update(tensordict_reset)

    # ------------------------------------------------------------------ step
    def _actions(self, tensordict: TensorDictBase) -> np.ndarray:
        """The action as float64 [N, K, A], clipped to [-1, 1], zero on slots without a motor."""
        a = tensordict.get(K.ACTION).detach()
        if a.device.type != "cpu":
            a = a.cpu()
        a = a.numpy().reshape(self.batch_size[0], self.max_limbs, self.action_slots)
        if not np.isfinite(a).all():
            bad = ~np.isfinite(a) & ~self._no_motor
            if bad.any():
                rows = np.nonzero(bad.any((1, 2)))[0]
                names = ", ".join(f"{self.robots[i].name!r} (sub-env {i})" for i in rows)
                raise ValueError(f"{self.name}: non-finite (NaN/inf) action for robot {names}")
        out = a.astype(np.float64)
        np.minimum(out, 1.0, out=out)  # the clip as two ufuncs (np.clip's wrapper costs more)
        np.maximum(out, -1.0, out=out)
        out[self._no_motor] = 0.0  # torso, padding, missing joints (even NaN there is ignored)
        return out

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        n = self.batch_size[0]
        a = self._actions(tensordict)
        partial = tensordict.get("_step", None)
        active = None if partial is None else partial.reshape(n).cpu().numpy().astype(bool)
        ctrl = a[self._ctrl_index]
        flat = a.reshape(n, -1)
        np.einsum("nk,nk->n", flat, flat, out=self._sq)
        with np.errstate(invalid="ignore"):
            self._run_all(ctrl, active)
        reward = self._reward.copy()
        blown = self._blown.copy()
        # Any non-finite qpos or qvel shows up in the observation (positions, rotations, cvel).
        if not np.isfinite(self._obs).all():
            blown |= ~np.isfinite(self._obs).all(axis=(1, 2))
        for v in self._root_out.values():
            if not np.isfinite(v).all():
                blown |= ~np.isfinite(v).all(axis=1)
        terminated = self._term | blown
        self._elapsed += 1
        truncated = (self._elapsed >= self.max_episode_steps) & ~terminated
        if blown.any():
            self._report_blowups(blown if active is None else blown & active)
            reward[blown] = 0.0
            self._obs[blown] = np.nan_to_num(self._obs[blown], nan=0.0, posinf=0.0, neginf=0.0)
            for v in self._root_out.values():
                v[blown] = np.nan_to_num(v[blown], nan=0.0, posinf=0.0, neginf=0.0)
            self._blown[:] = False
        if active is not None:  # sub-envs not stepped keep their state and flags
            keep = ~active
            reward[keep] = 0.0
            terminated[keep] = self._last_terminated[keep]
            truncated[keep] = self._last_truncated[keep]
            self._elapsed[keep] -= 1
        # in place: an attribute set on an env goes through torch's and torchrl's __setattr__
        self._last_terminated[:] = terminated
        self._last_truncated[:] = truncated
        return self._output(reward, terminated, truncated)

    def _step_proc_data(self, next_tensordict_out: TensorDictBase) -> TensorDictBase:
        """As TorchRL's, which reshapes the reward and fills in missing done keys: :meth:`_step`
        already emits the reward and every done key in their specs' shapes and dtypes."""
        return next_tensordict_out

    def _report_blowups(self, blown: np.ndarray) -> None:
        """One PhysicsBlowupWarning per sub-env and episode."""
        for i in np.nonzero(blown & ~self._warned)[0]:
            warnings.warn(
                f"{self.name}: the physics of robot {self.robots[i].name!r} (sub-env {i}) blew up "
                f"(non-finite state or a MuJoCo bad-qpos/qvel/qacc warning); its episode is "
                f"terminated and will restart at the next reset",
                PhysicsBlowupWarning,
                stacklevel=4,
            )
        self._warned |= blown

    # ------------------------------------------------------------------ robot pool (slots)
    def use_robot_pool(
        self, pool: Sequence[Robot], sample: Callable[[np.ndarray], np.ndarray]
    ) -> None:
        """Make the N sub-envs slots that any robot of ``pool`` can occupy, one robot per episode.

        At every reset (full or partial) ``sample(rows)`` is called with the sub-envs being
        reset (int array, ascending) and returns one pool index per row: the robot that sub-env
        runs next. From now on :attr:`table` covers the whole pool (in pool order), ``morph_id``
        is the pool index and :attr:`robots` the current robot of each sub-env. Every current
        robot must be in the pool and every pool robot must fit in K (build the env with
        ``max_limbs`` = the largest pool robot). Changing a sub-env's robot builds a new MjData
        (a private model if the task rules edit it) and a new featuriser for the N sub-envs;
        sub-envs that are not reset keep their state. Used by PPO's robot sampling.
        """
        pool = tuple(pool)
        if not pool:
            raise ValueError(f"{self.name}: the robot pool is empty")
        index: dict[tuple[str, str], int] = {}
        for p, r in enumerate(pool):
            if index.setdefault(_robot_key(r), p) != p:
                raise ValueError(f"{self.name}: robot {r.name!r} appears twice in the pool")
        missing = sorted({r.name for r in self.robots if _robot_key(r) not in index})
        if missing:
            raise ValueError(f"{self.name}: sub-env robots {missing} are not in the robot pool")
        too_big = [r.name for r in pool if r.num_limbs > self.max_limbs]
        if too_big:
            raise RobotTooLargeError(
                f"{self.name}: pool robots {too_big} have more than K={self.max_limbs} limbs "
                f"(build the env with max_limbs = the largest pool robot)"
            )
        known = {_robot_key(s.robot): s.model for s in self._sims if not s.rules.edits_model}
        self._pool_models = [known.get(_robot_key(r)) or self.compile_model(r) for r in pool]
        context = None
        f = self._featurizer
        if f.context_dim > 0:
            context = [
                np.asarray(f.limb_context(r, m), np.float32)
                for r, m in zip(pool, self._pool_models, strict=True)
            ]
        self.table = robot_table(pool, self.max_limbs, self.action_slots, context=context)
        self.distinct_robots = pool
        self.local_ids = torch.tensor([index[_robot_key(r)] for r in self.robots])
        self.morph_ids = self.local_ids.clone()
        self.robot_pool_sampler = sample
        self._relayout()

    def _reassign(self, rows: np.ndarray, ids) -> None:
        """Give sub-envs ``rows`` the pool robots ``ids`` (then rebuild what depends on them)."""
        ids = np.asarray(ids, np.int64).reshape(-1)
        pool = self.distinct_robots
        if ids.shape != rows.shape or (ids < 0).any() or (ids >= len(pool)).any():
            raise ValueError(
                f"{self.name}: the robot sampler must return one pool index in [0, {len(pool)}) "
                f"per reset sub-env ({len(rows)}), got {ids.tolist()}"
            )
        changed = False
        for i, p in zip(rows.tolist(), ids.tolist(), strict=True):
            if int(self.local_ids[i]) == p:
                continue
            r, model = pool[p], self._pool_models[p]
            dt = float(model.opt.timestep) * self.frame_skip
            if self._edits_model:  # a private model, as at construction (copy.copy: a deep copy)
                model = copy.copy(model)
            rules = self.rules_factory(r, model, dt)
            data = mujoco.MjData(model)
            self._sims[i] = _Sim(
                i, r, model, data, rules, slice(0, 0), data.ctrl, data.warning.number
            )
            self.local_ids[i] = self.morph_ids[i] = p
            self._cost[i] = cost_guess(model, self.frame_skip)
            changed = True
        if changed:
            self._relayout()

    def _relayout(self) -> None:
        """Rebuild the featuriser, control layout and static outputs for the current robots."""
        sims = self._sims
        self.robots = tuple(s.robot for s in sims)
        self._featurizer = self._featurizer_factory(
            self.robots, [s.model for s in sims], self.max_limbs
        )
        self._featurizer.pool = self._pool
        self._layout()
        for s in sims:  # fill the new featuriser's buffers (kinematics are idempotent)
            self._refresh(s)

    def _layout(self) -> None:
        """What follows from the current sub-envs and featuriser: the flat control layout, the
        featuriser's copy pairs, the control periods and the static outputs."""
        sims, f = self._sims, self._featurizer
        rows, limbs, slots, offset = [], [], [], 0
        cache = self._actuator_cache  # per robot, kept over resets
        for s in sims:
            key = _robot_key(s.robot)
            if key not in cache:
                cache[key] = _actuator_slots(s.robot, s.model)
            limb_of, slot_of = cache[key]
            rows.append(np.full(s.model.nu, s.index))
            limbs.append(limb_of)
            slots.append(slot_of)
            s.ctrl_slice = slice(offset, offset + s.model.nu)
            offset += s.model.nu
            s.copies = f.bind(s.index, s.data)
        self._ctrl_index = (np.concatenate(rows), np.concatenate(limbs), np.concatenate(slots))
        self.dt = np.array([float(s.model.opt.timestep) * self.frame_skip for s in sims])
        local = self.local_ids
        # Every output gets copies of these (see the module doc: consumers write into outputs)
        self._static = {key: self.table[key][local].to(self.device) for key in self._static}
        self._static_limbs = {k: v for (g, k), v in self._static.items() if g == "limbs"}
        self._static_graph = {k: v for (g, k), v in self._static.items() if g == "graph"}
        self._morph_id_dev = self.morph_ids.to(self.device)
        self._no_motor = ~self.table[K.ACTION_MASK][local].numpy()

    # ------------------------------------------------------------------ public helpers
    def close(self, *, raise_if_closed: bool = True) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None
        super().close(raise_if_closed=raise_if_closed)

    def sim(self, i: int) -> tuple[mujoco.MjModel, mujoco.MjData]:
        """The MjModel and MjData of sub-env ``i``: its live physics (read it, render it, edit it
        between steps; copies of a robot may share the MjModel). After writing ``qpos``/``qvel``
        directly, call :meth:`set_state` so that the observation and reward follow."""
        if not 0 <= i < len(self._sims):
            raise IndexError(f"{self.name} has {len(self._sims)} sub-envs; no sub-env {i}")
        s = self._sims[i]
        return s.model, s.data

    def task_rules(self, i: int) -> TaskRules:
        """The task rules of sub-env ``i``."""
        return self._sims[i].rules

    def set_state(
        self, i: int, qpos: np.ndarray | None = None, qvel: np.ndarray | None = None
    ) -> None:
        """Put sub-env ``i`` into a given state (tests, debugging, replaying a start state).

        The next step's reward measures progress from this state; the episode clock is unchanged.
        """
        s = self._sims[i]
        if qpos is not None:
            s.data.qpos[:] = qpos
        if qvel is not None:
            s.data.qvel[:] = qvel
        s.rules.begin(s.data)
        self._refresh(s)
        self._featurize(np.array([i]))

    def observe(self) -> TensorDictBase:
        """The current observation of all sub-envs (no step, no reset; reward left out)."""
        return self._output(None, self._last_terminated.copy(), self._last_truncated.copy())

    def sync_render(self, i: int, model: mujoco.MjModel, renderer=None) -> None:
        """Bring a renderer's private copy ``model`` of sub-env ``i``'s MjModel up to date with
        per-episode edits (terrain), through the sub-env's :meth:`TaskRules.sync_render`."""
        self._sims[i].rules.sync_render(model, renderer)

    def __repr__(self) -> str:
        names = sorted({r.name for r in self.robots})
        return f"{self.name}(n={self.batch_size[0]}, K={self.max_limbs}, robots={names})"
