"""The two things a benchmark plugs into :class:`gcnt.envs.base.BatchedMujocoEnv`.

* a :class:`Featurizer`: the per-limb observation (width F), gathered from each sub-env's
  ``MjData`` in the physics threads and computed for all sub-envs at once with whole-array numpy;
  optionally extra root outputs (e.g. a height map ``hfield`` [N, D]) and a static per-limb
  context (width C) that goes into the robot table as ``limbs/context``;
* :class:`TaskRules`, one object per sub-env: its start state (pose, reset noise, per-episode
  world edits), and its reward and termination after each control step (run in the physics
  threads).

Everything else (threads, partial resets, blow-ups, seeding, specs, the output TensorDict of
:mod:`gcnt.keys`, rendering hooks) is the env's. SMPENV (:mod:`gcnt.envs.smpenv`) and UNIMAL
(:mod:`gcnt.envs.unimal`) are the two worked examples.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor

import mujoco
import numpy as np

from gcnt.morphology import Robot

#: MuJoCo functions run on a sub-env after each step and reset, before the featuriser gathers:
#: positions, orientations and body velocities (``cvel``) of the current ``qpos``/``qvel``.
DEFAULT_KINEMATICS: tuple[Callable[[mujoco.MjModel, mujoco.MjData], None], ...] = (
    mujoco.mj_kinematics,
    mujoco.mj_comPos,
    mujoco.mj_comVel,
)


class Featurizer(ABC):
    """The per-limb observation of a fixed list of sub-envs, padded to K limbs.

    Built once per env as ``featurizer(robots, models, k)`` (one robot and MjModel per sub-env).
    The env calls, for sub-env ``j``, after :attr:`kinematics` ran on its MjData (in a physics
    thread, so touch only row ``j`` of your buffers): the copy pairs of :meth:`bind` if it gave
    any, else :meth:`gather`; then, on the caller's thread, :meth:`compute` (and
    :meth:`compute_root`) for all sub-envs or a subset ``rows``.
    """

    #: per-limb observation width F
    obs_dim: int = 0
    #: width C of the static per-limb context (0: none; see :meth:`limb_context`)
    context_dim: int = 0
    #: MuJoCo functions ``f(model, data)`` the env runs on a sub-env before gathering
    kinematics: tuple[Callable[[mujoco.MjModel, mujoco.MjData], None], ...] = DEFAULT_KINEMATICS
    #: the env's helper physics threads (set by the env; None with one thread). They are idle
    #: while :meth:`compute` and :meth:`compute_root` run, so a featuriser may hand them part of
    #: a batch (numpy releases the GIL inside large array operations). A task they have not
    #: started yet (``Future.cancel()`` succeeds) is the caller's to run.
    pool: ThreadPoolExecutor | None = None

    @property
    def root_outputs(self) -> Mapping[str, int]:
        """Extra float32 outputs at the root of the TensorDict, name -> width D ([N, D] each)."""
        return {}

    def limb_context(self, robot: Robot, model: mujoco.MjModel) -> np.ndarray:
        """Static description of each limb of ``robot``, [robot.num_limbs, C] (C > 0 only)."""
        raise NotImplementedError(
            f"{type(self).__name__} declares context_dim={self.context_dim} but no limb_context"
        )

    def bind(self, j: int, data: mujoco.MjData) -> list[tuple[np.ndarray, np.ndarray]] | None:
        """Optional fast path of :meth:`gather`: ``(buffer view, MjData view)`` pairs that the env
        copies with ``dst[...] = src`` (MjData arrays never move). None: call :meth:`gather`."""
        return None

    @abstractmethod
    def gather(self, j: int, data: mujoco.MjData) -> None:
        """Copy what sub-env ``j``'s observation needs out of its MjData (kinematics current)."""

    @abstractmethod
    def compute(self, rows: np.ndarray | None = None) -> np.ndarray:
        """Observations float32 [n, K, F] of the gathered sub-envs (``rows``: a subset, in order).
        Padded limbs must come out as zeros. The env copies the result at once, so a featuriser
        may return the same buffer every call."""

    def compute_root(self, rows: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """The :attr:`root_outputs` of the gathered sub-envs, float32 [n, D] each (copied by the
        env at once, like :meth:`compute`'s result)."""
        return {}


class TaskRules(ABC):
    """Start state, reward and termination of one sub-env (one object per sub-env).

    Built as ``rules(robot, model, dt)`` with the sub-env's robot, its MjModel and the control
    period ``dt`` (frame_skip × timestep). The object may keep per-episode state (e.g. the last
    x position for a velocity reward): it serves one sub-env only.
    """

    #: True if :meth:`reset` edits the MjModel (e.g. terrain per episode): then every sub-env gets
    #: a private MjModel instead of sharing one per robot
    edits_model: bool = False

    @abstractmethod
    def reset(self, model: mujoco.MjModel, data: mujoco.MjData, rng: np.random.Generator) -> None:
        """Put ``data``, just reset to the model's defaults (``mj_resetData``), into a start
        state: pose, reset noise, per-episode world edits. Runs on the caller's thread, sub-envs
        in index order, so that draws from ``rng`` are reproducible."""

    @abstractmethod
    def begin(self, data: mujoco.MjData) -> None:
        """The state in ``data`` is where the next step's reward is measured from (called after
        :meth:`reset` and after ``set_state``)."""

    @abstractmethod
    def step(self, data: mujoco.MjData, action_sq: float) -> tuple[float, bool]:
        """After a control step: ``(reward, terminated)``. ``action_sq`` is Σa² of the clipped
        actions on the sub-env's motors. Runs in a physics thread: touch only this sub-env."""

    def sync_render(self, model: mujoco.MjModel, renderer: mujoco.Renderer | None) -> None:
        """Copy this sub-env's per-episode model edits into a renderer's private model copy (and
        upload them to its GPU context, e.g. ``mjr_uploadHField``). Default: nothing to copy."""
        return None


FeaturizerFactory = Callable[[Sequence[Robot], Sequence[mujoco.MjModel], int], Featurizer]
RulesFactory = Callable[[Robot, mujoco.MjModel, float], TaskRules]
