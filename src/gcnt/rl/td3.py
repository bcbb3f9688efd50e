"""TD3 on SMPENV: one policy for many robots, read top to bottom.

Built from torchrl parts: the batched ``SMPEnv`` stepped by a ``Collector``, per-robot replay
buffers (``ReplayBufferEnsemble`` routed by ``morph_id``), ``TD3Loss`` with per-limb twin critics
(see ``td3_loss``), ``SoftUpdate`` targets and Gaussian exploration (``AdditiveGaussianModule``).

Two update schedules (``collector.schedule``):

* ``paper``: robots step in lockstep until every robot has finished an episode; then each robot in
  turn gets as many updates as it stored transitions, each from its own buffer.
* ``mixed``: every ``steps_per_batch`` lockstep steps, updates on padded mini-batches that hold
  ``batch_size`` transitions of every robot: the same samples per stored step as ``paper``, in
  one forward pass per update instead of one per robot.

Every stored environment step is counted (``env_steps``), over all robots.
"""

from __future__ import annotations

import logging
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictSequential
from torchrl.collectors import Collector
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import AdditiveGaussianModule
from torchrl.objectives import SoftUpdate
from tqdm import tqdm
from tqdm.contrib.logging import logging_redirect_tqdm

from gcnt.nn.graph_lookup import is_table_key
from gcnt.nn.keys import ACTION
from gcnt.recipes import Recipe
from gcnt.rl import replay as rb
from gcnt.rl.evaluate import evaluate, write_eval
from gcnt.rl.factories import make_env, make_net, train_robots
from gcnt.rl.run_dir import RunDir, make_logger, seed_everything, set_rng_state
from gcnt.rl.td3_loss import actor_loss, critic_loss, make_td3_loss

log = logging.getLogger(__name__)


class TD3Learner:
    """Networks, loss, optimisers and the update step; no env, no buffer (benchmarkable alone)."""

    def __init__(self, recipe: Recipe, table: TensorDictBase):
        o = recipe.optim
        self.recipe = recipe
        self.actor = make_net(recipe, table, "td3_actor")
        # two independently initialised critics (given one, TD3Loss re-draws the twin's weights
        # uniformly between each tensor's min and max, losing the layers' own init schemes)
        self.critics = [make_net(recipe, table, "td3_critic") for _ in range(2)]
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
        o = self.recipe.optim
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
        missing, unexpected = self.loss.load_state_dict(state["loss"], strict=False)
        missing = [k for k in missing if not is_table_key(k)]
        if missing or unexpected:
            raise KeyError(
                f"checkpoint does not fit the networks: missing {missing}, unexpected {unexpected}"
            )
        self.actor_opt.load_state_dict(state["actor_opt"])
        self.critic_opt.load_state_dict(state["critic_opt"])
        self.updates = state["updates"]


class UpdateSchedule:
    """When to update and on what: yields the mini-batches of each update phase."""

    def __init__(self, recipe: Recipe, num_robots: int):
        self.kind = recipe.collector.schedule
        self.updates_per_step = recipe.optim.updates_per_step
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


class TrainStats:
    """Episode returns per robot, losses and rates between two log lines."""

    def __init__(self, names: list[str], env_steps: int, updates: int):
        self.names = names
        self.returns: dict[int, list[float]] = defaultdict(list)
        self.losses: dict[str, list[float]] = defaultdict(list)
        self.t, self.env_steps, self.updates = time.perf_counter(), env_steps, updates

    def add_episodes(self, data: TensorDictBase) -> None:
        done = data["next", "done"].squeeze(-1)
        robots = data["morph_id"][done].tolist()
        rets = data["next", "episode_reward"].squeeze(-1)[done].tolist()
        for robot, ret in zip(robots, rets, strict=True):
            self.returns[robot].append(ret)

    def add_losses(self, losses: dict[str, float]) -> None:
        for k, v in losses.items():
            self.losses[k].append(v)

    def row(self, env_steps: int, updates: int) -> dict:
        now = time.perf_counter()
        row = {
            "env_steps": env_steps,
            "updates": updates,
            "env_steps_per_s": (env_steps - self.env_steps) / (now - self.t),
            "updates_per_s": (updates - self.updates) / (now - self.t),
            **{k: float(np.mean(v)) for k, v in self.losses.items()},
        }
        per_robot = {
            f"train_return/{self.names[k]}": float(np.mean(v)) for k, v in self.returns.items()
        }
        if per_robot:
            row["train_return/mean"] = float(np.mean(list(per_robot.values())))
        row.update(per_robot)
        self.returns.clear()
        self.losses.clear()
        self.t, self.env_steps, self.updates = now, env_steps, updates
        return row


