"""PPO for one policy over many robots, behind the algorithm seam (``gcnt.rl.algorithm``).

Built from torchrl parts: ``ClipPPOLoss`` (ratio clip, value clipped around the old value),
``GAE`` (timeouts bootstrap with V(s): truncation is not termination), a ``ReplayBuffer`` sampled
without replacement for the mini-batches, and the shared run loop's collector. Settings: the
``ppo:`` recipe section (``gcnt.rl.ppo.config``; defaults are the paper's table 4).

One iteration, read top to bottom (:meth:`PPOLearner.learn`):

1. ``num_envs`` envs step ``steps_per_env`` times in lockstep with the policy's sampled actions
   (dropout off unless ``collect_dropout``); as a ``VecNormalize`` wrapper does, every
   observation from the reset on joins the running statistics and is then normalised with them,
   and the update reuses the normalised observations the policy acted on;
2. rewards are divided by the running std of the discounted return (clipped);
3. GAE (gamma, lambda) with the critic, advantages normalised over the iteration;
4. ``epochs`` passes over the data in mini-batches; before each mini-batch step, if
   mean(log pi_old - log pi) of the mini-batch exceeds the method's threshold, the rest of the
   iteration is skipped (KL early stop); Adam with a warm-up + cosine learning rate and
   gradient-norm clipping;
5. the robot sampler updates its probabilities from the finished episodes' lengths (with the
   ``multi`` collector, whose workers normalise with copies of the statistics of the iteration's
   start, the statistics also merge the iteration's observations here; before the first
   iteration they are those of one reset of the training env).

With ``robot_sampling: sampled`` the envs are slots: each takes a robot drawn by
:class:`~gcnt.rl.ppo.robot_sampler.RobotSampler` at every reset (``BatchedMujocoEnv.use_robot_pool``).
"""

from __future__ import annotations

import functools
import logging
import math
import time
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np
import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.data import LazyTensorStorage, ReplayBuffer
from torchrl.data.replay_buffers.samplers import SamplerWithoutReplacement
from torchrl.envs import Compose, EnvBase, RewardSum, StepCounter, TransformedEnv
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

from gcnt.keys import ACTION, HFIELD, LOG_PROB, MASK, MORPH_ID, OBS, VALUE
from gcnt.morphology import Robot
from gcnt.recipes import Recipe, RecipeError
from gcnt.rl.accelerate import autocast, compile_step
from gcnt.rl.algorithm import Algorithm, CollectSettings
from gcnt.rl.device import load_optimizer_state
from gcnt.rl.factories import (
    base_env,
    env_widths,
    load_weights,
    make_batched_env,
    make_net,
    network_weights,
)
from gcnt.rl.ppo.config import PPOConfig
from gcnt.rl.ppo.normalize import ObsNormalizer, RewardScaler
from gcnt.rl.ppo.robot_sampler import RobotDraw, RobotSampler, shared_probs

log = logging.getLogger(__name__)

#: keys a mini-batch needs (the static robot keys are restored from ``morph_id``)
_BATCH_KEYS = (MORPH_ID, OBS, ACTION, LOG_PROB, VALUE, "advantage", "value_target", HFIELD)


#: the normalised observation the collecting policy acted on (kept beside the raw ``limbs/obs``)
SEEN_OBS = ("limbs", "obs_seen")


