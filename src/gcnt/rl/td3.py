"""TD3 for one policy over many robots, behind the algorithm seam (``gcnt.rl.algorithm``).

Built from torchrl parts: per-robot replay buffers (``ReplayBufferEnsemble`` routed by
``morph_id``), ``TD3Loss`` with per-limb twin critics (see ``td3_loss``), ``SoftUpdate`` targets
and Gaussian exploration (``AdditiveGaussianModule``); the shared run loop (``gcnt.rl.loop``)
collects the batches. Settings: the ``td3:`` recipe section (``gcnt.rl.td3_config``).

Two update schedules (``td3.schedule``):

* ``paper``: robots step in lockstep until every robot has finished an episode; then each robot in
  turn gets as many updates as it stored transitions, each from its own buffer.
* ``mixed``: every ``steps_per_batch`` lockstep steps, updates on padded mini-batches that hold
  ``batch_size`` transitions of every robot: the same samples per stored step as ``paper``, in
  one forward pass per update instead of one per robot.

Every stored environment step is counted, over all robots.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictSequential
from torchrl.envs import EnvBase
from torchrl.modules import AdditiveGaussianModule
from torchrl.objectives import SoftUpdate

from gcnt.morphology import Robot
from gcnt.nn.graph_lookup import is_table_key
from gcnt.nn.keys import ACTION
from gcnt.recipes import Recipe
from gcnt.rl import replay as rb
from gcnt.rl.algorithm import Algorithm, CollectSettings
from gcnt.rl.factories import make_net
from gcnt.rl.td3_config import TD3Config
from gcnt.rl.td3_loss import actor_loss, critic_loss, make_td3_loss

log = logging.getLogger(__name__)


class TD3Learner:
    """Networks, loss, optimisers and the update step; no env, no buffer (benchmarkable alone)."""

    def __init__(self, recipe: Recipe, env: EnvBase):
        o: TD3Config = recipe.algo_config
        self.recipe, self.config = recipe, o
        self.actor = make_net(recipe, env, "td3_actor")
        # two independently initialised critics (given one, TD3Loss re-draws the twin's weights
        # uniformly between each tensor's min and max, losing the layers' own init schemes)
        self.critics = [make_net(recipe, env, "td3_critic") for _ in range(2)]
        self.loss = make_td3_loss(
            self.actor,
            self.critics,
            gamma=o.gamma,
            policy_noise=o.policy_noise,
            noise_clip=o.noise_clip,
        )
        self.target_updater = SoftUpdate(self.loss, tau=o.tau)
        self.actor_params = list(self.loss.actor_network_params.values(True, True))
        self.critic_params = list(self.loss.qvalue_network_params.values(True, True))
        self.actor_opt = torch.optim.Adam(self.actor_params, lr=o.lr)
        self.critic_opt = torch.optim.Adam(self.critic_params, lr=o.lr)
        self.lookup = self.actor[0]  # every chain starts with its GraphLookup
        self.updates = 0

    def update(self, batch: TensorDictBase) -> dict[str, float]:
        """One critic update, plus an actor and target update every ``policy_delay`` calls."""
        o = self.config
        batch = self.lookup(batch.to(self.recipe.device))  # restore the static graph keys
        q_loss = critic_loss(self.loss, batch)
        self.critic_opt.zero_grad(set_to_none=True)
        q_loss.backward()
        if o.max_grad_norm > 0:
            torch.nn.utils.clip_grad_norm_(self.critic_params, o.max_grad_norm)
        self.critic_opt.step()
        self.updates += 1
        out = {"loss_critic": q_loss.item()}
        if self.updates % o.policy_delay == 0:
            a_loss = actor_loss(self.loss, batch)
            self.actor_opt.zero_grad(set_to_none=True)
            a_loss.backward()
            if o.max_grad_norm > 0:
                torch.nn.utils.clip_grad_norm_(self.actor_params, o.max_grad_norm)
            self.actor_opt.step()
            self.target_updater.step()
            out["loss_actor"] = a_loss.item()
        return out

    def state_dict(self) -> dict:
        # The robot table is static data, not learnt state: the loss holds (expanded) copies of
        # GraphLookup's buffers, which are left out so a checkpoint loads for any robot set.
        loss_state = {k: v for k, v in self.loss.state_dict().items() if not is_table_key(k)}
        return {
            "loss": loss_state,
            "actor_opt": self.actor_opt.state_dict(),
            "critic_opt": self.critic_opt.state_dict(),
            "updates": self.updates,
        }

    def load_state_dict(self, state: dict) -> None:
        try:
            missing, unexpected = self.loss.load_state_dict(state["loss"], strict=False)
        except RuntimeError as e:  # a tensor of another shape: the recipe's sizes changed
            raise ValueError(f"the checkpoint does not fit the recipe's networks: {e}") from None
        missing = [k for k in missing if not is_table_key(k)]
        if missing or unexpected:
            raise ValueError(
                f"the checkpoint does not fit the recipe's networks: missing {missing[:5]}, "
                f"unexpected {unexpected[:5]}"
            )
        self.actor_opt.load_state_dict(state["actor_opt"])
        self.critic_opt.load_state_dict(state["critic_opt"])
        self.updates = state["updates"]


class UpdateSchedule:
    """When to update and on what: yields the mini-batches of each update phase."""

    def __init__(self, config: TD3Config, num_robots: int):
        self.kind = config.schedule
        self.updates_per_step = config.updates_per_step
        self.pending = np.zeros(num_robots)  # transitions stored since the last update phase
        self.finished = np.zeros(num_robots, dtype=bool)  # robot ended an episode since then

    def add(self, data: TensorDictBase) -> None:
        morph = data["morph_id"]
        self.pending += np.bincount(morph.reshape(-1).numpy(), minlength=len(self.pending))
        self.finished[morph[data["next", "done"].squeeze(-1)].numpy()] = True

    def batches(self, replay, warm: bool):
        if not warm:  # random exploration, or a buffer still smaller than a batch
            self.pending[:] = 0
            return
        if self.kind == "paper" and self.finished.all():
            # each robot in turn, as many updates as it stored transitions, from its own buffer
            for robot, n in enumerate(self.pending):
                for _ in range(round(n * self.updates_per_step)):
                    yield rb.sample_robot(replay, robot)
            self.finished[:] = False
        elif self.kind == "mixed":
            # one padded batch holds batch_size transitions of every robot
            for _ in range(round(self.pending.sum() * self.updates_per_step / len(self.pending))):
                yield rb.sample_mixed(replay)
        else:
            return
        self.pending[:] = 0


class TD3(Algorithm):
    """TD3 behind the run loop: exploration, replay, update schedule, checkpoint state."""

    name = "td3"

    def __init__(self, recipe: Recipe, env: EnvBase, robots: Sequence[Robot]) -> None:
        super().__init__(recipe, env, robots)
        c: TD3Config = self.config
        n = len(self.robots)
        self.learner = TD3Learner(recipe, env)
        capacity = rb.per_robot_capacity(n, c.buffer_size_per_robot, c.buffer_total_size)
        self.replay = rb.make_replay(n, capacity, c.batch_size)
        self.schedule = UpdateSchedule(c, n)
        self.stored = 0

    @property
    def updates(self) -> int:  # the learner counts them
        return self.learner.updates

    @updates.setter
    def updates(self, value: int) -> None:
        if hasattr(self, "learner"):
            self.learner.updates = value

    def _frames_per_batch(self) -> int:
        return self.env.batch_size[0] * self.config.steps_per_batch

    def collect_settings(self, env_steps: int) -> CollectSettings:
        c, device = self.config, self.recipe.device
        explore = TensorDictSequential(
            self.learner.actor,
            AdditiveGaussianModule(
                self.env.full_action_spec[ACTION].to(device),
                sigma_init=c.exploration_noise,
                sigma_end=c.exploration_noise,
                annealing_num_steps=1,
                action_key=ACTION,
            ),
        )
        fpb = self._frames_per_batch()
        random_left = max(0, c.init_random_frames - env_steps)
        random_left = -(-random_left // fpb) * fpb  # whole collector batches
        return CollectSettings(explore, fpb, random_left)

    def process(self, data: TensorDictBase, env_steps: int) -> Iterator[dict[str, float]]:
        c = self.config
        self.stored += rb.store(self.replay, data)
        self.schedule.add(data)
        warm = env_steps >= c.init_random_frames and all(
            len(self.replay[i]) >= c.batch_size for i in range(len(self.robots))
        )
        for batch in self.schedule.batches(self.replay, warm):
            yield self.learner.update(batch)

    def resolved(self) -> dict[str, Any]:
        c, fpb = self.config, self._frames_per_batch()
        return {
            "num_envs": int(self.env.batch_size[0]),
            "frames_per_batch": fpb,
            "init_random_frames": -(-c.init_random_frames // fpb) * fpb,
            "buffer_per_robot": rb.per_robot_capacity(
                len(self.robots), c.buffer_size_per_robot, c.buffer_total_size
            ),
        }

    def state_dict(self) -> dict[str, Any]:
        return self.learner.state_dict()

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.learner.load_state_dict(state)

    def buffers_state(self, directory: Path) -> bool:
        if not self.config.checkpoint_buffers:
            return False
        for i in range(len(self.robots)):
            path = Path(directory) / str(i)
            path.mkdir(parents=True, exist_ok=True)
            self.replay[i].dumps(path)
        return True

    def load_buffers(self, directory: Path) -> None:
        for i in range(len(self.robots)):
            path = Path(directory) / str(i)
            if path.exists():
                self.replay[i].loads(path)

    def policy_state(self) -> dict[str, Any]:
        actor = self.learner.actor.state_dict()
        return {"actor": {k: v for k, v in actor.items() if not is_table_key(k)}}

    @classmethod
    def eval_policy(
        cls, recipe: Recipe, state: dict[str, Any], env: EnvBase, *, deterministic: bool = True
    ):
        actor = make_net(recipe, env, "td3_actor")
        _load_weights(actor, state["actor"])
        actor.eval()
        if deterministic:
            return actor
        return TensorDictSequential(
            actor,
            AdditiveGaussianModule(
                env.full_action_spec[ACTION].to(recipe.device),
                sigma_init=recipe.algo_config.exploration_noise,
                sigma_end=recipe.algo_config.exploration_noise,
                annealing_num_steps=1,
                action_key=ACTION,
            ),
        )


def _load_weights(module: torch.nn.Module, weights: dict) -> None:
    """Load network weights (the robot table is rebuilt, not loaded); a mismatch names itself."""
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
