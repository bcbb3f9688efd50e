"""Evaluation: mean ± standard error of the episode return per robot, for any algorithm.

The paper's table 1 protocol is 100 deterministic episodes per robot and seed; ModuMorph's PPO
protocol is 32 episodes per robot with sampled actions. Episodes run in parallel copies of each
robot; every copy runs a fixed share of the episodes, so early-ending (failed) episodes are not
over-represented. The env comes from the recipe's benchmark, the policy from its algorithm.

Each robot's episode lengths (control steps, mean and shortest) are kept beside its returns; a
robot whose episodes end within :data:`SHORT_EPISODE_STEPS` steps on average (below the time
limit) is named in a warning: its return says little about the policy (e.g. a robot file whose
start pose its task's termination rule reads as a fall).
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type

from gcnt.files import write_output, write_text
from gcnt.morphology import Robot
from gcnt.morphology.catalogues import resolve_robots
from gcnt.recipes import Recipe
from gcnt.rl.algorithm import get_algorithm
from gcnt.rl.device import on_device
from gcnt.rl.factories import base_env, make_env, run_robots
from gcnt.run.directory import CHECKPOINT_MISFITS, RunDirError, strict_json
from gcnt.run.resolved import resolve_run

log = logging.getLogger(__name__)

#: Episodes shorter than this on average (in control steps, and below the time limit) are
#: reported in a warning.
SHORT_EPISODE_STEPS = 10


class PolicyMismatchError(ValueError):
    """A checkpoint's policy weights that do not fit the network its recipe builds."""


def eval_robots(specs: Sequence[str], recipe: Recipe | None = None) -> list[Robot]:
    """The robots of ``specs``, each once (a robot named twice is evaluated once; robot files
    of one name are distinct robots, see :func:`~gcnt.morphology.catalogues.resolve_robots`),
    named as in the run of ``recipe`` (:func:`~gcnt.recipes.run_robot_specs`)."""
    if recipe is None:
        return resolve_robots(specs, repeats=True)
    return resolve_run(recipe).robots_of(specs, recipe)


def eval_padding(recipe: Recipe, robots: Sequence[Robot]) -> int:
    """Pad at least as much as in training: size-dependent networks (the per-robot MLP) need it,
    and cannot take a robot with more limbs (a RobotTooLargeError naming it)."""
    from gcnt.envs.robot_table import RobotTooLargeError
    from gcnt.nn.registry import NETWORKS

    train_k = recipe.env.max_limbs or max(r.num_limbs for r in run_robots(recipe)[0])
    big = max(robots, key=lambda r: r.num_limbs)
    entry = NETWORKS.get(recipe.network.name)
    if big.num_limbs > train_k and entry is not None and entry.fixed_limbs:
        raise RobotTooLargeError(
            f"robot {big.name!r} has {big.num_limbs} limbs; network {recipe.network.name!r} "
            f"was built for at most {train_k} (its input size is fixed by the training robots' "
            "padding, env.max_limbs): it cannot be evaluated on larger robots"
        )
    return max(train_k, big.num_limbs)


def check_eval_robots(recipe: Recipe, specs: Sequence[str]) -> list[Robot]:
    """The robots of ``specs`` if the recipe's policy can be evaluated on them (else the error
    that evaluating would raise, before anything runs)."""
    robots = eval_robots(specs, recipe)
    if robots:
        eval_padding(recipe, robots)
    return robots


def acting_policy(recipe: Recipe, policy_state: dict, env, deterministic: bool):
    """The algorithm's evaluation policy, on the recipe's device, for the env's CPU tensors."""
    actor = get_algorithm(recipe.algo).eval_policy(
        recipe, policy_state, env, deterministic=deterministic
    )
    return on_device(actor, recipe.device)


