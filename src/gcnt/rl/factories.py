"""Small ``make_*`` factories that build each part of a run from its recipe.

The env comes from the recipe's benchmark (``gcnt.envs.benchmark``); observation and action
widths are read from the env's specs, so nothing here knows a benchmark's numbers.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch
from tensordict.nn import TensorDictModuleBase
from torchrl.envs import Compose, EnvBase, RewardSum, StepCounter, TransformedEnv

from gcnt.keys import ACTION, HFIELD, OBS
from gcnt.morphology import Robot
from gcnt.nn.graph_lookup import is_table_key
from gcnt.nn.registry import make_network
from gcnt.recipes import Recipe
from gcnt.run.resolved import benchmark_of, resolve_run


def run_robots(recipe: Recipe) -> tuple[list[Robot], list[Robot]]:
    """The recipe's training and test robots as its run's record holds them
    (:func:`gcnt.run.resolved.resolve_run`: resolved and checked once per recipe)."""
    record = resolve_run(recipe)
    return list(record.train_robots), list(record.test_robots)


def train_robots(recipe: Recipe) -> list[Robot]:
    """The recipe's training robots (given, of its benchmark, apart from its test robots)."""
    return list(resolve_run(recipe).train_robots)


def make_env(
    recipe: Recipe,
    robots: Sequence[Robot],
    *,
    copies: int = 1,
    seed: int | None = None,
    max_limbs: int | None = None,
    num_threads: int | None = None,
) -> TransformedEnv:
    """The benchmark's batched env over ``copies`` of each robot, with episode returns
    (``RewardSum``) and lengths (``StepCounter``) tracked.

    Instance i·copies + c is copy c of robot i; its ``morph_id`` is i.
    """
    instances = [r for r in robots for _ in range(copies)]
    ids = [i for i in range(len(robots)) for _ in range(copies)]
    env = make_batched_env(
        recipe, instances, ids, seed=seed, max_limbs=max_limbs, num_threads=num_threads
    )
    return TransformedEnv(env, Compose(RewardSum(), StepCounter()))


def make_batched_env(
    recipe: Recipe,
    instances: Sequence[Robot],
    robot_ids: Sequence[int],
    *,
    seed: int | None = None,
    max_limbs: int | None = None,
    num_threads: int | None = None,
) -> EnvBase:
    """The benchmark's batched env (no transforms) with one sub-env per entry of ``instances``,
    sub-env i reporting ``morph_id`` ``robot_ids[i]``; the recipe's world, episode length, seed
    and threads unless given."""
    bench = benchmark_of(recipe)
    return bench.make_env(
        instances,
        max_limbs=max_limbs or recipe.env.max_limbs,
        max_episode_steps=recipe.env.max_episode_steps,
        seed=recipe.seed if seed is None else seed,
        num_threads=num_threads if num_threads is not None else recipe.env.num_threads,
        robot_ids=robot_ids,
        world=bench.check_world(recipe.env.world),
    )


def base_env(env: EnvBase) -> EnvBase:
    return env.base_env if isinstance(env, TransformedEnv) else env


def env_widths(env: EnvBase) -> dict[str, int]:
    """Per-limb observation width, action slots per limb and height-map width (0: none)."""
    obs_spec = env.observation_spec
    keys = obs_spec.keys(True, True)
    return {
        "obs_dim": int(obs_spec[OBS].shape[-1]),
        "num_actions": int(env.full_action_spec[ACTION].shape[-1]),
        "hfield_dim": int(obs_spec[HFIELD].shape[-1]) if HFIELD in keys else 0,
    }


def make_net(recipe: Recipe, env: EnvBase, role: str, **extra: Any) -> TensorDictModuleBase:
    """One network of the recipe's method for ``role`` (td3_actor, ppo_critic, ...) over the
    robots of ``env``'s robot table, sized from ``env``'s specs."""
    net = recipe.network
    widths = env_widths(env)
    if widths["hfield_dim"]:
        extra.setdefault("hfield_dim", widths["hfield_dim"])
    bench = benchmark_of(recipe)
    world = bench.check_world(recipe.env.world)
    if world in bench.decoder_hidden:
        extra.setdefault("decoder_hidden", bench.decoder_hidden[world])
    return make_network(
        net.name,
        role,
        table=base_env(env).table,
        obs_dim=widths["obs_dim"],
        num_actions=widths["num_actions"],
        preset=net.preset or benchmark_of(recipe).preset,
        **extra,
        **net.sizes(),
    ).to(recipe.device)


def network_weights(module: torch.nn.Module) -> dict:
    """A network's state dict without its robot table (static data, rebuilt for any robots)."""
    return {k: v for k, v in module.state_dict().items() if not is_table_key(k)}


def load_weights(module: torch.nn.Module, weights: dict) -> None:
    """Load network weights (the robot table is rebuilt, not loaded); a mismatch names itself."""
    # torch names every mis-shaped tensor over several lines; the first one, in one line
    own = module.state_dict()
    for key, value in weights.items():
        if key in own and tuple(own[key].shape) != tuple(value.shape):
            raise ValueError(
                f"the checkpoint does not fit the recipe's network: {key} is "
                f"{list(value.shape)} in the checkpoint, {list(own[key].shape)} in the network"
            )
    try:
        missing, unexpected = module.load_state_dict(weights, strict=False)
    except RuntimeError as e:
        raise ValueError(f"the checkpoint does not fit the recipe's network: {e}") from None
    missing = [k for k in missing if not is_table_key(k)]
    if missing or unexpected:
        raise ValueError(
            f"the checkpoint does not fit the recipe's network: missing {missing[:5]}, "
            f"unexpected {unexpected[:5]}"
        )