def train(recipe: Recipe, run: RunDir, *, resume: bool = False) -> RunDir:
    """Train per ``recipe`` into ``run`` (continuing its checkpoint when ``resume``)."""
    c, r = recipe.collector, recipe.replay_buffer
    seed_everything(recipe.seed)
    robots = train_robots(recipe)
    num_robots = len(robots)
    env = make_env(recipe, robots, copies=recipe.env.copies)
    learner = TD3Learner(recipe, env.base_env.table)
    replay = rb.make_replay(
        num_robots, rb.per_robot_capacity(num_robots, r.size_per_robot, r.total_size), r.batch_size
    )

    env_steps = 0
    if resume:
        state = run.load_checkpoint(map_location=recipe.device)
        learner.load_state_dict(state["learner"])
        env_steps = state["env_steps"]
        set_rng_state(state["rng"])
        buffers = run.path / "checkpoints" / "replay"
        if state.get("has_buffers") and buffers.exists():
            for i in range(num_robots):
                replay[i].loads(buffers / str(i))
        run.truncate_metrics(env_steps)
        log.info("resuming %s at %d env steps, %d updates", run.path, env_steps, learner.updates)
        env.set_seed(recipe.seed + env_steps)  # fresh episodes, a seed that differs per resume
    next_log = _next_multiple(env_steps, recipe.logger.log_interval)
    next_ckpt = _next_multiple(env_steps, recipe.checkpoint_interval)
    next_eval = _next_multiple(env_steps, recipe.eval.interval) if recipe.eval.interval else None

    explore = TensorDictSequential(
        learner.actor,
        AdditiveGaussianModule(
            env.full_action_spec[ACTION].to(recipe.device),
            sigma_init=c.exploration_noise,
            sigma_end=c.exploration_noise,
            annealing_num_steps=1,
            action_key=ACTION,
        ),
    )
    num_envs = env.batch_size[0]
    frames_per_batch = num_envs * c.steps_per_batch
    random_left = max(0, c.init_random_frames - env_steps)
    random_left = -(-random_left // frames_per_batch) * frames_per_batch  # whole collector batches
    collector = Collector(
        env,
        explore,
        frames_per_batch=frames_per_batch,
        total_frames=-1,
        init_random_frames=random_left,
        policy_device=recipe.device,  # networks on the recipe's device, MuJoCo on the CPU
        env_device="cpu",
        storing_device="cpu",
        auto_register_policy_transforms=False,  # the policy needs no InitTracker
    )
    logger = make_logger(recipe, run)

    schedule = UpdateSchedule(recipe, num_robots)
    stats = TrainStats([robot.name for robot in robots], env_steps, learner.updates)
    bar = tqdm(
        total=c.total_frames, initial=env_steps, unit="step", disable=not recipe.logger.progress
    )
    # log lines go above the progress bar instead of through it
    with logging_redirect_tqdm(loggers=[logging.getLogger("gcnt")]):
        try:
            for data in collector:
                env_steps += rb.store(replay, data)
                bar.update(data.numel())
                stats.add_episodes(data)
                schedule.add(data)
                warm = env_steps >= c.init_random_frames and all(
                    len(replay[i]) >= r.batch_size for i in range(num_robots)
                )
                for batch in schedule.batches(replay, warm):
                    stats.add_losses(learner.update(batch))

                last = env_steps >= c.total_frames
                if env_steps >= next_log or last:
                    row = stats.row(env_steps, learner.updates)
                    _log_row(run, logger, row)
                    bar.set_postfix(ret=f"{row.get('train_return/mean', float('nan')):.1f}")
                    next_log = _next_multiple(env_steps, recipe.logger.log_interval)
                if env_steps >= next_ckpt or last:
                    _checkpoint(
                        run, learner, replay, env_steps, num_robots, recipe.checkpoint_buffers
                    )
                    next_ckpt = _next_multiple(env_steps, recipe.checkpoint_interval)
                if next_eval is not None and env_steps >= next_eval and not last:
                    _evaluate(recipe, run, learner, logger, env_steps, video=recipe.eval.video)
                    next_eval = _next_multiple(env_steps, recipe.eval.interval)
                if last:
                    break
        finally:
            bar.close()
            collector.shutdown()
    _evaluate(recipe, run, learner, logger, env_steps, video=recipe.eval.video)
    if (
        logger is not None
        and hasattr(logger, "experiment")
        and hasattr(logger.experiment, "finish")
    ):
        logger.experiment.finish()
    return run


def _next_multiple(x: int, every: int) -> int:
    return (x // every + 1) * every if every > 0 else 2**62


def _log_row(run: RunDir, logger, row: dict) -> None:
    run.log_metrics(row)
    if logger is not None:
        for k, v in row.items():
            if k != "env_steps":
                logger.log_scalar(k, v, step=row["env_steps"])
    log.info(
        "env_steps %d  updates %d  return %.1f  %.0f steps/s",
        row["env_steps"],
        row["updates"],
        row.get("train_return/mean", float("nan")),
        row["env_steps_per_s"],
    )


def _checkpoint(run: RunDir, learner, replay, env_steps: int, num_robots: int, buffers: bool):
    if buffers:
        for i in range(num_robots):
            replay[i].dumps(run.path / "checkpoints" / "replay" / str(i))
    run.save_checkpoint(
        {
            "learner": learner.state_dict(),
            "actor": learner.actor.state_dict(),  # for `gcnt eval` without rebuilding the loss
            "env_steps": env_steps,
            "has_buffers": buffers,
        }
    )


def _evaluate(
    recipe: Recipe, run: RunDir, learner: TD3Learner, logger, env_steps: int, video: bool
):
    specs = recipe.eval.robots or [*recipe.env.robots, *recipe.env.test_robots]
    if recipe.eval.episodes <= 0 or not specs:
        return
    results = evaluate(recipe, learner.actor.state_dict(), specs, episodes=recipe.eval.episodes)
    path = write_eval(run.path / "eval" / f"step{env_steps}.json", results, env_steps)
    if logger is not None:
        for name, res in results.items():
            logger.log_scalar(f"eval_return/{name}", res["mean"], step=env_steps)
    log.info("eval at %d steps written to %s", env_steps, Path(path))
    if video:
        _render(recipe, run, learner, env_steps)


@torch.no_grad()
def _render(recipe: Recipe, run: RunDir, learner: TD3Learner, env_steps: int) -> None:
    """A video of the deterministic policy on the first training robot (morph_id 0)."""
    from gcnt.envs import SMPEnv
    from gcnt.envs.render import render_rollout

    robot = train_robots(recipe)[0]
    k = learner.lookup.num_limbs  # pad like the policy's robot table
    env = SMPEnv([robot], max_limbs=k, seed=recipe.seed, num_threads=1)
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        out = render_rollout(
            env, learner.actor, steps=300, path=run.path / "videos" / f"step{env_steps}.mp4"
        )
    env.close()
    log.info("video of %s written to %s", robot.name, out)
