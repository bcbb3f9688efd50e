"""``gcnt eval RUN_DIR [--robots test|train|NAME|PATH ...] [--episodes 100]``."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from gcnt.rl.run_dir import RunDir

log = logging.getLogger(__name__)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("run_dir", help="a run directory written by `gcnt train`")
    p.add_argument(
        "--robots",
        nargs="+",
        default=["test"],
        help="test | train | robot names | robot files | Benchmark:split (default: test)",
    )
    p.add_argument("--episodes", type=int, default=100, help="episodes per robot (default 100)")
    p.add_argument("--seed", type=int, default=10_000, help="evaluation seed")
    p.add_argument("--json", metavar="PATH", help="also write the results to PATH")


def run(args: argparse.Namespace) -> int:
    from gcnt.rl.evaluate import evaluate, format_table, write_eval

    run_dir = RunDir(args.run_dir)
    recipe = run_dir.load_recipe()
    specs: list[str] = []
    for spec in args.robots:
        if spec == "test":
            specs += recipe.env.test_robots
        elif spec == "train":
            specs += recipe.env.robots
        else:
            specs.append(spec)
    if not specs:
        log.error("no robots to evaluate (the recipe has no test robots; pass --robots ...)")
        return 2
    state = run_dir.load_checkpoint()
    results = evaluate(recipe, state["actor"], specs, episodes=args.episodes, seed=args.seed)
    print(format_table(results))
    out = write_eval(run_dir.path / "eval" / "final.json", results, state["env_steps"])
    if args.json:
        write_eval(Path(args.json), results, state["env_steps"])
    print(f"written: {out}")
    return 0