class NormalizedPolicy(TensorDictModuleBase):
    """``actor`` on normalised ``limbs/obs``; the input TensorDict keeps the raw observation.

    ``track``: the collecting policy, as a ``VecNormalize`` env wrapper (MetaMorph, ModuMorph):
    every observation it is given, from the reset on, first joins the statistics and is then
    normalised with them; the normalised observation is written to :data:`SEEN_OBS`. The same
    observations given twice in a row join once (torchrl's collector asks the policy about the
    reset observations once to learn its output keys, then again for the first step)."""

    def __init__(
        self, norm: ObsNormalizer | None, actor: TensorDictModuleBase, track: bool = False
    ):
        super().__init__()
        self.norm, self.actor, self.track = norm, actor, track and norm is not None
        self.in_keys = list(dict.fromkeys([*actor.in_keys, MASK]))
        self.out_keys = [k for k in actor.out_keys if k != OBS]
        if self.track:
            self.out_keys.append(SEEN_OBS)

    def forward(self, td: TensorDictBase) -> TensorDictBase:
        if self.norm is None:
            return self.actor(td)
        if self.track:
            obs = td.get(OBS)
            last = getattr(self, "_last_obs", None)
            if last is None or last.shape != obs.shape or not torch.equal(last, obs):
                self.norm.update(obs, td.get(MASK))
                self._last_obs = obs.clone()
        sub = td.select(*self.actor.in_keys, strict=False)
        seen = self.norm(td.get(OBS), td.get(MASK))
        sub.set(OBS, seen)
        out = self.actor(sub)
        for key in self.out_keys:
            if key in out.keys(True):
                td.set(key, out.get(key))
        if self.track:
            td.set(SEEN_OBS, seen)
        return td


def lr_factor(iteration: int, total: int, config: PPOConfig) -> float:
    """The learning-rate multiplier of ``iteration`` (0-based) in a run of ``total``: a linear
    warm-up from ``warmup_start`` to 1 over ``warmup_iterations``, times a cosine decay."""
    f = 1.0
    if config.lr_schedule == "cosine":
        f = 0.5 * (1.0 + math.cos(math.pi * min(iteration, total) / max(total, 1)))
    if iteration < config.warmup_iterations:
        w = config.warmup_start
        f *= w + (1.0 - w) * iteration / config.warmup_iterations
    return f


def make_gae(config: PPOConfig, critic: TensorDictModuleBase | None) -> GAE:
    """GAE(gamma, lambda) over a batch [N, T] (time last): ``terminated`` cuts the bootstrap,
    ``done`` the trace, so a time limit (truncated, not terminated) bootstraps with V(s').
    ``critic`` None: the batch carries ``state_value`` and ``("next", "state_value")``."""
    return GAE(
        gamma=config.gamma,
        lmbda=config.gae_lambda,
        value_network=critic,
        average_gae=False,
        # shifted=True (one critic call) is wrong across resets inside a batch in torchrl 0.14:
        # it takes V(s_t) of a new episode's first state from the previous episode's last obs
        shifted=False,
        deactivate_vmap=True,  # the graph lookup checks ids in Python
    )


