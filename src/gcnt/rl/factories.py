"""Small ``make_*`` factories that build each part of a run from its recipe."""

from __future__ import annotations

from collections.abc import Sequence

from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.envs import RewardSum, TransformedEnv

from gcnt.envs.smpenv import SMPEnv
from gcnt.morphology import Robot
from gcnt.morphology.benchmarks import resolve_robots
from gcnt.nn.registry import make_network
from gcnt.recipes import Recipe

OBS_DIM = 19  # SMPENV limb observation
NUM_ACTIONS = 1  # one hinge per SMPENV limb


def train_robots(recipe: Recipe) -> list[Robot]:
    robots = resolve_robots(recipe.env.robots)
    names = [r.name for r in robots]
    dupes = {n for n in names if names.count(n) > 1}
    if dupes:
        raise ValueError(f"env.robots lists {sorted(dupes)} more than once; use env.copies")
    return robots


def make_env(
    recipe: Recipe,
    robots: Sequence[Robot],
    *,
    copies: int = 1,
    seed: int | None = None,
    max_limbs: int | None = None,
) -> TransformedEnv:
    """The batched env over ``copies`` of each robot, with per-episode returns tracked.

    Instance i·copies + c is copy c of robot i; its ``morph_id`` is i.
    """
    instances = [r for r in robots for _ in range(copies)]
    ids = [i for i in range(len(robots)) for _ in range(copies)]
    env = SMPEnv(
        instances,
        max_limbs=max_limbs or recipe.env.max_limbs,
        max_episode_steps=recipe.env.max_episode_steps,
        seed=recipe.seed if seed is None else seed,
        num_threads=recipe.env.num_threads,
        robot_ids=ids,
    )
    return TransformedEnv(env, RewardSum())


def make_net(recipe: Recipe, table: TensorDictBase, role: str) -> TensorDictModuleBase:
    """One network of the recipe's method for ``role`` (td3_actor, td3_critic, ...)."""
    net = recipe.network
    return make_network(
        net.name,
        role,
        table=table,
        obs_dim=OBS_DIM,
        num_actions=NUM_ACTIONS,
        preset=net.preset,
        **net.kwargs,
    ).to(recipe.device)