@torch.no_grad()
def evaluate(
    recipe: Recipe,
    policy_state: dict,
    robot_specs: Sequence[str],
    *,
    episodes: int = 100,
    parallel: int = 10,
    seed: int = 10_000,
    deterministic: bool = True,
) -> dict[str, dict]:
    """Run the recipe's trained policy on each robot for ``episodes`` episodes.

    ``policy_state`` is the algorithm's :meth:`~gcnt.rl.algorithm.Algorithm.policy_state` (as in
    a checkpoint's ``"policy"``); the policy is rebuilt for the evaluated robots (any robots,
    including never-seen robot files), so its graph table matches them.
    """
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    robots = eval_robots(robot_specs, recipe)
    copies = max(1, min(parallel, episodes))
    quota = [episodes // copies + (c < episodes % copies) for c in range(copies)]
    env = make_env(recipe, robots, copies=copies, seed=seed, max_limbs=eval_padding(recipe, robots))
    try:
        actor = acting_policy(recipe, policy_state, env, deterministic)
    except CHECKPOINT_MISFITS as e:
        env.close()
        if type(e) in CHECKPOINT_MISFITS:  # not a named error of its own
            raise PolicyMismatchError(
                "the checkpoint's policy does not fit the recipe's network (was the recipe "
                f"changed since training?): {str(e).splitlines()[0] if str(e) else repr(e)}"
            ) from None
        raise

    n_env = env.batch_size[0]
    target = torch.tensor([quota[i % copies] for i in range(n_env)])
    got = torch.zeros(n_env, dtype=torch.long)
    steps = torch.zeros(n_env, dtype=torch.long)  # control steps of each sub-env's episode
    rets: list[list[float]] = [[] for _ in robots]
    lengths: list[list[int]] = [[] for _ in robots]
    td = env.reset()
    mode = ExplorationType.DETERMINISTIC if deterministic else ExplorationType.RANDOM
    with set_exploration_type(mode):
        while bool((got < target).any()):
            td = actor(td)
            td, td_next = env.step_and_maybe_reset(td)
            steps += 1
            done = td["next", "done"].squeeze(-1)
            ep_ret = td["next", "episode_reward"].squeeze(-1)
            for i in done.nonzero().flatten().tolist():
                if got[i] < target[i]:
                    rets[i // copies].append(float(ep_ret[i]))
                    lengths[i // copies].append(int(steps[i]))
                    got[i] += 1
            steps[done.cpu()] = 0
            td = td_next
    env.close()
    results = {r.name: summarize(rets[i], lengths[i]) for i, r in enumerate(robots)}
    warn_short_episodes(results, recipe.env.max_episode_steps)
    return results


def warn_short_episodes(results: dict[str, dict], max_episode_steps: int) -> list[str]:
    """Warn about each robot whose episodes last fewer than :data:`SHORT_EPISODE_STEPS` control
    steps on average while the time limit allows more: its episodes end (terminate) almost at
    once. Returns those robots' names."""
    limit = min(SHORT_EPISODE_STEPS, max_episode_steps)
    short = [n for n, r in results.items() if r.get("length_mean", limit) < limit]
    for name in short:
        r = results[name]
        log.warning(
            "robot %r: its episodes end after %.1f control steps on average (shortest %d, time "
            "limit %d): its task's termination rule ends them almost at once, so its return "
            "says little about the policy",
            name,
            r["length_mean"],
            r["length_min"],
            max_episode_steps,
        )
    return short


@torch.no_grad()
def render_policy(
    recipe: Recipe,
    policy_state: dict,
    path: Path,
    *,
    robot: str | Robot | None = None,
    steps: int | None = None,
) -> Path:
    """A video of one episode of the deterministic policy on ``robot`` (a robot, or a spec
    whose first robot is filmed; default: every training robot, side by side, up to
    :data:`gcnt.envs.render.MAX_TILES`), at most ``steps`` control steps (None: until the
    episodes end)."""
    from gcnt.envs.render import MAX_TILES, render_rollout

    if isinstance(robot, Robot):
        robots = [robot]
    elif robot:
        robots = eval_robots([robot], recipe)[:1]
    else:
        robots = eval_robots(recipe.env.robots, recipe)[:MAX_TILES]
    env = make_env(
        recipe, robots, seed=recipe.seed, max_limbs=eval_padding(recipe, robots), num_threads=1
    )
    actor = acting_policy(recipe, policy_state, env, True)
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        out = render_rollout(base_env(env), actor, steps=steps, path=path, index=range(len(robots)))
    env.close()
    return out


def summarize(returns: Sequence[float], lengths: Sequence[int] | None = None) -> dict:
    """Mean, standard error and list of the episode ``returns``; with the episodes' ``lengths``
    (control steps), also ``length_mean`` and ``length_min``."""
    x = np.asarray(returns, dtype=np.float64)
    stderr = float(x.std(ddof=1) / math.sqrt(len(x))) if len(x) > 1 else float("nan")
    out = {"mean": float(x.mean()), "stderr": stderr, "episodes": len(x), "returns": x.tolist()}
    if lengths is not None:
        out["length_mean"] = float(np.mean(lengths))
        out["length_min"] = int(np.min(lengths))
    return out


def write_eval(
    path: Path,
    results: dict[str, dict],
    env_steps: int | None = None,
    meta: dict | None = None,
    *,
    named: bool = False,
) -> Path:
    """Write results as ``{"env_steps", **meta, "robots": {name: summary}}`` (atomically), as
    strict JSON: a non-finite value (the standard error of one episode) is ``null``. A failed
    write (no permission, a full disk) leaves no temporary file and is a RunDirError naming
    ``path``. ``named``: a path the user named (``--json``), which may be a device or a FIFO
    (:func:`gcnt.files.write_output`)."""
    out = {"env_steps": env_steps, **(meta or {}), "robots": results}
    if results:
        out["over_robots"] = summarize_robots(results)
    text = json.dumps(strict_json(out), indent=1, allow_nan=False)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        if named:
            write_output(path, text.encode("utf-8"))
        else:
            write_text(path, text)
    except OSError as e:
        raise RunDirError(f"{path}: cannot write the evaluation ({e.strerror or e})") from None
    return path


def format_table(results: dict[str, dict]) -> str:
    """One row per robot: mean return, standard error, episodes and episode length (control
    steps: mean, shortest; ``-`` where the results have none)."""
    width = max([5, *(len(n) for n in results)])
    lines = [f"{'robot':<{width}}  {'return':>10}  {'± s.e.':>8}  episodes  length (mean, min)"]
    for name, r in results.items():
        length = f"{r['length_mean']:.1f}, {r['length_min']}" if "length_mean" in r else "-"
        se = f"{r['stderr']:>8.1f}" if r["episodes"] > 1 else f"{'-':>8}"  # none of one episode
        lines.append(f"{name:<{width}}  {r['mean']:>10.1f}  {se}  {r['episodes']:>8}  {length}")
    if len(results) > 1:
        s = summarize_robots(results)
        if "ci95_low" in s:
            interval = (
                f"95% CI [{s['ci95_low']:.1f}, {s['ci95_high']:.1f}] "
                f"(bootstrap over n = {s['robots']} robots)"
            )
        else:
            interval = (
                f"range [{s['range_low']:.1f}, {s['range_high']:.1f}] over n = {s['robots']} robots"
            )
        lines.append(
            f"{'mean over ' + str(s['robots']) + ' robots':<{width}}  {s['mean']:>10.1f}  "
            + interval
        )
    return "\n".join(lines)


def summarize_robots(results: dict[str, dict], *, resamples: int = 2000, seed: int = 0) -> dict:
    """The mean over robots of their mean returns, and around it, named for what it is: a 95%
    bootstrap confidence interval (percentile method, resampling robots; ``ci95_low``,
    ``ci95_high``) over at least :data:`~gcnt.bootstrap.MIN_BOOTSTRAP` robots, else
    the range of their means (``range_low``, ``range_high``; one robot: its mean)."""
    from scipy.stats import bootstrap

    from gcnt.bootstrap import MIN_BOOTSTRAP

    x = np.array([r["mean"] for r in results.values()], dtype=np.float64)
    mean = float(x.mean())
    if len(x) < MIN_BOOTSTRAP:
        low, high = (float(x.min()), float(x.max())) if len(x) else (mean, mean)
        return {"mean": mean, "range_low": low, "range_high": high, "robots": len(x)}
    if np.all(x == x[0]):
        low = high = mean
    else:
        ci = bootstrap(
            (x,),
            np.mean,
            confidence_level=0.95,
            n_resamples=resamples,
            method="percentile",
            random_state=np.random.default_rng(seed),
        ).confidence_interval
        low, high = float(ci.low), float(ci.high)
    return {"mean": mean, "ci95_low": low, "ci95_high": high, "robots": len(x)}
