"""UnimalEnv: the UNIMAL benchmark on the batched MuJoCo env (N 3-D robots, any mix, padded).

UNIMAL plugs into :class:`~gcnt.envs.base.BatchedMujocoEnv` with

* its world (``worlds.py``: FT, Incline, MT, Obstacles), compiled into each robot's model once at
  construction; MT's height field and Obstacles' boxes change every episode in place;
* its featuriser (``featurize.py``): the 52-d limb observation, the 35-number limb context
  (``limbs/context``, scaled with ModuMorph's bounds) and, on MT and Obstacles, the 1410-value
  height map ``hfield`` (``hfield.py``);
* its task rules (``rules.py``): reward = torso forward velocity, fall and side terminations per
  world, reset noise U(±0.005);
* two action slots per limb (slot 0: the hinge about the limb's x axis, slot 1: about its y axis;
  masked where a limb lacks one and on the torso; MuJoCo clamps ctrl to ±1, torque = gear × ctrl)
  and a frame skip of 4 (control period 0.02 s at the files' 0.005 s timestep).

:data:`UNIMAL_BENCHMARK` is its record in the benchmark registry (``gcnt.envs.benchmark``).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import torch

from gcnt.envs.base import BatchedMujocoEnv, PhysicsBlowupWarning
from gcnt.envs.benchmark import Benchmark
from gcnt.envs.unimal.featurize import ACTION_SLOTS, CONTEXT_DIM, OBS_DIM, UnimalFeaturizer
from gcnt.envs.unimal.hfield import HFIELD_DIM
from gcnt.envs.unimal.rules import UnimalRules, fall_threshold
from gcnt.envs.unimal.worlds import WORLDS, TerrainsByModel, world_model
from gcnt.morphology import Robot

__all__ = [
    "ACTION_SLOTS",
    "CONTEXT_DIM",
    "FRAME_SKIP",
    "HFIELD_DIM",
    "OBS_DIM",
    "UNIMAL_BENCHMARK",
    "PhysicsBlowupWarning",
    "UnimalEnv",
    "fall_threshold",
]

FRAME_SKIP = 4


class UnimalEnv(BatchedMujocoEnv):
    """N UNIMAL robots in lockstep in one ``world``, batch [N]; a robot may appear several times.

    Emits the TensorDict contract (see ``gcnt.envs.base``) with ``limbs/obs`` [N,K,52],
    ``limbs/context`` [N,K,35] and, on MT and Obstacles, ``hfield`` [N,1410]; takes
    ``limbs/action`` [N,K,2] in [-1, 1].

    Args:
        robots: one UNIMAL :class:`~gcnt.morphology.Robot` per sub-env.
        max_limbs: K, the padded limb count (default: the largest robot; UNIMAL runs use 12).
        world: "ft", "incline", "mt" or "obstacles" (None: FT).
        max_episode_steps: control steps before an episode is truncated (1000).
        device, seed, num_threads, robot_ids: see :class:`~gcnt.envs.base.BatchedMujocoEnv`.
        frame_skip: physics steps per control step (4).

    Attributes (besides the base class's): ``world``, ``hfield_seconds`` (time spent computing
    height maps so far).
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
        world = UNIMAL_BENCHMARK.check_world(world)
        bad = [r.name for r in robots if r.family != "unimal"]
        if bad:
            raise ValueError(f"UnimalEnv takes UNIMAL robots only; not UNIMAL: {bad}")
        self.world = world
        spec = WORLDS[world]
        self._terrains = TerrainsByModel()
        terrain_of = self._terrains.terrain_of if spec.height_map else None

        def featurizer(robots: Sequence[Robot], models, k: int) -> UnimalFeaturizer:
            self._terrains.keep(models)
            return UnimalFeaturizer(robots, models, k, terrain_of=terrain_of)

        super().__init__(
            robots,
            max_limbs,
            featurizer=featurizer,
            rules=self._terrains.recording(
                lambda robot, model, dt: UnimalRules(robot, model, dt, world)
            ),
            action_slots=ACTION_SLOTS,
            frame_skip=frame_skip,
            max_episode_steps=max_episode_steps,
            device=device,
            seed=seed,
            num_threads=num_threads,
            robot_ids=robot_ids,
            compile_model=functools.partial(world_model, world=world),
        )

    @property
    def hfield_seconds(self) -> float:
        return self._featurizer.hfield_seconds


UNIMAL_BENCHMARK = Benchmark(
    name="unimal",
    catalogue="unimal",
    make_env=UnimalEnv,
    preset="unimal",
    limb_obs_dim=OBS_DIM,
    action_slots=ACTION_SLOTS,
    worlds=tuple(WORLDS),
    default_world="ft",
    hfield_worlds=tuple(name for name, world in WORLDS.items() if world.height_map),
    hfield_dim=HFIELD_DIM,
    decoder_hidden={name: world.decoder_hidden for name, world in WORLDS.items()},
    train_split="Unimal:train",
    description="UNIMAL: 3-D robots from the DERL design space (MetaMorph, Gupta et al. 2022) "
    "in four worlds: flat terrain, incline, mixed terrain, obstacles",
)
