"""``gcnt eval RUN_DIR [--robots test|train|NAME|PATH ...] [--episodes N] [--stochastic]``.

Every evaluation is kept: ``eval/<robots>-step<N>-<mode>.json`` in the run directory says what
was evaluated (robots, episodes, seed, deterministic or sampled actions).
"""

from __future__ import annotations

import argparse
import logging
import re
from pathlib import Path

log = logging.getLogger(__name__)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("run_dir", help="a run directory written by `gcnt train`")
    p.add_argument(
        "--robots",
        nargs="+",
        default=["test"],
        help="test | train | robot names | robot files or folders | Benchmark:split "
        "(default: test)",
    )
    p.add_argument(
        "--episodes",
        type=int,
        default=None,
        help="episodes per robot (default: 100 deterministic, 32 with --stochastic)",
    )
    p.add_argument("--seed", type=int, default=10_000, help="evaluation seed")
    p.add_argument(
        "--stochastic",
        action="store_true",
        help="sample actions from the policy (ModuMorph's PPO protocol) instead of its mean",
    )
    p.add_argument("--json", metavar="PATH", help="also write the results to PATH")


def _label(specs: list[str]) -> str:
    text = "+".join(Path(s).stem if s.endswith(".xml") else s for s in specs)
    text = re.sub(r"[^A-Za-z0-9_.+-]+", "_", text.replace(":", "-"))
    return text[:80] or "robots"


def run(args: argparse.Namespace) -> int:
    from gcnt.recipes import RecipeError
    from gcnt.rl.evaluate import PolicyMismatchError, evaluate, format_table, write_eval
    from gcnt.rl.loop import check_network
    from gcnt.rl.run_dir import CheckpointError, RunDir

    episodes = args.episodes if args.episodes is not None else (32 if args.stochastic else 100)
    if episodes < 1:
        raise RecipeError(f"--episodes must be >= 1, got {episodes}")
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
        raise RecipeError(
            "no robots to evaluate (the recipe has no test robots; pass --robots ...)"
        )
    check_network(recipe)
    state = run_dir.load_checkpoint()
    policy = state.get("policy") or {"actor": state["actor"]}  # "actor": checkpoints before 0.2
    deterministic = not args.stochastic
    try:
        results = evaluate(
            recipe, policy, specs, episodes=episodes, seed=args.seed, deterministic=deterministic
        )
    except PolicyMismatchError as e:
        raise CheckpointError(f"{run_dir.checkpoint_path}: {e}") from None
    print(format_table(results))
    meta = {
        "robots_spec": args.robots,
        "episodes": episodes,
        "seed": args.seed,
        "deterministic": deterministic,
    }
    mode = "det" if deterministic else "stoch"
    name = f"{_label(args.robots)}-step{state['env_steps']}-{mode}-seed{args.seed}.json"
    out = write_eval(run_dir.path / "eval" / name, results, state["env_steps"], meta)
    if args.json:
        write_eval(Path(args.json), results, state["env_steps"], meta)
    print(f"written: {out}")
    return 0
