"""Deterministic evaluation: mean ± standard error of the episode return per robot.

The paper's table 1 protocol is 100 episodes per robot and seed. Episodes run in parallel copies of
each robot; every copy runs a fixed share of the episodes, so early-ending (failed) episodes are
not over-represented.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type

from gcnt.morphology.benchmarks import resolve_robots
from gcnt.recipes import Recipe
from gcnt.rl.factories import make_env, make_net


@torch.no_grad()
def evaluate(
    recipe: Recipe,
    actor_state: dict,
    robot_specs: Sequence[str],
    *,
    episodes: int = 100,
    parallel: int = 10,
    seed: int = 10_000,
) -> dict[str, dict]:
    """Run the deterministic actor on each robot for ``episodes`` episodes.

    ``actor_state`` is a state dict of the recipe's actor; the actor is rebuilt for the evaluated
    robots (any robots, including never-seen robot files), so its graph table matches them.
    """
    robots = list({r.name: r for r in resolve_robots(robot_specs)}.values())  # unique, in order
    # pad at least as much as in training: size-dependent networks (the per-robot MLP) need it
    train_k = recipe.env.max_limbs or max(r.num_limbs for r in resolve_robots(recipe.env.robots))
    max_limbs = max(train_k, *(r.num_limbs for r in robots))
    copies = max(1, min(parallel, episodes))
    quota = [episodes // copies + (c < episodes % copies) for c in range(copies)]
    env = make_env(recipe, robots, copies=copies, seed=seed, max_limbs=max_limbs)
    actor = make_net(recipe, env.base_env.table, "td3_actor")
    actor.load_state_dict(actor_state)
    actor.eval()

    n_env = env.batch_size[0]
    target = torch.tensor([quota[i % copies] for i in range(n_env)])
    got = torch.zeros(n_env, dtype=torch.long)
    rets: list[list[float]] = [[] for _ in robots]
    td = env.reset()
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        while bool((got < target).any()):
            td = actor(td)
            td, td_next = env.step_and_maybe_reset(td)
            done = td["next", "done"].squeeze(-1)
            ep_ret = td["next", "episode_reward"].squeeze(-1)
            for i in done.nonzero().flatten().tolist():
                if got[i] < target[i]:
                    rets[i // copies].append(float(ep_ret[i]))
                    got[i] += 1
            td = td_next
    env.close()
    return {r.name: summarize(rets[i]) for i, r in enumerate(robots)}


def summarize(returns: Sequence[float]) -> dict:
    x = np.asarray(returns, dtype=np.float64)
    stderr = float(x.std(ddof=1) / math.sqrt(len(x))) if len(x) > 1 else float("nan")
    return {"mean": float(x.mean()), "stderr": stderr, "episodes": len(x), "returns": x.tolist()}


def write_eval(path: Path, results: dict[str, dict], env_steps: int | None = None) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"env_steps": env_steps, "robots": results}, indent=1))
    return path


def format_table(results: dict[str, dict]) -> str:
    width = max([5, *(len(n) for n in results)])
    lines = [f"{'robot':<{width}}  {'return':>10}  {'± s.e.':>8}  episodes"]
    for name, r in results.items():
        lines.append(f"{name:<{width}}  {r['mean']:>10.1f}  {r['stderr']:>8.1f}  {r['episodes']}")
    return "\n".join(lines)
