"""``gcnt bench-train``: what the training pipeline costs on top of the learning itself.

In one run: (1) the bare TD3 update rate (same networks, same mini-batch, no env, no buffer) and
(2) ``gcnt train`` with the same recipe end to end, measured after the random-exploration phase:
environment steps per second and updates per second. The ratio of end-to-end to bare updates/s is
the fraction of time spent learning; 1.0 means the env, collector and buffers cost nothing. With
one update per environment step (the paper), env steps/s equals updates/s in the long run; over a
short window the paper schedule's not-yet-trained pending steps make env steps/s look higher.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time



def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("recipe", nargs="?", default="recipes/smpenv/walker.yaml")
    p.add_argument("overrides", nargs="*", help="dotted recipe overrides")
    p.add_argument("--updates", type=int, default=30, help="bare updates to time")
    p.add_argument("--steps", type=int, default=400, help="env steps to time end to end")
    p.add_argument("--warmup", type=int, default=200, help="random-action steps before timing")
    p.add_argument("--json", action="store_true", help="print JSON only")


def bare_update_rate(recipe, n_updates: int) -> float:
    """Updates/s on one fixed mini-batch shaped as the recipe's schedule samples it."""
    from gcnt.rl import replay as rb
    from gcnt.rl.factories import make_env, train_robots
    from gcnt.rl.td3 import TD3Learner

    c = recipe.td3
    robots = train_robots(recipe)
    env = make_env(recipe, robots)
    steps = -(-c.batch_size // env.batch_size[0]) + 1
    data = env.rollout(steps, break_when_any_done=False)
    replay = rb.make_replay(len(robots), capacity=data.numel(), batch_size=c.batch_size)
    rb.store(replay, data)
    batch = (rb.sample_mixed(replay) if c.schedule == "mixed" else rb.sample_robot(replay, 0))
    batch = batch.clone()
    learner = TD3Learner(recipe, env)
    for _ in range(3):
        learner.update(batch)
    t0 = time.perf_counter()
    for _ in range(n_updates):
        learner.update(batch)
    return n_updates / (time.perf_counter() - t0)


def end_to_end_rate(recipe, warmup: int, steps: int) -> dict:
    from gcnt.rl.loop import train
    from gcnt.rl.run_dir import RunDir

    with tempfile.TemporaryDirectory() as tmp:
        recipe.run_dir = tmp
        recipe.td3.init_random_frames = warmup
        recipe.collector.total_frames = warmup + steps
        recipe.td3.steps_per_batch = 1
        recipe.logger.backend, recipe.logger.progress = "none", False
        recipe.logger.log_interval = max(1, warmup)
        recipe.checkpoint_interval = 10**12
        recipe.eval.episodes = 0
        run = RunDir(tmp)
        run.create(recipe)
        train(recipe, run)
        all_rows = run.read_metrics()
        rows = [r for r in all_rows if r["env_steps"] > warmup]
        before = [r for r in all_rows if r["env_steps"] <= warmup]
    span = rows[-1]["env_steps"] - warmup
    secs = sum(
        (r["env_steps"] - p["env_steps"]) / r["env_steps_per_s"]
        for p, r in zip([{"env_steps": warmup}, *rows], rows, strict=False)
    )
    updates = rows[-1]["updates"] - before[-1]["updates"] if before else rows[-1]["updates"]
    return {"env_steps_per_s": span / secs, "updates_per_s": updates / secs, "updates": updates}


def run(args: argparse.Namespace) -> int:
    import torch

    from gcnt.recipes import RecipeError, load_recipe

    recipe = load_recipe(args.recipe, args.overrides)
    if recipe.algo != "td3":
        raise RecipeError(f"bench-train measures TD3 recipes; {args.recipe} has algo {recipe.algo}")
    bare = bare_update_rate(recipe, args.updates)
    e2e = end_to_end_rate(recipe, args.warmup, args.steps)
    # time per update end to end vs bare: what the env, collector and buffers add to learning
    ratio = e2e["updates_per_s"] / bare
    out = {
        "recipe": args.recipe,
        "network": recipe.network.name,
        "batch_size": recipe.td3.batch_size,
        "updates_per_step": recipe.td3.updates_per_step,
        "threads": torch.get_num_threads(),
        "bare_updates_per_s": bare,
        "end_to_end_env_steps_per_s": e2e["env_steps_per_s"],
        "end_to_end_updates_per_s": e2e["updates_per_s"],
        "ratio": ratio,
    }
    if args.json:
        print(json.dumps(out))
    else:
        print(
            f"bare TD3 update:   {bare:8.2f} updates/s ({recipe.network.name}, batch {out['batch_size']})"
        )
        print(
            f"end to end:        {e2e['env_steps_per_s']:8.2f} env steps/s, "
            f"{e2e['updates_per_s']:.2f} updates/s ({e2e['updates']} updates)"
        )
        print(f"ratio (end-to-end updates/s ÷ bare updates/s): {ratio:.3f}")
    return 0
