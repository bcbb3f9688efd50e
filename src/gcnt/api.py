"""Using a trained run from Python: :func:`load_run` (what it recorded, its metrics and
evaluations: data only), :func:`load_policy` (its trained deterministic acting policy) and
:func:`make_env` (an env the policy acts on). Exported from :mod:`gcnt`::

    import gcnt

    run = gcnt.load_run("runs/quickstart/td3-gcnt/seed0")
    env = gcnt.make_env(run.path)                  # the run's training robots
    policy = gcnt.load_policy(run.path)
    td = policy(env.reset())                       # td["limbs", "action"]: per limb

Like ``gcnt eval``, nothing the run names is imported (a plugin's method is named by
``gcnt.plugins.load([...])`` first), and robots the run trained on that are not registered here
are read from the run's own copies.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase


@dataclass(frozen=True)
class LoadedRun:
    """A run directory as data: no network is built and no code it names is imported."""

    path: Path
    #: the recipe as the run recorded it (``recipe.yaml``), its ``resolved:`` record included
    recipe: dict[str, Any]
    #: the rows of ``metrics.jsonl`` (one per log step)
    metrics: list[dict[str, Any]]
    #: the evaluation files under ``eval/`` (:class:`gcnt.run.data.EvalRecord`)
    evaluations: list[Any]

    @property
    def robots(self) -> dict[str, Any]:
        """The robots the run recorded: ``{"train": [...], "test": [...], "index": {name:
        {"sha256", ...}}}`` (empty for a run written before robots were stored)."""
        resolved = self.recipe.get("resolved")
        return dict(resolved.get("robots") or {}) if isinstance(resolved, dict) else {}

    @property
    def record(self) -> Any:
        """The run's record (:class:`gcnt.run.resolved.RunRecord`); None for a run written
        before the record."""
        from gcnt.run.resolved import RunRecord

        resolved = self.recipe.get("resolved")
        return RunRecord.from_resolved(resolved) if isinstance(resolved, dict) else None


def load_run(run: str | Path) -> LoadedRun:
    """The record of the run directory ``run``, its metrics and its evaluations."""
    from gcnt.run.data import RECIPE_FILE, AnalysisError, Run

    path = Path(run)
    if not (path / RECIPE_FILE).is_file():
        raise AnalysisError(f"{path}: no {RECIPE_FILE}; is this a gcnt run directory?")
    r = Run(path)
    return LoadedRun(path, r.recipe, r.metrics(), r.evals())


def _recipe_and_robots(run: str | Path, robots: Sequence[str] | None, device: str):
    from gcnt.rl.evaluate import eval_padding, eval_robots
    from gcnt.run.directory import RunDir

    recipe = RunDir(run).load_recipe([f"device={device}"], anywhere=True)
    chosen = eval_robots(list(robots) if robots is not None else recipe.env.robots, recipe)
    return recipe, chosen, eval_padding(recipe, chosen)


def make_env(
    run: str | Path,
    robots: Sequence[str] | None = None,
    *,
    copies: int = 1,
    seed: int = 0,
    device: str = "cpu",
):
    """The run's benchmark env (a torchrl ``EnvBase``, batched: ``copies`` of each robot) on
    ``robots`` (robot specs, as ``gcnt eval --robots`` takes them; default: the run's training
    robots), padded as :func:`load_policy` pads for the same robots."""
    from gcnt.rl.factories import make_env as build

    recipe, chosen, pad = _recipe_and_robots(run, robots, device)
    return build(recipe, chosen, copies=copies, seed=seed, max_limbs=pad)


class DeterministicPolicy(TensorDictModuleBase):
    """A trained acting policy that always takes its deterministic action (the mean of a
    stochastic one), whatever exploration type the caller sets."""

    def __init__(self, policy: TensorDictModuleBase):
        super().__init__()
        self.policy = policy
        self.in_keys = list(policy.in_keys)
        self.out_keys = list(policy.out_keys)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        import torch
        from torchrl.envs.utils import ExplorationType, set_exploration_type

        with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
            return self.policy(tensordict)


def load_policy(
    run: str | Path,
    checkpoint: str = "last",
    device: str = "cpu",
    robots: Sequence[str] | None = None,
) -> DeterministicPolicy:
    """The trained deterministic acting policy of the run directory ``run`` (its last
    checkpoint), on ``device``, for ``robots`` (robot specs; default: the run's training
    robots): a TensorDict module that writes ``("limbs", "action")`` into the tensordicts of an env made
    by :func:`make_env` for the same robots."""
    from gcnt.rl.evaluate import acting_policy
    from gcnt.rl.factories import make_env as build
    from gcnt.run.directory import RunDir

    if checkpoint != "last":
        raise ValueError(f"checkpoint: a run keeps its last checkpoint only; got {checkpoint!r}")
    recipe, chosen, pad = _recipe_and_robots(run, robots, device)
    state = RunDir(run).load_checkpoint()
    policy_state = state.get("policy") or {"actor": state["actor"]}
    env = build(recipe, chosen, copies=1, seed=recipe.seed, max_limbs=pad, num_threads=1)
    try:
        return DeterministicPolicy(acting_policy(recipe, policy_state, env, True)).eval()
    finally:
        env.close()
