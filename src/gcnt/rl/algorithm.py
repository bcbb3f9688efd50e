"""The algorithm seam: what an algorithm gives the shared run loop (:func:`gcnt.rl.loop.train`).

The run loop owns everything every algorithm shares: seeding, resume, the env and its collector,
the progress bar, metrics, checkpoints, evaluation and video. An algorithm owns its networks,
losses, optimisers and data handling, and provides:

* :meth:`Algorithm.collect_settings`: the exploring policy and the collector's batch sizes;
* :meth:`Algorithm.process`: what it does with each collected batch (it yields loss dictionaries);
* :meth:`Algorithm.state_dict` / :meth:`load_state_dict`: its checkpoint state;
* :meth:`Algorithm.policy_state` and :meth:`Algorithm.eval_policy`: the policy evaluation and
  video rebuild for any robots (zero-shot included), from a checkpoint alone.

A new algorithm is a subclass plus two registrations, with no gcnt file edited::

    register_algorithm_section("toy", ToyConfig)   # gcnt.recipes: its ``toy:`` recipe section
    register_algorithm("toy", ToyAlgorithm)
"""

from __future__ import annotations

import importlib
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.envs import EnvBase

from gcnt.morphology import Robot
from gcnt.recipes import Recipe, RecipeError, algorithm_names
from gcnt.suggest import did_you_mean


@dataclass
class CollectSettings:
    """How the run loop's collector runs an algorithm's policy."""

    #: the exploring policy the collector runs (on the recipe's device)
    policy: TensorDictModuleBase
    #: frames per collected batch (all envs together)
    frames_per_batch: int
    #: frames of uniformly random actions before the policy acts (a multiple of the above)
    init_random_frames: int = 0
    #: counted env steps (:meth:`Algorithm.admit`) of random actions, where they are not the
    #: collector's frames: the run loop ends the collector's random phase once it counted them
    random_steps: int | None = None
    #: env constructors, one per worker process: collect with torchrl's MultiSyncCollector over
    #: them (the policy's weights are sent to the workers after each batch is processed) instead
    #: of the training env in this process. Their envs together must match the training env.
    env_makers: list[Callable[[], EnvBase]] | None = None


