"""``gcnt bench-learn``: the learning check (too long for the tests): does a recipe beat random?

For each seed, trains the recipe (default: the quick start) into a temporary directory and
compares the random policy's training return (the uniform-random exploration phase) with the
deterministic policy's evaluation return at the end, robot by robot mean. Passes when every seed
clears both margins; exits 1 otherwise.
"""

from __future__ import annotations

import argparse
import tempfile
import time

from gcnt.files import MiB, read_json


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "recipe", nargs="?", help="recipe file (default: recipes/quickstart.yaml, from any folder)"
    )
    p.add_argument("overrides", nargs="*", help="dotted recipe overrides")
    p.add_argument("--seeds", default="0,1", metavar="S1,S2,...", help="seeds (default: 0,1)")
    p.add_argument("--min-gain", type=float, default=100.0, help="final - random must exceed this")
    p.add_argument("--min-ratio", type=float, default=2.0, help="final / random must exceed this")


def learning_check(recipe_path: str, overrides: list[str], seed: int) -> dict:
    import numpy as np

    from gcnt.recipes import load_recipe
    from gcnt.rl.loop import train
    from gcnt.run.directory import RunDir

    with tempfile.TemporaryDirectory() as tmp:
        recipe = load_recipe(recipe_path, [*overrides, f"seed={seed}", f"run_dir={tmp}"])
        recipe.logger.backend, recipe.logger.progress = "none", False
        recipe.eval.robots = recipe.eval.robots or recipe.env.robots
        run = RunDir(tmp)
        run.create(recipe)
        t0 = time.perf_counter()
        train(recipe, run)
        minutes = (time.perf_counter() - t0) / 60
        rows = run.read_metrics()
        evals = sorted((run.path / "eval").glob("step*.json"), key=lambda p: p.stat().st_mtime)
        final = read_json(evals[-1], 64 * MiB, "an evaluation is JSON", ValueError)["robots"]
    # the first logged return: episodes of the uniform-random exploration phase
    random_return = next(r["train_return/mean"] for r in rows if "train_return/mean" in r)
    return {
        "seed": seed,
        "random_return": random_return,
        "final_return": float(np.mean([v["mean"] for v in final.values()])),
        "final_per_robot": {k: v["mean"] for k, v in final.items()},
        "minutes": minutes,
    }


def run(args: argparse.Namespace) -> int:
    from gcnt.rl.td3.stacked_loop import parse_seeds

    seeds = parse_seeds(args.seeds)
    from gcnt.recipes import default_recipe

    recipe = args.recipe or default_recipe()
    results = [learning_check(recipe, args.overrides, s) for s in seeds]
    ok = True
    print(f"{'seed':>4}  {'random':>8}  {'final':>8}  {'minutes':>7}  per robot (final)")
    for r in results:
        passed = r["final_return"] - r["random_return"] > args.min_gain and r[
            "final_return"
        ] > args.min_ratio * max(r["random_return"], 1e-9)
        ok &= passed
        robots = ", ".join(f"{k} {v:.0f}" for k, v in r["final_per_robot"].items())
        print(
            f"{r['seed']:>4}  {r['random_return']:8.1f}  {r['final_return']:8.1f}  "
            f"{r['minutes']:7.1f}  {robots}  {'ok' if passed else 'FAIL'}"
        )
    print("learning check:", "passed" if ok else "FAILED")
    return 0 if ok else 1
