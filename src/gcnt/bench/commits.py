"""Two commits' bare TD3 update, timed in alternate rounds: ``gcnt bench-train --commits A,B``.

Each commit is checked out into a temporary git worktree of the checkout gcnt runs from; each
round runs, for A then B, a fresh Python process that imports that worktree's ``gcnt`` (its
``src`` first on ``PYTHONPATH``; the installed dependencies are shared), builds the recipe's
learner as that commit builds it, warms it up and times ``--updates`` updates on the batches
that commit's schedule samples (:func:`gcnt.bench.td3.robot_batches`: every robot's batch in
turn on the paper schedule). Alternating keeps both commits under the same machine load; the
ratio is of the medians. The timing script uses only what every commit since the bench began
has (``load_recipe``, ``robot_batches``, ``training_threads``, ``TD3Learner.step``).
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

#: what each round runs in the commit's worktree: argv = recipe, updates, overrides...
TIMER = """
import json, sys, time
import gcnt  # before torch: gcnt sets the OpenMP spin count
import torch
from gcnt.bench.td3 import robot_batches, training_threads
from gcnt.recipes import load_recipe
from gcnt.rl.td3.learner import TD3Learner
recipe = load_recipe(sys.argv[1], sys.argv[3:])
training_threads(recipe)
env, batches = robot_batches(recipe)
torch.manual_seed(0)
learner = TD3Learner(recipe, env)
period = recipe.td3.policy_delay
for b in batches:
    for _ in range(period + 1):
        learner.update(b)
cycle = period * len(batches)
n = max(cycle, -(-int(sys.argv[2]) // cycle) * cycle)
t0 = time.perf_counter()
rows = [learner.step(batches[i // period % len(batches)]) for i in range(n)]
torch.stack([r["loss_critic"] for r in rows]).sum().item()
ms = 1e3 * (time.perf_counter() - t0) / n
print(json.dumps({"update_ms": ms, "updates": n, "gcnt": gcnt.__file__}))
"""


class CommitBenchError(RuntimeError):
    """A commit that cannot be checked out or timed (the message names it)."""


def _git(root: Path, *args: str) -> str:
    out = subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True)
    if out.returncode:
        raise CommitBenchError(f"git {' '.join(args)}: {out.stderr.strip() or out.stdout.strip()}")
    return out.stdout.strip()


def checkout_root(start: Path | None = None) -> Path:
    """The git checkout holding ``start`` (default: the working folder)."""
    try:
        return Path(_git(start or Path.cwd(), "rev-parse", "--show-toplevel"))
    except (CommitBenchError, FileNotFoundError):
        raise CommitBenchError(
            "bench-train --commits compares commits of a git checkout: run it inside one"
        ) from None


def _recipe_in(worktree: Path, root: Path, recipe: str) -> str:
    """``recipe`` as the commit has it: a file of the checkout is read from the worktree."""
    path = Path(recipe).resolve()
    if path.is_file() and path.is_relative_to(root):
        return str(worktree / path.relative_to(root))
    return recipe  # a shipped name, or a file outside the checkout: the same for both


def compare_commits(
    recipe: str, overrides: list[str], commits: list[str], updates: int, rounds: int = 5
) -> dict:
    """Median ms per bare update of each commit (alternate rounds, a fresh process each) and
    the ratio last ÷ first."""
    root = checkout_root()
    shas = [_git(root, "rev-parse", "--verify", f"{c}^{{commit}}") for c in commits]
    seconds: dict[str, list[float]] = {c: [] for c in commits}
    with tempfile.TemporaryDirectory(prefix="gcnt-commits-") as tmp:
        trees = {}
        try:
            for c, sha in zip(commits, shas, strict=True):
                tree = Path(tmp) / sha[:12]
                if tree.exists():  # the same commit twice
                    trees[c] = tree
                    continue
                _git(root, "worktree", "add", "--detach", "--quiet", str(tree), sha)
                trees[c] = tree
            for _ in range(rounds):
                for c in commits:
                    seconds[c].append(_time_once(trees[c], root, recipe, overrides, updates, c))
        finally:
            for tree in set(trees.values()):
                subprocess.run(
                    ["git", "-C", str(root), "worktree", "remove", "--force", str(tree)],
                    capture_output=True,
                )
    out = {
        "commits": dict(zip(commits, shas, strict=True)),
        "update_ms": {c: statistics.median(v) for c, v in seconds.items()},
        "rounds_ms": seconds,
    }
    out["ratio"] = out["update_ms"][commits[-1]] / out["update_ms"][commits[0]]
    return out


def _time_once(
    tree: Path, root: Path, recipe: str, overrides: list[str], updates: int, name: str
) -> float:
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(tree / "src"), os.environ.get("PYTHONPATH", "")]),
    }
    args = [sys.executable, "-c", TIMER, _recipe_in(tree, root, recipe), str(updates), *overrides]
    done = subprocess.run(args, capture_output=True, text=True, env=env, cwd=tree)
    lines = [x for x in done.stdout.splitlines() if x.startswith("{")]
    if done.returncode or not lines:
        last = (done.stderr.strip().splitlines() or ["no output"])[-1]
        raise CommitBenchError(f"commit {name}: the timed update failed: {last}")
    row = json.loads(lines[-1])
    if not Path(row["gcnt"]).resolve().is_relative_to(tree.resolve()):
        raise CommitBenchError(
            f"commit {name}: the timed process imported gcnt from {row['gcnt']}, not from the "
            "commit's worktree"
        )
    return row["update_ms"]
