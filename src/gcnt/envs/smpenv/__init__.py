"""SMPEnv: the SMPENV benchmark on the batched MuJoCo env (N planar robots, any mix, padded).

SMPENV plugs into :class:`~gcnt.envs.base.BatchedMujocoEnv` with its featuriser
(:class:`~gcnt.envs.smpenv.featurize.LimbFeaturizer`, 19 numbers per limb), its task rules
(:class:`~gcnt.envs.smpenv.rules.PlanarRootRules`: planar root joints, per-family reward, healthy test
and reset noise), one action slot per limb (each limb has one hinge and one motor) and a frame
skip of 4. There are no root outputs (no height map) and no limb context.

:data:`SMPENV_BENCHMARK` is its record in the benchmark registry (``gcnt.envs.benchmark``).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from gcnt.envs.base import BatchedMujocoEnv, PhysicsBlowupWarning
from gcnt.envs.benchmark import Benchmark
from gcnt.envs.smpenv.featurize import OBS_DIM, LimbFeaturizer
from gcnt.envs.smpenv.rules import FRAME_SKIP, PlanarRootRules
from gcnt.morphology import Robot

__all__ = ["SMPENV_BENCHMARK", "PhysicsBlowupWarning", "SMPEnv"]

#: Action slots per limb in SMPENV (one hinge per limb).
ACTION_SLOTS = 1


class SMPEnv(BatchedMujocoEnv):
    """N SMPENV robots in lockstep, batch [N]; the same robot may appear several times.

    Emits the TensorDict contract (see ``gcnt.envs.base``) with ``limbs/obs`` [N,K,19] (see
    ``gcnt.envs.smpenv.featurize``) and takes ``limbs/action`` [N,K,1] in [-1, 1]. Rewards,
    terminations and reset noise follow ``gcnt.envs.smpenv.rules``.

    Args:
        robots: one :class:`~gcnt.morphology.Robot` per sub-env.
        max_limbs: K, the padded limb count (default: the largest robot). A larger robot raises
            :class:`~gcnt.envs.RobotTooLargeError`.
        max_episode_steps: control steps before an episode is truncated.
        device: where the output tensors live (the simulation runs on the CPU).
        seed: seed of the reset noise (see :meth:`set_seed`).
        num_threads: threads stepping the physics, at most N (default: automatic; see
            :class:`~gcnt.envs.base.BatchedMujocoEnv`). Results do not depend on it.
        robot_ids: each sub-env's index into a run-wide robot table, emitted as ``morph_id``
            (default: the index of its robot in :attr:`table`).
        frame_skip: physics steps per control step (SMPENV: 4).
        world: must be None (SMPENV has one world; the argument of ``Benchmark.make_env``).

    Attributes:
        robots, max_limbs (K), table (``robot_table`` of the distinct robots, batch [R]),
        local_ids ([N] into ``table``), morph_ids ([N], the emitted ``morph_id``), dt (control
        period per sub-env, [N]), thread_use; methods :meth:`sim`, :meth:`set_state`,
        :meth:`observe` (see the base class).
    """

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
        world: str | None = None,
    ):
        SMPENV_BENCHMARK.check_world(world)  # SMPENV has one world: world must be None
        super().__init__(
            robots,
            max_limbs,
            featurizer=LimbFeaturizer,
            rules=PlanarRootRules,
            action_slots=ACTION_SLOTS,
            frame_skip=frame_skip,
            max_episode_steps=max_episode_steps,
            device=device,
            seed=seed,
            num_threads=num_threads,
            robot_ids=robot_ids,
        )


SMPENV_BENCHMARK = Benchmark(
    name="smpenv",
    catalogue="smpenv",
    make_env=SMPEnv,
    preset="smpenv",
    limb_obs_dim=OBS_DIM,
    action_slots=ACTION_SLOTS,
    train_split="CWHH++:train",
    description="SMPENV: planar walkers, cheetahs, hoppers and humanoids (SMP, Huang et al. 2020)",
)