class Algorithm(ABC):
    """One learning algorithm behind the run loop.

    Built by the run loop as ``cls(recipe, env, robots)``: ``env`` is the training env (already
    built by the benchmark, batch [N]; its specs give the observation and action widths, its
    ``table`` the robot table), ``robots`` the run's training robots (``morph_id`` indexes them).
    """

    #: its name in recipes (``algo:``)
    name: ClassVar[str] = ""
    #: gradient updates so far (logged and checkpointed; an instance attribute once assigned, or
    #: a property reading the algorithm's learner)
    updates: int = 0

    def __init__(self, recipe: Recipe, env: EnvBase, robots: Sequence[Robot]) -> None:
        self.recipe = recipe
        self.config = recipe.algo_config
        self.env = env
        self.robots = list(robots)
        #: what it chose for this run and why, one line each: logged when training starts
        self.choices: list[str] = []

    # ------------------------------------------------------------------ the env
    @classmethod
    def train_env_copies(cls, recipe: Recipe, num_robots: int) -> int:
        """Sub-envs per training robot in the training env (default: ``env.copies``)."""
        return recipe.env.copies

    @classmethod
    def make_train_env(cls, recipe: Recipe, robots: Sequence[Robot]) -> EnvBase:
        """The training env over ``robots`` (default: the benchmark's env with
        :meth:`train_env_copies` copies of each robot; PPO builds robot-sampling slots)."""
        from gcnt.rl.factories import make_env

        return make_env(recipe, robots, copies=cls.train_env_copies(recipe, len(robots)))

    # ------------------------------------------------------------------ collection and learning
    @abstractmethod
    def collect_settings(self, env_steps: int) -> CollectSettings:
        """The collector's policy and sizes, for a run that has ``env_steps`` steps behind it."""

    @abstractmethod
    def process(self, data: TensorDictBase, env_steps: int) -> Iterator[dict[str, float]]:
        """Learn from one collected batch (batch [N, T]); yield one dict of losses per update.

        ``env_steps`` counts the steps of every batch so far, this one included.
        """

    def admit(self, data: TensorDictBase) -> TensorDictBase:
        """The transitions of a collected batch that the run keeps and counts (default: all
        of them, as collected)."""
        return data

    def reset_due(self) -> bool:
        """Whether every sub-env must start a new episode before the next batch (asked once
        after each batch's update phase)."""
        return False

    def log_extras(self) -> dict[str, float]:
        """Extra scalars for the next log row (learning rate, KL, ...); cleared by the callee."""
        return {}

    def resolved(self) -> dict[str, Any]:
        """Sizes derived from the recipe (iterations, batch counts), written to recipe.yaml."""
        return {}

    # ------------------------------------------------------------------ checkpoints
    @abstractmethod
    def state_dict(self) -> dict[str, Any]:
        """Everything needed to continue training exactly (networks, optimisers, counters)."""

    @abstractmethod
    def load_state_dict(self, state: dict[str, Any]) -> None: ...

    def buffers_state(self, directory) -> bool:
        """Write large data (replay buffers) to ``directory``; True if anything was written."""
        return False

    def load_buffers(self, directory) -> None:  # noqa: B027 (optional hook, no-op by default)
        """Read what :meth:`buffers_state` wrote (nothing to read by default)."""

    def start_from(self, state: dict[str, Any]) -> None:
        """Fine-tuning (``init_from``): take over the learnt networks, and whatever the policy
        reads with them (observation statistics), from another run's :meth:`state_dict`;
        optimisers, buffers and counters stay as built. A ValueError names what does not fit."""
        raise RecipeError(f"init_from: algorithm {self.name!r} cannot start from a trained run")

    # ------------------------------------------------------------------ evaluation
    @abstractmethod
    def policy_state(self) -> dict[str, Any]:
        """What :meth:`eval_policy` needs to rebuild the policy (weights, frozen statistics)."""

    @classmethod
    @abstractmethod
    def eval_policy(
        cls, recipe: Recipe, state: dict[str, Any], env: EnvBase, *, deterministic: bool = True
    ) -> TensorDictModuleBase:
        """The trained policy for ``env``'s robots (any robots: the network is rebuilt for its
        robot table), from :meth:`policy_state` output. ``deterministic``: the mean action."""


_ALGORITHMS: dict[str, type[Algorithm]] = {}
_BUILTIN: dict[str, str] = {"td3": "gcnt.rl.td3.learner:TD3", "ppo": "gcnt.rl.ppo.learner:PPO"}


def register_algorithm(name: str, cls: type[Algorithm], *, replace: bool = False) -> None:
    """Make algorithm ``cls`` trainable with ``algo: name`` (its recipe section must be
    registered with :func:`gcnt.recipes.register_algorithm_section`)."""
    if name in _BUILTIN and get_algorithm(name) is not cls:
        raise ValueError(
            f"algorithm {name!r} is built into gcnt and cannot be replaced; register yours under "
            "a name of its own"
        )
    if name in _ALGORITHMS and not replace and _ALGORITHMS[name] is not cls:
        raise ValueError(f"algorithm {name!r} is already registered")
    _ALGORITHMS[name] = cls


def get_algorithm(name: str) -> type[Algorithm]:
    if name not in _ALGORITHMS and name in _BUILTIN:
        module, attr = _BUILTIN[name].split(":")
        _ALGORITHMS[name] = getattr(importlib.import_module(module), attr)
    if name not in _ALGORITHMS:
        known = sorted({*_ALGORITHMS, *_BUILTIN, *algorithm_names()})
        raise RecipeError(f"algo: unknown algorithm {name!r}{did_you_mean(name, known)}")
    return _ALGORITHMS[name]