class PPOLearner:
    """Networks, normalisation, loss, GAE, optimiser and one iteration's update (no env)."""

    def __init__(self, recipe: Recipe, env: EnvBase, iterations: int):
        o: PPOConfig = recipe.algo_config
        self.recipe, self.config, self.iterations = recipe, o, iterations
        self.actor = make_net(recipe, env, "ppo_actor", ppo_std=o.std, ppo_init_std=o.init_std)
        self.critic = make_net(recipe, env, "ppo_critic")
        # dropout off except in the update, unless the method collects with it on
        self.collect_dropout = o.dropout_while_collecting(recipe.network.name)
        self._collection_mode()
        self.loss = ClipPPOLoss(
            self.actor,
            self.critic,
            clip_epsilon=o.clip_epsilon,
            entropy_bonus=True,  # logged; weight entropy_coeff (the paper: 0)
            entropy_coeff=o.entropy_coeff,
            # torchrl's "l2" is (v - R)² with no ½; the originals (MetaMorph, ModuMorph
            # ppo.py) take ½ · max((v - R)², (v_clip - R)²) times VALUE_COEF, so the ½ is here
            critic_coeff=0.5 * o.critic_coeff,
            loss_critic_type="l2",
            normalize_advantage=False,  # done over the whole iteration, below
            clip_value=o.clip_value if o.clip_value > 0 else None,
            functional=False,
        )
        self.gae = make_gae(o, None)  # values computed in chunks (see values)
        self.params = [
            p for net in (self.actor, self.critic) for p in net.parameters() if p.requires_grad
        ]
        self.opt = torch.optim.Adam(self.params, lr=o.lr, eps=o.adam_eps)
        widths = env_widths(env)
        k = base_env(env).max_limbs
        self.obs_norm = (
            ObsNormalizer(k, widths["obs_dim"], o.obs_clip).to(recipe.device)
            if o.obs_norm
            else None
        )
        self.kl_stop = o.kl_threshold(recipe.network.name)
        # compile.compile: the loss forward is compiled (its backward through AOTAutograd); the
        # KL early stop reads its output before the optimiser step, so the step stays eager and
        # compile.cudagraphs is refused for PPO (PPOConfig.check_recipe)
        self.accel = recipe.compile
        self.loss_forward = compile_step(self.loss, self.accel)
        self.iteration = 0
        self.updates = 0

    # ------------------------------------------------------------------ one iteration
    def lr_now(self) -> float:
        return self.config.lr * lr_factor(self.iteration, self.iterations, self.config)

    def normalized(self, data: TensorDictBase) -> TensorDictBase:
        """A shallow copy of ``data`` [N, T] with its (root and next) observations normalised.

        A batch the tracking policy collected keeps the observations it acted on
        (:data:`SEEN_OBS`); a next observation is the following step's, as it was normalised
        then, unless its episode ended there or it is the batch's last (those are normalised
        with the statistics as they are now). Other batches are normalised with the statistics
        as they are now."""
        out = data.clone(False)
        if self.obs_norm is None:
            return out
        nxt = out.get("next").clone(False)
        now = self.obs_norm(data.get(("next", *OBS)), data.get(("next", *MASK)))
        if SEEN_OBS in data.keys(True):
            seen = data.get(SEEN_OBS)
            out.set(OBS, seen)
            done = data.get(("next", "done")).reshape(data.shape)
            follows = torch.zeros_like(done)
            follows[:, :-1] = ~done[:, :-1]
            shifted = torch.cat([seen[:, 1:], seen[:, -1:]], 1)
            cont = follows.reshape(*follows.shape, *([1] * (seen.dim() - follows.dim())))
            nxt.set(OBS, torch.where(cont, shifted, now))
        else:
            out.set(OBS, self.obs_norm(data.get(OBS), data.get(MASK)))
            nxt.set(OBS, now)
        out.set("next", nxt)
        return out

    @torch.no_grad()
    def values(self, data: TensorDictBase) -> None:
        """V(s) and V(s') of a batch [N, T], in chunks of about a mini-batch (one forward over a
        whole iteration would hold every activation at once)."""
        n, t = data.shape
        step = max(1, self.config.minibatch_size // t)
        keys = list(self.critic.in_keys)
        for where in ((), ("next",)):
            src = data.get(where) if where else data
            parts = [
                self.critic(src[i : i + step].select(*keys, strict=False)).get(VALUE)
                for i in range(0, n, step)
            ]
            data.set((*where, VALUE), torch.cat(parts, 0))

    @torch.no_grad()
    def advantages(self, data: TensorDictBase) -> TensorDictBase:
        """GAE on a batch [N, T] (time last) with normalised observations and scaled rewards;
        writes ``advantage`` (normalised over the batch if configured), ``value_target`` and
        ``state_value``."""
        self.values(data)
        self.gae(data)
        if self.config.normalize_advantage:
            adv = data.get("advantage")
            data.set("advantage", (adv - adv.mean()) / (adv.std() + 1e-8))
        return data

    def learn(self, data: TensorDictBase) -> Iterator[dict[str, float]]:
        """One PPO iteration on ``data`` [N, T] (raw observations, scaled rewards); yields one
        loss dict per mini-batch step. At the end the batch's observations join the statistics
        when the collecting policy did not add them as it acted (the ``multi`` collector's
        workers, another policy)."""
        o = self.config
        device = self.recipe.device
        batch = self.advantages(self.normalized(data.to(device)))
        keys = [k for k in _BATCH_KEYS if k in batch.keys(True)]
        flat = batch.select(*keys).reshape(-1)
        n = flat.numel()
        mb = min(o.minibatch_size, n)
        rb = self._buffer(n, mb)
        rb.extend(flat)
        max_norm = o.max_grad_norm if o.max_grad_norm > 0 else float("inf")
        lr = self.lr_now()
        for group in self.opt.param_groups:
            group["lr"] = lr
        self.stopped_at: tuple[int, int] | None = None
        self.last_kl = float("nan")
        self.actor.train()
        self.critic.train()
        try:
            for epoch in range(o.epochs):
                for step in range(n // mb):
                    with autocast(self.accel, device):
                        out = self.loss_forward(rb.sample())
                    kl = float(out["kl_approx"])
                    self.last_kl = kl
                    if self.kl_stop > 0 and kl > self.kl_stop:
                        self.stopped_at = (epoch, step)
                        break
                    total = out["loss_objective"] + out["loss_critic"] + out["loss_entropy"]
                    self.opt.zero_grad(set_to_none=True)
                    total.backward()
                    # the gradient norm is logged; an infinite bound measures without clipping
                    grad = float(torch.nn.utils.clip_grad_norm_(self.params, max_norm))
                    self.opt.step()
                    self.updates += 1
                    yield {
                        "loss_policy": float(out["loss_objective"].detach()),
                        "loss_critic": float(out["loss_critic"].detach()),
                        "approx_kl": kl,
                        "clip_fraction": float(out["clip_fraction"]),
                        "value_clip_fraction": float(out.get("value_clip_fraction", float("nan"))),
                        "explained_variance": float(out["explained_variance"]),
                        "entropy": float(out["entropy"]),
                        "grad_norm": grad,
                    }
                if self.stopped_at is not None:
                    break
        finally:
            self._collection_mode()
        collected_here = SEEN_OBS in data.keys(True) and o.collector == "single"
        if self.obs_norm is not None and not collected_here:
            # collected by worker processes (their own copies of the statistics), or by another
            # policy: the statistics merge the batch here
            self.obs_norm.update(data.get(OBS), data.get(MASK))
        self.iteration += 1

    def _collection_mode(self) -> None:
        """Actor and critic as they collect and value an iteration (see ``collect_dropout``)."""
        self.actor.train(self.collect_dropout)
        self.critic.train(self.collect_dropout)

    def _buffer(self, n: int, mb: int) -> ReplayBuffer:
        """The iteration's data, sampled in mini-batches without replacement (one per learner,
        emptied each iteration)."""
        rb = getattr(self, "_rb", None)
        if rb is None or self._rb_shape != (n, mb):
            rb = self._rb = ReplayBuffer(
                storage=LazyTensorStorage(n, device=self.recipe.device),
                sampler=SamplerWithoutReplacement(drop_last=True),
                batch_size=mb,
            )
            self._rb_shape = (n, mb)
        else:
            rb.empty()
        return rb

    # ------------------------------------------------------------------ state
    def state_dict(self) -> dict:
        return {
            "actor": network_weights(self.actor),
            "critic": network_weights(self.critic),
            "opt": self.opt.state_dict(),
            "obs_norm": None if self.obs_norm is None else self.obs_norm.state_dict(),
            "iteration": self.iteration,
            "updates": self.updates,
        }

    def load_networks(self, state: dict) -> None:
        """The actor's and critic's weights from a :meth:`state_dict` (optimiser, statistics
        and counters left as they are); a ValueError names the network that does not fit."""
        for key in ("actor", "critic"):
            try:
                load_weights(getattr(self, key), state[key])
            except ValueError as e:
                raise ValueError(f"PPO {key}: {e}") from None

    def start_obs_norm(self, state: dict | None) -> None:
        """Another run's observation statistics (:meth:`ObsNormalizer.state_dict`), counts
        included, fitted to this run's limb slots (``ObsNormalizer.for_limbs``)."""
        if (state is None) != (self.obs_norm is None):
            raise ValueError(
                f"that run has ppo.obs_norm={state is not None}, this recipe has "
                f"ppo.obs_norm={self.obs_norm is not None}"
            )
        if state is None:
            return
        k, f = state["mean"].shape
        if f != self.obs_norm.mean.shape[1]:
            raise ValueError(
                f"observation statistics of {f} features per limb in that run, "
                f"{self.obs_norm.mean.shape[1]} in this run's observations"
            )
        trained = ObsNormalizer(k, f)
        trained.load_state_dict(state)
        self.obs_norm.load_state_dict(trained.for_limbs(self.obs_norm.mean.shape[0]).state_dict())

    def load_state_dict(self, state: dict) -> None:
        self.load_networks(state)
        load_optimizer_state(self.opt, state["opt"])
        if self.obs_norm is not None and state.get("obs_norm") is not None:
            self.obs_norm.load_state_dict(state["obs_norm"])
        self.iteration = state["iteration"]
        self.updates = state["updates"]


def finished_episodes(data: TensorDictBase) -> tuple[np.ndarray, np.ndarray]:
    """``(robot ids, lengths)`` of the episodes that ended in ``data`` [N, T], in time order;
    the lengths are torchrl's ``StepCounter`` count at the last step."""
    done = data.get(("next", "done")).reshape(data.shape).cpu().numpy()
    count = data.get(("next", "step_count")).reshape(data.shape).cpu().numpy()
    morph = data.get(MORPH_ID).reshape(data.shape).cpu().numpy()
    done_t, done_n = np.nonzero(done.T)  # time-major, as the episodes ended
    return morph[done_n, done_t], count[done_n, done_t].astype(np.int64)


def make_slot_env(
    recipe: Recipe,
    robots: Sequence[Robot],
    num_envs: int,
    *,
    draw: RobotDraw | None,
    seed: int,
    num_threads: int | None = None,
) -> TransformedEnv:
    """``num_envs`` envs over the run's ``robots``: with ``draw``, slots that take a robot drawn
    at every reset (``morph_id`` = index in ``robots``); without, ``num_envs / len(robots)``
    copies of each robot. Episode returns (``RewardSum``) and lengths (``StepCounter``) are
    tracked."""
    r = len(robots)
    k = recipe.env.max_limbs or max(x.num_limbs for x in robots)
    if draw is None:
        if num_envs % r:
            raise RecipeError(
                f"ppo.robot_sampling: fixed needs ppo.num_envs ({num_envs}) to be a multiple of "
                f"the {r} training robots; use robot_sampling: sampled"
            )
        ids = [i for i in range(r) for _ in range(num_envs // r)]
    else:
        ids = [i % r for i in range(num_envs)]
    env = make_batched_env(
        recipe, [robots[i] for i in ids], ids, seed=seed, max_limbs=k, num_threads=num_threads
    )
    if draw is not None:
        env.use_robot_pool(robots, draw)
    return TransformedEnv(env, Compose(RewardSum(), StepCounter()))


def make_worker_env(torch_seed: int, *args, **kwargs) -> TransformedEnv:
    """:func:`make_slot_env` in a collector's worker process, whose own random state (the
    policy's action noise there) starts from ``torch_seed``: a run is repeated exactly for a
    seed and a number of workers."""
    torch.manual_seed(torch_seed)
    return make_slot_env(*args, **kwargs)


class PPO(Algorithm):
    """PPO behind the run loop: slot envs and robot sampling, normalisation, iterations."""

    name = "ppo"

    @classmethod
    def make_train_env(cls, recipe: Recipe, robots: Sequence[Robot]) -> EnvBase:
        o: PPOConfig = recipe.algo_config
        draw = None
        if o.robot_sampling == "sampled":
            draw = RobotDraw(shared_probs(len(robots)), seed=recipe.seed + 1)
        return make_slot_env(recipe, robots, o.num_envs, draw=draw, seed=recipe.seed)

    def __init__(self, recipe: Recipe, env: EnvBase, robots: Sequence[Robot]) -> None:
        super().__init__(recipe, env, robots)
        o: PPOConfig = self.config
        if env.batch_size[0] != o.num_envs:
            raise RecipeError(
                f"ppo: the training env has {env.batch_size[0]} envs, ppo.num_envs is "
                f"{o.num_envs} (build it with PPO.make_train_env)"
            )
        self.frames_per_batch = o.num_envs * o.steps_per_env
        self.iterations = max(1, -(-recipe.collector.total_frames // self.frames_per_batch))
        self.minibatches_per_epoch = self.frames_per_batch // min(
            o.minibatch_size, self.frames_per_batch
        )
        self.learner = PPOLearner(recipe, env, self.iterations)
        draw = base_env(env).robot_pool_sampler
        self.draw: RobotDraw | None = draw if isinstance(draw, RobotDraw) else None
        self.sampler = RobotSampler(
            len(self.robots),
            uniform_iterations=o.uniform_iterations,
            warmup_episodes=o.ema_warmup_episodes,
            alpha=o.ema_alpha,
            probs=None if self.draw is None else self.draw.probs,  # the env reads these
        )
        self.scaler = (
            RewardScaler(self.collected_envs, o.gamma, o.reward_clip) if o.reward_scaling else None
        )
        self._extras: dict[str, float] = {}
        self._t_end: float | None = None

    @property
    def worker_envs(self) -> int:
        """Envs per ``multi`` collector worker (``ppo.worker_envs``, or num_envs / workers)."""
        o: PPOConfig = self.config
        return o.worker_envs or o.num_envs // o.workers

    @property
    def collected_envs(self) -> int:
        """The envs whose trajectories an iteration's batch holds: num_envs, or with the
        ``multi`` collector workers x :attr:`worker_envs` (the workers' batches stacked)."""
        o: PPOConfig = self.config
        return o.workers * self.worker_envs if o.collector == "multi" else o.num_envs

    @property
    def updates(self) -> int:  # the learner counts them
        return self.learner.updates

    # ------------------------------------------------------------------ collection and learning
    def policy(self) -> NormalizedPolicy:
        """The collecting policy: with the single collector its observations join the statistics
        as it acts; the ``multi`` collector's workers normalise with the statistics of the
        iteration's start (a worker's own updates would depend on how the envs are split over
        workers), which then merge the iteration's batch."""
        single = self.config.collector == "single"
        return NormalizedPolicy(self.learner.obs_norm, self.learner.actor, track=single)

    def collect_settings(self, env_steps: int) -> CollectSettings:
        o: PPOConfig = self.config
        makers = None
        if o.collector == "multi":
            per = self.worker_envs
            sampled = o.robot_sampling == "sampled"
            makers = [
                functools.partial(
                    make_worker_env,
                    self.recipe.seed + 1000 * (w + 1) + 7,
                    self.recipe,
                    self.robots,
                    per,
                    draw=self.sampler.drawer(self.recipe.seed + 1 + 1000 * (w + 1))
                    if sampled
                    else None,
                    seed=self.recipe.seed + 1000 * (w + 1),
                    num_threads=1,
                )
                for w in range(o.workers)
            ]
            log.info(
                "ppo.collector=multi: %d worker processes; the run repeats for its seed and "
                "ppo.workers (another worker count draws other random streams)",
                o.workers,
            )
            if not sampled and per % len(self.robots):
                raise RecipeError(
                    f"ppo.collector: multi with fixed robots needs its envs per worker ({per}) to "
                    f"be a multiple of the {len(self.robots)} robots"
                )
            self._statistics_from_a_reset()
        return CollectSettings(self.policy(), self.frames_per_batch, 0, env_makers=makers)

    def _statistics_from_a_reset(self) -> None:
        """Before the ``multi`` collector's first iteration, whose workers normalise with the
        statistics of the iteration's start: a reset of the training env joins the statistics,
        so that the first iteration is normalised as every later one is (the single collector
        gets there by letting the reset observations join as it acts)."""
        norm = self.learner.obs_norm
        if norm is None or bool((norm.count > 1.0).any()):  # seen observations already
            return
        reset = self.env.reset()
        norm.update(reset.get(OBS).to(norm.mean.device), reset.get(MASK).to(norm.mean.device))

    def process(self, data: TensorDictBase, env_steps: int) -> Iterator[dict[str, float]]:
        o: PPOConfig = self.config
        t0 = time.perf_counter()
        collect_s = t0 - self._t_end if self._t_end is not None else float("nan")
        # [N, T]; a multi-process collector stacks its workers' envs
        data = data.reshape(self.collected_envs, -1)
        robots, lengths = finished_episodes(data)
        self.sampler.add_episodes(robots, lengths)
        if self.scaler is not None:
            data = data.clone(False)
            nxt = data.get("next").clone(False)
            nxt.set("reward", self.scaler(nxt.get("reward"), nxt.get("done")))
            data.set("next", nxt)
        lr = self.learner.lr_now()
        yield from self.learner.learn(data)
        self.sampler.end_iteration()
        update_s = time.perf_counter() - t0
        stop = self.learner.stopped_at
        self._extras = {
            "lr": lr,
            "iteration": self.learner.iteration,
            "kl_last": self.learner.last_kl,
            "kl_stopped": float(stop is not None),
            "epochs_done": (stop[0] + stop[1] / self.minibatches_per_epoch)
            if stop
            else float(o.epochs),
            "update_s": update_s,
            "collect_env_steps_per_s": data.numel() / collect_s if collect_s > 0 else float("nan"),
            "reward_scale_std": self.scaler.std if self.scaler is not None else 1.0,
            **self.sampler.stats(),
        }
        self._t_end = time.perf_counter()

    def log_extras(self) -> dict[str, float]:
        out, self._extras = self._extras, {}
        return out

    def resolved(self) -> dict[str, Any]:
        o: PPOConfig = self.config
        return {
            "num_envs": o.num_envs,
            "collected_envs": self.collected_envs,
            "frames_per_batch": self.frames_per_batch,
            "iterations": self.iterations,
            "minibatches_per_epoch": self.minibatches_per_epoch,
            "kl_stop": self.learner.kl_stop,
        }

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict[str, Any]:
        return {
            "learner": self.learner.state_dict(),
            "sampler": self.sampler.state_dict(),
            "draw_rng": None if self.draw is None else self.draw.rng.bit_generator.state,
            "reward_scaler": None if self.scaler is None else self.scaler.state_dict(),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.learner.load_state_dict(state["learner"])
        self.sampler.load_state_dict(state["sampler"])
        if self.draw is not None and state.get("draw_rng") is not None:
            self.draw.rng.bit_generator.state = state["draw_rng"]
        if self.scaler is not None and state.get("reward_scaler") is not None:
            self.scaler.load_state_dict(state["reward_scaler"])

    def start_from(self, state: dict[str, Any]) -> None:
        # actor, critic and observation statistics; Adam, lr schedule, sampler, scaler fresh
        self.learner.load_networks(state["learner"])
        self.learner.start_obs_norm(state["learner"].get("obs_norm"))

    # ------------------------------------------------------------------ evaluation
    def policy_state(self) -> dict[str, Any]:
        norm = self.learner.obs_norm
        return {
            "actor": network_weights(self.learner.actor),
            "obs_norm": None if norm is None else norm.state_dict(),
        }

    @classmethod
    def eval_policy(
        cls, recipe: Recipe, state: dict[str, Any], env: EnvBase, *, deterministic: bool = True
    ) -> TensorDictModuleBase:
        """The actor with frozen observation statistics; sampled actions unless
        ``deterministic`` (the caller's exploration type picks mean or sample)."""
        o: PPOConfig = recipe.algo_config
        actor = make_net(recipe, env, "ppo_actor", ppo_std=o.std, ppo_init_std=o.init_std)
        load_weights(actor, state["actor"])
        actor.eval()
        norm = None
        if state.get("obs_norm") is not None:
            k, f = state["obs_norm"]["mean"].shape
            trained = ObsNormalizer(k, f)
            trained.load_state_dict(state["obs_norm"])
            norm = trained.for_limbs(base_env(env).max_limbs).to(recipe.device)
            norm.clip = o.obs_clip
        return NormalizedPolicy(norm, actor).eval()
