"""Mjcf3dEnv: the ``mjcf3d`` benchmark of general 3-D robots on the batched MuJoCo env.

Any robot file with a free-jointed root body and hinges on its limbs (up to three per limb;
bodies without joints welded into their parent's limb) runs here, in a world of UNIMAL's built
around its body tree. It plugs into :class:`~gcnt.envs.base.BatchedMujocoEnv` with

* its world (``world.py``): the robot's bodies inside UNIMAL's FT, MT or Obstacles world, at a
  0.005 s timestep, every motor's control range mapped onto [−1, 1];
* its featuriser (``featurize.py``): the 63-d limb token in the torso's heading frame, a
  44-number limb context and, on MT and Obstacles, UNIMAL's 1410-value height map ``hfield``;
* its task rules (``rules.py``): UNIMAL's start state, reward (forward velocity) and terrain, and
  a fall height relative to the robot's own start height;
* three action slots per limb (a limb's hinges in file order; masked where a limb has fewer and
  on the torso) and a frame skip of 4 (control period 0.02 s).

:data:`MJCF3D_BENCHMARK` is its record in the benchmark registry (``gcnt.envs.benchmark``); its
network sizes are UNIMAL's (``preset="unimal"``).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import torch

from gcnt.envs.base import BatchedMujocoEnv
from gcnt.envs.benchmark import Benchmark
from gcnt.envs.mjcf3d.featurize import ACTION_SLOTS, CONTEXT_DIM, OBS_DIM, Mjcf3dFeaturizer
from gcnt.envs.mjcf3d.rules import Mjcf3dRules, fall_height
from gcnt.envs.mjcf3d.world import TIMESTEP, world_model
from gcnt.envs.unimal.hfield import HFIELD_DIM
from gcnt.envs.unimal.worlds import WORLDS as UNIMAL_WORLDS
from gcnt.envs.unimal.worlds import TerrainsByModel
from gcnt.morphology import Robot

__all__ = [
    "ACTION_SLOTS",
    "CONTEXT_DIM",
    "FRAME_SKIP",
    "MJCF3D_BENCHMARK",
    "OBS_DIM",
    "TIMESTEP",
    "WORLDS",
    "Mjcf3dEnv",
    "fall_height",
]

FRAME_SKIP = 4
#: the UNIMAL worlds a general 3-D robot can walk in
WORLDS = ("ft", "mt", "obstacles")


class Mjcf3dEnv(BatchedMujocoEnv):
    """N general 3-D robots in lockstep in one ``world``, batch [N].

    Emits the TensorDict contract (see ``gcnt.envs.base``) with ``limbs/obs`` [N,K,63],
    ``limbs/context`` [N,K,44] and, on MT and Obstacles, ``hfield`` [N,1410]; takes
    ``limbs/action`` [N,K,3] in [-1, 1].

    Args:
        robots: one ``mjcf3d`` :class:`~gcnt.morphology.Robot` per sub-env.
        max_limbs: K, the padded limb count (default: the largest robot).
        world: "ft", "mt" or "obstacles" (None: FT).
        max_episode_steps, device, seed, num_threads, robot_ids: see
            :class:`~gcnt.envs.base.BatchedMujocoEnv`.
        frame_skip: physics steps per control step (4).
    """

    def __init__(
        self,
        robots: Sequence[Robot],
        max_limbs: int | None = None,
        *,
        world: str | None = None,
        max_episode_steps: int = 1000,
        device: torch.device | str = "cpu",
        seed: int | None = None,
        num_threads: int | None = None,
        robot_ids: Sequence[int] | None = None,
        frame_skip: int = FRAME_SKIP,
    ):
        world = MJCF3D_BENCHMARK.check_world(world)
        bad = [r.name for r in robots if r.family != "mjcf3d"]
        if bad:
            raise ValueError(f"Mjcf3dEnv takes general 3-D (mjcf3d) robots only; not: {bad}")
        self.world = world
        terrains = TerrainsByModel()
        terrain_of = terrains.terrain_of if UNIMAL_WORLDS[world].height_map else None

        def featurizer(robots: Sequence[Robot], models, k: int) -> Mjcf3dFeaturizer:
            terrains.keep(models)
            return Mjcf3dFeaturizer(robots, models, k, terrain_of=terrain_of)

        super().__init__(
            robots,
            max_limbs,
            featurizer=featurizer,
            rules=terrains.recording(lambda robot, model, dt: Mjcf3dRules(robot, model, dt, world)),
            action_slots=ACTION_SLOTS,
            frame_skip=frame_skip,
            max_episode_steps=max_episode_steps,
            device=device,
            seed=seed,
            num_threads=num_threads,
            robot_ids=robot_ids,
            compile_model=functools.partial(world_model, world=world),
        )


MJCF3D_BENCHMARK = Benchmark(
    name="mjcf3d",
    catalogue="mjcf3d",
    make_env=Mjcf3dEnv,
    preset="unimal",
    limb_obs_dim=OBS_DIM,
    action_slots=ACTION_SLOTS,
    worlds=WORLDS,
    default_world="ft",
    hfield_worlds=tuple(w for w in WORLDS if UNIMAL_WORLDS[w].height_map),
    hfield_dim=HFIELD_DIM,
    decoder_hidden={w: UNIMAL_WORLDS[w].decoder_hidden for w in WORLDS},
    train_split="MJCF3D:train",
    description="general 3-D robots from any MJCF file with a free root and hinged limbs "
    "(dm_control's and gymnasium's humanoid and ant, UNIMAL robots read as 3-D) on UNIMAL's "
    "flat terrain, mixed terrain and obstacles",
)
