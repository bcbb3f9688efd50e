"""TD3 for one policy over many robots, behind the algorithm seam (:mod:`gcnt.rl.algorithm`).

One update, in the order the code runs (the run loop, :func:`gcnt.rl.loop.train`, hands each
collected batch to :meth:`TD3.process`):

1. **store** (:meth:`TD3.store`): the batch goes into the per-robot replay rings, one
   [robots, capacity] storage (:class:`~gcnt.rl.td3.replay.RobotReplay`), and the
   :class:`UpdateSchedule` counts what each robot stored;
2. **sample** (:meth:`UpdateSchedule.batches`): the schedule yields the phase's mini-batches,
   ``RobotReplay.sample_mixed`` (``mixed``) or ``sample_robot`` (``paper``), one index draw each;
3. **target** (:meth:`TD3Learner.critic_loss`): the robot-only stages run once per robot
   (:class:`~gcnt.rl.td3.tensor_chain.TensorChain`); the target actor's action plus clipped noise
   (:func:`~gcnt.rl.td3.loss.smoothed_target_action`), the target critics' per-limb Q' and the
   TD target (:func:`~gcnt.rl.td3.loss.td_target`; per limb by default, as the AMORPHEUS/SWAT
   code: ``td3.target``);
4. **critic step** (:meth:`TD3Learner._critic_step`): both critics' errors
   (:func:`~gcnt.rl.td3.loss.critic_error`) from the critic ensemble
   (:class:`~gcnt.rl.td3.ensemble.Ensemble`: the two critics' parameters stacked; the two
   target critics likewise), evaluated under one vmap with one backward, or, on a CPU with 2 to
   4 cores, one member per thread, each with its own backward (:mod:`~gcnt.rl.td3.twin`,
   ``compile.twin_threads``), or the second member in a helper process
   (:mod:`~gcnt.rl.td3.twin_process`, ``compile.twin_processes``); then :func:`apply_gradients` (clip → Adam step → zero_grad; one
   fused Adam over the stacked parameters);
5. **delayed actor and target step** (:func:`delayed_update`, every ``policy_delay`` critic
   steps, :meth:`TD3Learner._actor_step`): -Q1 of the actor's action
   (:func:`~gcnt.rl.td3.loss.deterministic_actor_loss`), gradients for the actor only,
   :func:`apply_gradients`, then :func:`soft_update` of all target networks by ``tau`` (one
   foreach lerp).

Steps 4 and 5 are the two functions the ``compile:`` recipe section may compile or capture
(:mod:`gcnt.rl.accelerate`). Exploration is the actor plus Gaussian noise, clipped to the
action bounds (:class:`~gcnt.rl.td3.exploration.GaussianExploration`). Settings: the ``td3:`` recipe section (:mod:`gcnt.rl.td3.config`).
Several seeds in one process: :mod:`gcnt.rl.td3.stacked` (the same steps under one vmap).

Two update schedules (``td3.schedule``):

* ``paper``: robots step in lockstep until every robot has finished an episode; then each robot in
  turn gets as many updates as it stored transitions, each from its own ring.
* ``mixed``: every ``steps_per_batch`` lockstep steps, updates on padded mini-batches that hold
  ``batch_size`` transitions of every robot: the same samples per stored step as ``paper``, in
  one forward pass per update instead of one per robot.

Every stored environment step is counted, over all robots.
"""

from __future__ import annotations

import copy
import dataclasses
import logging
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictSequential
from torchrl.envs import EnvBase

from gcnt import keys as K
from gcnt.envs.stepper import usable_cpus
from gcnt.keys import ACTION, HFIELD, LIMB_Q, MASK, MORPH_ID, OBS
from gcnt.morphology import Robot
from gcnt.nn.layers import as_dtype
from gcnt.nn.registry import NETWORKS
from gcnt.recipes import Recipe, RecipeError
from gcnt.rl.accelerate import (
    accelerate,
    autocast,
    begin_step,
    choose_compile,
    compile_step,
    optimizer_kwargs,
    owned,
    timed_first_call,
)
from gcnt.rl.algorithm import Algorithm, CollectSettings
from gcnt.rl.config_check import check_replay_memory
from gcnt.rl.device import load_optimizer_state
from gcnt.rl.factories import load_weights, make_net, network_weights
from gcnt.rl.td3 import replay as rb
from gcnt.rl.td3.config import TD3Config, target_rule
from gcnt.rl.td3.ensemble import Ensemble, is_members_layout, stack_members
from gcnt.rl.td3.exploration import GaussianExploration
from gcnt.rl.td3.loss import (
    critic_error,
    deterministic_actor_loss,
    smoothed_target_action,
    target_noise,
    td_target,
)
from gcnt.rl.td3.tensor_chain import RobotBatch, TensorChain, TensorChainModule, has_dropout
from gcnt.rl.td3.twin import InTurn, make_pair_runner

log = logging.getLogger(__name__)


class TD3Learner:
    """Networks, optimisers and the update steps; no env, no buffer (benchmarkable alone).

    The actor and the two critics are the method's TensorDict chains (the critics as one
    :class:`~gcnt.rl.td3.ensemble.Ensemble`); the update calls the same modules on plain tensors
    (:class:`TensorChain`), with robot-only stages computed once per robot, and the collector
    runs the actor the same way (:class:`TensorChainModule`). Targets are copies of the online
    networks, moved towards them by ``tau`` after each actor update. Two steps with static
    shapes, so each can be compiled and captured (``compile:`` recipe section,
    :mod:`gcnt.rl.accelerate`): the critic step, and the actor + target step that runs every
    ``policy_delay`` critic steps.
    """

    def __init__(
        self,
        recipe: Recipe,
        env: EnvBase,
        *,
        pair: bool = False,
        twin_threads: bool | None = None,
    ):
        o: TD3Config = recipe.algo_config
        self.recipe, self.config, self.accel = recipe, o, recipe.compile
        self.device = torch.device(recipe.device)
        #: the TD target rule (``td3.target``, resolved for the network)
        self.rule = target_rule(o, recipe.network.name)
        self.actor = make_net(recipe, env, "td3_actor")
        # two independently initialised critics (each layer keeps its own init scheme), as one
        # ensemble (``pair``: as two networks run in turn, the previous layout, kept to compare)
        critics = [make_net(recipe, env, "td3_critic") for _ in range(2)]
        self.pair = pair
        self.critics = (
            torch.nn.ModuleList(critics) if pair else Ensemble(critics, recipe.network.name)
        )
        self.target_actor = copy.deepcopy(self.actor).requires_grad_(False)
        self.target_critics = copy.deepcopy(self.critics).requires_grad_(False)
        self._chains()
        self.actor_params = list(self.actor.parameters())
        self.critic_params = list(self.critics.parameters())
        self._online = self.actor_params + self.critic_params
        self._target = list(self.target_actor.parameters()) + list(self.target_critics.parameters())
        opt_kw = optimizer_kwargs(self.accel, self.device)
        self.actor_opt = torch.optim.Adam(self.actor_params, lr=o.lr, **opt_kw)
        self.critic_opt = torch.optim.Adam(self.critic_params, lr=o.lr, **opt_kw)
        #: how the twin (target) critics run: in one call of the ensemble (or in turn, ``pair``),
        #: or one member per thread (``compile.twin_threads``; ``twin_threads`` overrides it)
        self.twin = make_pair_runner(
            self.accel.twin_threads if twin_threads is None else twin_threads,
            self.device,
            compiled=self.accel.compile is True or self.accel.cudagraphs,
            dropout=has_dropout(critics[0]),
            torch_threads=self.accel.torch_threads,
            processes=self.accel.twin_processes and not pair,
        )
        # compile.compile: each step's loss forward as one graph (no graph break), its backward
        # through AOTAutograd; the optimiser tail runs eagerly
        self.critic_forward = compile_step(
            self._critic_forward, self.accel, fullgraph=True, name="TD3 critic loss"
        )
        self.actor_forward = compile_step(
            self.actor_loss, self.accel, fullgraph=True, name="TD3 actor loss"
        )
        if not pair:
            self.critics.views()  # built before any compiled call reads them
        self.critic_step = timed_first_call(
            accelerate(self._critic_step, self.accel, self.device), self.accel, "TD3 critic step"
        )
        self.actor_step = timed_first_call(
            accelerate(self._actor_step, self.accel, self.device), self.accel, "TD3 actor step"
        )
        self.updates = 0

    def _chains(self) -> None:
        """The plain-tensor calls of the networks."""
        self.f_actor = TensorChain(self.actor)
        self.f_target_actor = TensorChain(self.target_actor)
        if self.pair:
            self.f_critics = [TensorChain(c) for c in self.critics]
            self.f_target_critics = [TensorChain(c) for c in self.target_critics]

    #: the four networks of a learner, by attribute
    NETWORKS = ("actor", "critics", "target_actor", "target_critics")

    def loss_shell(self) -> TD3Learner:
        """A learner with copies of this one's networks and settings, and no optimiser or
        step: its :meth:`critic_loss` and :meth:`actor_loss` run with whatever parameters are
        swapped into its networks (``gcnt.rl.td3.stacked`` swaps each seed's in, leaving the seeds'
        own modules untouched)."""
        shell = self._shell(copy.deepcopy)
        shell.twin = InTurn()  # vmapped by the stacked learner: no threads inside
        return shell

    def process_shell(self) -> TD3Learner:
        """A learner holding this one's networks themselves (not copies) and settings, and no
        optimiser or step: what the twin critics' helper process runs the losses of
        (:mod:`gcnt.rl.td3.twin_process`), on parameters shared with this process."""
        shell = self._shell(lambda net: net)
        shell.actor_params, shell.critic_params = self.actor_params, self.critic_params
        shell.actor_forward = shell.actor_loss
        return shell

    def _shell(self, take: Callable[[torch.nn.Module], torch.nn.Module]) -> TD3Learner:
        """A learner with this one's settings and ``take`` of each of its networks."""
        shell = object.__new__(type(self))
        shell.recipe, shell.config, shell.accel = self.recipe, self.config, self.accel
        shell.rule, shell.pair, shell.device = self.rule, self.pair, self.device
        for name in self.NETWORKS:
            setattr(shell, name, take(getattr(self, name)))
        if not shell.pair:
            shell.critics.views()
        shell._chains()
        shell.updates = self.updates
        return shell

    def shared_tensors(self) -> list[torch.Tensor]:
        """Every parameter and buffer of the four networks (what a helper process reads)."""
        nets = [getattr(self, name) for name in self.NETWORKS]
        return [t for n in nets for t in (*n.parameters(), *n.buffers())]

    def _twin(
        self,
        critics: torch.nn.Module,
        inputs: dict,
        robots,
        then: Callable[[dict], torch.Tensor],
        backward: bool = False,
    ) -> torch.Tensor:
        """``then`` of both critics' chain outputs on ``inputs``, stacked [2, ...]: one vmapped
        call of the ensemble, or each member on its own thread (:attr:`twin`); ``pair``: the
        two networks in turn or on two threads. ``backward`` (with threads): each critic's
        result backpropagated on its thread, and returned detached."""

        def each(out: torch.Tensor) -> torch.Tensor:
            if not backward:
                return out
            out.backward()
            return out.detach()

        if self.pair:
            chains = self.f_critics if critics is self.critics else self.f_target_critics
            return torch.stack(self.twin.map(lambda f: each(then(f(inputs, robots))), chains))
        if not self.twin.parallel:
            return critics(inputs, robots, then)
        fixed = critics is self.target_critics  # no gradient: slices kept between calls
        return torch.stack(
            self.twin.map(
                lambda i: critics.one(i, inputs, robots, then, fixed=fixed, backward=backward),
                range(critics.size),
            )
        )

    def _robots(self, ids: torch.Tensor, batch: TensorDictBase):
        """The batch's :class:`~gcnt.rl.td3.tensor_chain.RobotBatch`: the robot table cut to
        the batch's limb slots where it holds fewer than the table (a batch of robots at their
        own size, :meth:`TD3.store`)."""
        critic = self.f_critics[0] if self.pair else self.critics.chain
        return self.f_actor.robot_batch(ids, critic, limbs=batch.get(OBS).shape[-2])

    def padded_noise(self, action: torch.Tensor) -> torch.Tensor:
        """TD3's target-smoothing noise for ``action`` (:func:`target_noise`), drawn at the
        table's padded size and cut to ``action``'s limb slots: a batch cut to its robot's own
        size draws the random stream, and gets the values on its real limbs, that its padded
        batch would."""
        o, k = self.config, self.f_actor.lookup.num_limbs
        if action.shape[-2] >= k:
            return target_noise(action, o.policy_noise, o.noise_clip)
        full = action.new_empty(*action.shape[:-2], k, action.shape[-1])
        return target_noise(full, o.policy_noise, o.noise_clip).narrow(-2, 0, action.shape[-2])

    # ------------------------------------------------------------------ the two steps
    def _inputs(self, batch: TensorDictBase, next_step: bool) -> dict:
        pre = ("next",) if next_step else ()
        out = {OBS: batch.get((*pre, *OBS))}
        hfield = batch.get((*pre, HFIELD), None)
        if hfield is not None:
            out[HFIELD] = hfield
        return out

    def critic_loss(
        self,
        batch: TensorDictBase,
        noise: torch.Tensor | None = None,
        morph_id: torch.Tensor | None = None,
        backward: bool = False,
    ) -> torch.Tensor:
        """The twin-critic loss on ``batch`` (the sum of the critics' errors). ``noise``: the
        target-smoothing noise (drawn here first when not given, as :func:`target_noise`);
        ``morph_id``: the samples' robots (read from ``batch`` when not given); ``backward``:
        backpropagate each critic's error where it is computed (on its thread, see
        :attr:`twin`) and return the loss detached."""
        o = self.config
        ids = batch.get(MORPH_ID) if morph_id is None else morph_id
        robots = self._robots(ids, batch)
        mask = robots.gathered(MASK)
        action = batch.get(ACTION)
        if noise is None:
            noise = self.padded_noise(action)
        with autocast(self.accel, self.device):
            with torch.no_grad():
                nxt = self._inputs(batch, next_step=True)
                next_action = self._target_action(nxt, robots)
                nxt[ACTION] = smoothed_target_action(next_action, noise)
                next_q = self._twin(self.target_critics, nxt, robots, _limb_q)
                target = td_target(
                    batch.get((K.NEXT, K.REWARD)),
                    batch.get((K.NEXT, K.TERMINATED)),
                    tuple(next_q.unbind(0)),
                    mask,
                    o.gamma,
                    self.rule,
                )
            now = self._inputs(batch, next_step=False)
            now[ACTION] = action
            each = backward and self.twin.parallel  # each critic's backward on its thread
            if each and not self.pair:
                self.critics.prepare_grads()  # each member's gradients go into its slice

            def error(out: dict) -> torch.Tensor:
                q = out[LIMB_Q]
                return critic_error(q, as_dtype(target, q.dtype), mask, self.rule)

            loss = as_dtype(
                self._twin(self.critics, now, robots, error, backward=each).sum(), action.dtype
            )
            if backward and not each:
                loss.backward()
                return loss.detach()
            return loss

    def _target_action(self, inputs: dict, robots: RobotBatch) -> torch.Tensor:
        """The target actor's action on ``inputs`` (no gradient); where the twin critics run on
        two threads, each thread computes one half of the batch (the same values)."""
        n = robots.ids.shape[0]
        if not self.twin.parallel or n < 2 or torch.compiler.is_compiling():
            return self.f_target_actor(inputs, robots)[ACTION]
        cut = [slice(0, n // 2), slice(n // 2, n)]

        def half(part: slice) -> torch.Tensor:
            with torch.no_grad():
                own = RobotBatch(robots.table, robots.ids[part])
                return self.f_target_actor({k: v[part] for k, v in inputs.items()}, own)[ACTION]

        return torch.cat(self.twin.map(half, cut))

    def actor_loss(
        self, batch: TensorDictBase, morph_id: torch.Tensor | None = None
    ) -> torch.Tensor:
        """-Q1 of the actor's action on ``batch``, over real limbs (``morph_id``: as in
        :meth:`critic_loss`)."""
        ids = batch.get(MORPH_ID) if morph_id is None else morph_id
        robots = self._robots(ids, batch)
        mask = robots.gathered(MASK)
        with autocast(self.accel, self.device):
            now = self._inputs(batch, next_step=False)
            now[ACTION] = self.f_actor(now, robots)[ACTION]
            if self.pair:
                q1 = self.f_critics[0](now, robots)[LIMB_Q]
                loss = deterministic_actor_loss(q1, mask, self.rule)
            else:  # critic 1 alone
                loss = self.critics.one(
                    0,
                    now,
                    robots,
                    lambda out: deterministic_actor_loss(out[LIMB_Q], mask, self.rule),
                    fixed=True,
                )
            return as_dtype(loss, now[OBS].dtype)

    # Both steps take and return TensorDicts (what a CUDA graph captures) and leave no gradient
    # behind (zeroed after the optimiser step, as a captured graph needs).
    def _critic_forward(self, batch: TensorDictBase, noise: torch.Tensor) -> torch.Tensor:
        """The critic loss (what ``compile.compile`` compiles): with its graph, or already
        backpropagated where each critic runs on its own thread."""
        return self.critic_loss(batch, noise, backward=self.twin.parallel)

    def _critic_step(self, batch: TensorDictBase) -> TensorDictBase:
        """One critic update on ``batch``; returns ``loss_critic``. The target-smoothing noise
        is drawn here, outside the compiled loss, so a compiled step draws what eager draws."""
        noise = self.padded_noise(batch.get(ACTION))
        with self.twin.step(self, "critic", batch, noise):
            loss = self.critic_forward(batch, noise)
        if not self.twin.parallel:
            loss.backward()
        apply_gradients(
            self.critic_opt,
            self.critic_params,
            self.config.max_grad_norm,
            clip_norm,
            keep=self.twin.parallel and not self.pair,  # the members' gradient slices
        )
        return TensorDict({"loss_critic": loss.detach()})

    def _actor_step(self, batch: TensorDictBase) -> TensorDictBase:
        """One actor update (critic 1 fixed) and the soft target update; returns
        ``loss_actor``. Where the twin critics run on two threads, the actor's loss and
        gradients do too, each thread on one half of the batch (:meth:`_actor_grads`)."""
        o = self.config
        if self.twin.parallel and not self.pair and batch.numel() >= 2:
            with self.twin.step(self, "actor", batch):
                loss, grads = self._actor_grads(batch)
        else:
            loss = self.actor_forward(batch)
            # gradients for the actor only (the critic is a fixed function here)
            grads = torch.autograd.grad(loss, self.actor_params, allow_unused=True)
        for p, g in zip(self.actor_params, grads, strict=True):
            p.grad = g
        apply_gradients(self.actor_opt, self.actor_params, o.max_grad_norm, clip_norm)
        soft_update(self._target, self._online, o.tau)
        return TensorDict({"loss_actor": loss.detach()})

    def _actor_grads(self, batch: TensorDictBase) -> tuple[torch.Tensor, list] | None:
        """The actor loss and its gradients as two halves of ``batch`` give them, one half per
        thread (:attr:`twin`): every loss rule is a mean over the batch's samples, so the
        whole batch's is the halves' means weighted by their sizes, and so are its gradients
        (equal to the whole batch's up to rounding; tested in float64)."""
        n = batch.shape[0]
        halves = [batch[: n // 2], batch[n // 2 :]]

        def half(part: TensorDictBase) -> tuple[torch.Tensor, tuple]:
            loss = self.actor_forward(part) * (part.shape[0] / n)
            return loss.detach(), torch.autograd.grad(loss, self.actor_params, allow_unused=True)

        parts = self.twin.map(half, halves, gather=True)
        if parts is None:  # a helper process's half, sent to the process that steps the actor
            return None
        (loss_a, grads_a), (loss_b, grads_b) = parts
        pairs = list(zip(grads_a, grads_b, strict=True))
        both = [(a, b) for a, b in pairs if a is not None and b is not None]
        if both:  # into the first half's gradients, which nothing else holds
            torch._foreach_add_([a for a, _ in both], [b for _, b in both])
        grads = [  # the second half's own where the first has none (a copy: it may be a view)
            a if a is not None else None if b is None else b.clone() for a, b in pairs
        ]
        return loss_a + loss_b, grads

    def step(self, batch: TensorDictBase) -> dict[str, torch.Tensor]:
        """One critic update, plus an actor and target update every ``policy_delay`` calls;
        the losses stay tensors on the device (no synchronisation)."""
        batch = batch.to(self.device) if batch.device != self.device else batch
        return delayed_update(self, batch)

    def update(self, batch: TensorDictBase) -> dict[str, float]:
        """:meth:`step`, with the losses as floats."""
        return {k: v.item() for k, v in self.step(batch).items()}

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict:
        # The robot table is static data, not learnt state: GraphLookup's buffers are left out
        # so that a checkpoint loads for any robot set.
        return {
            "actor": network_weights(self.actor),
            "critics": network_weights(self.critics),
            "target_actor": network_weights(self.target_actor),
            "target_critics": network_weights(self.target_critics),
            "actor_opt": self.actor_opt.state_dict(),
            "critic_opt": self.critic_opt.state_dict(),
            "updates": self.updates,
        }

    def load_networks(self, state: dict) -> None:
        """The four networks' weights from a :meth:`state_dict` (optimisers and counter left
        as they are); a ValueError names the network that does not fit."""
        if "actor" not in state:
            raise ValueError(
                "the checkpoint's TD3 learner state has an older layout (one torchrl TD3Loss); "
                "its policy can still be evaluated (`gcnt eval`), but training cannot start "
                "from it"
            )
        for key in ("actor", "critics", "target_actor", "target_critics"):
            weights = state[key]
            if key.endswith("critics") and not self.pair and is_members_layout(weights):
                weights = stack_members(weights, 2)  # two networks' weights (older runs)
            try:
                load_weights(getattr(self, key), weights)
            except ValueError as e:
                raise ValueError(f"TD3 {key}: {e}") from None

    def load_state_dict(self, state: dict) -> None:
        self.load_networks(state)
        load_optimizer_state(self.actor_opt, state["actor_opt"])
        critic_opt = state["critic_opt"]
        if not self.pair:
            critic_opt = stack_pair_adam(critic_opt, len(self.critic_params))
        load_optimizer_state(self.critic_opt, critic_opt)
        # the recipe's learning rate wins over the saved one: a run resumed with another
        # td3.lr (e.g. after a divergence) trains with it
        for opt in (self.actor_opt, self.critic_opt):
            for group in opt.param_groups:
                group["lr"] = self.config.lr
        self.updates = state["updates"]


#: ``compile.compile: auto``'s break-even, in updates per schedule: the compile time of TD3's
#: update (both losses' forward and backward graphs, a cold inductor cache as on a fresh clone)
#: over the seconds a compiled bare update saves against eager, both on 1 torch thread and
#: measured in one process (``gcnt.bench.td3.compiled_vs_eager``) on a 2-core Xeon (AMX) beside
#: other jobs: 1,000 s cold (27-42 s from a warm cache); the quick start's mixed update saved
#: 34-36 ms (0.60-0.79x eager), study 1's Walker++ paper-schedule update 6-22 ms (0.67-0.91x),
#: taken as their means (docs/performance.md, issue 45)
COMPILE_BREAK_EVEN = {"paper": 70_000.0, "mixed": 30_000.0}


def resolve_compile(
    recipe: Recipe, num_robots: int, params: int | None = None
) -> tuple[Recipe, str]:
    """``recipe`` with ``compile.compile`` a bool (:func:`gcnt.rl.accelerate.choose_compile` for
    ``auto``: the run's planned updates, :meth:`TD3Config.planned_updates`, against
    :data:`COMPILE_BREAK_EVEN`, and the actor's ``params``; a copy, the recipe given is left as
    it is), and why."""
    c: TD3Config = recipe.algo_config
    compiled, why = choose_compile(
        recipe.compile,
        recipe.device,
        c.planned_updates(recipe.collector.total_frames, num_robots),
        COMPILE_BREAK_EVEN[c.schedule],
        params,
    )
    auto = recipe.compile.compile == "auto"
    # eager would run the twin critics on two threads (twin.make_pair_runner's automatic choice)
    if compiled and auto and recipe.compile.twin_threads is None and one_update_thread(recipe):
        why += f"; {ONE_THREAD_CAVEAT}"
    if compiled is recipe.compile.compile:
        return recipe, why
    run = copy.copy(recipe)
    run.compile = dataclasses.replace(recipe.compile, compile=compiled)
    return run, why


#: what ``compile.compile: auto`` adds when it compiles on a CPU with 2 to 4 cores: the compiled
#: update runs on one torch thread where the eager one runs its twin critics on two threads, and
#: on an idle 2-core Xeon Walker++ at the paper's sizes updated 1.25x slower compiled (0.57-0.80x
#: eager at the quick start's and study 1's sizes; docs/performance.md)
ONE_THREAD_CAVEAT = (
    "compiled on one torch thread, where the eager critics run on two: on an idle machine a "
    "large network (the paper's sizes) can update faster eagerly (compile.compile=false)"
)


def actor_parameters(recipe: Recipe, env: EnvBase) -> int | None:
    """The parameters of the run's actor (built once aside, without drawing from torch's
    global random stream), where ``compile.compile: auto`` needs them; None otherwise."""
    if recipe.compile.compile in (True, False):
        return None
    with torch.random.fork_rng(devices=[]):
        return sum(p.numel() for p in make_net(recipe, env, "td3_actor").parameters())


def one_update_thread(recipe: Recipe) -> bool:
    """Whether a run's TD3 update takes 1 torch intra-op thread instead of torch's default (one
    per core): an update, eager or compiled, on a CPU with 2 to 4 usable cores and
    ``compile.torch_threads`` unset. On an idle machine two threads can be faster (the quick
    start's one-call ensemble: 17.7 against 25 ms per update on a 2-core Xeon), but on a machine
    shared with other jobs each kernel's parallel region waits for a thread another job has taken
    (106 against 26 ms beside a busy loop; inductor generates a compiled update's kernels for the
    threads set when it compiles), and one or two threads round differently, so the thread count
    is not chosen by the machine's load: a seeded run repeats whatever else runs."""
    return (
        torch.device(recipe.device).type == "cpu"
        and recipe.compile.torch_threads is None
        and 2 <= usable_cpus() <= 4
    )


def trims_padding(recipe: Recipe, learner: TD3Learner | None = None) -> bool:
    """Whether one-robot batches run at their robot's own limb count: ``td3.trim_padding``, for
    a method the registry declares ``padding_free`` and (``learner``'s networks, where given)
    with no dropout, whose random draws would differ with the batch's shape."""
    entry = NETWORKS.get(recipe.network.name)
    return (
        recipe.algo_config.trim_padding
        and entry is not None
        and entry.padding_free
        and (learner is None or not (has_dropout(learner.actor) or has_dropout(learner.critics)))
    )


def stack_pair_adam(state: dict, num_params: int) -> dict:
    """An Adam state dict over two critics' parameters (critic 1's, then critic 2's: 2P
    tensors, as runs before the ensemble saved it) as the ensemble's: P stacked tensors, each
    moment [2, ...]; one already stacked is returned as it is."""
    (group,) = state["param_groups"]
    ids = group["params"]
    if len(ids) != 2 * num_params:
        return state
    moments = state["state"]
    stacked = {}
    for j in range(num_params):
        a, b = moments.get(ids[j]), moments.get(ids[num_params + j])
        if not a or not b:
            continue
        stacked[ids[j]] = {k: a[k].clone() if k == "step" else torch.stack([a[k], b[k]]) for k in a}
    return {"state": stacked, "param_groups": [{**group, "params": ids[:num_params]}]}


def _limb_q(out: dict) -> torch.Tensor:
    return out[LIMB_Q]


def clip_norm(params: Sequence[torch.Tensor], max_norm: float) -> None:
    """torch's gradient-norm clip over all ``params`` together."""
    torch.nn.utils.clip_grad_norm_(params, max_norm, foreach=True)


def apply_gradients(
    opt: torch.optim.Optimizer,
    params: Sequence[torch.Tensor],
    max_grad_norm: float,
    clip: Callable[[Sequence[torch.Tensor], float], Any],
    keep: bool = False,
) -> None:
    """The optimiser tail of every TD3 step: ``clip`` the gradients of ``params`` to
    ``max_grad_norm`` (0: no clipping), step, and leave no gradient behind (``keep``: zeroed in
    place, for gradients the next step writes into: the ensemble members' slices)."""
    if max_grad_norm > 0:
        clip(params, max_grad_norm)
    opt.step()
    opt.zero_grad(set_to_none=not keep)


def soft_update(target: list[torch.Tensor], online: list[torch.Tensor], tau: float) -> None:
    """Move every target tensor ``tau`` of the way towards its online tensor."""
    with torch.no_grad():
        torch._foreach_lerp_(target, online, tau)


def delayed_update(learner, batch: TensorDictBase) -> dict[str, torch.Tensor]:
    """TD3's delayed policy update on a learner with ``critic_step``, ``actor_step``,
    ``updates``, ``config`` and ``accel``: a critic step, then an actor + target step on every
    ``policy_delay``-th call (two graphed steps, chosen here in Python)."""
    begin_step(learner.accel)
    out = owned({"loss_critic": learner.critic_step(batch)["loss_critic"]}, learner.accel)
    learner.updates += 1
    if learner.updates % learner.config.policy_delay == 0:
        begin_step(learner.accel)
        out |= owned({"loss_actor": learner.actor_step(batch)["loss_actor"]}, learner.accel)
    return out


def loss_rows(losses: list[dict[str, torch.Tensor]]) -> list[dict[str, Any]]:
    """A phase's loss dicts (tensors on the device) as plain values, read with one
    synchronisation for the whole phase."""
    if not losses:
        return []
    keys = sorted({k for row in losses for k in row})
    values = {k: torch.stack([row[k] for row in losses if k in row]).tolist() for k in keys}
    its = {k: iter(v) for k, v in values.items()}
    return [{k: next(its[k]) for k in row} for row in losses]


class UpdateSchedule:
    """When to update and on what: yields the mini-batches of each update phase.

    With ``rounds`` (the "paper" schedule with ``round_steps`` ``first_episode`` or
    ``store_all_count_first``) it also keeps which sub-envs finished their first episode of the
    round (:meth:`admit` counts only the steps up to it, and stores the rest or drops it), and
    asks for a reset of every sub-env when a round ends. ``round_updates`` shares a round's
    updates out among the robots: ``mean`` gives each the mean of the robots' counted steps
    (the originals' ``per_morph_iter``), ``own`` each its own counted steps."""

    def __init__(
        self,
        config: TD3Config,
        num_robots: int,
        num_envs: int = 0,
        limbs: Sequence[int] | None = None,
    ):
        self.kind = config.schedule
        #: each robot's limb count, when its one-robot batches are cut to it (``trim_padding``)
        self.limbs = None if limbs is None else list(limbs)
        self.updates_per_step = config.updates_per_step
        self.pending = np.zeros(num_robots)  # transitions stored since the last update phase
        self.counted = np.zeros(num_robots)  # steps counted since the last update phase
        self.finished = np.zeros(num_robots, dtype=bool)  # robot ended an episode since then
        self.rounds = self.kind == "paper" and config.round_steps != "all"
        #: the steps after a sub-env's first episode of the round are stored (not dropped)
        self.store_after_first = config.round_steps == "store_all_count_first"
        self.mean_updates = config.round_updates == "mean"
        self.env_done = np.zeros(num_envs, dtype=bool)  # sub-env ended an episode this round
        self.reset_due = False

    def admit(self, data: TensorDictBase) -> tuple[TensorDictBase, TensorDictBase]:
        """The steps of ``data`` [envs, steps] the run counts, and those it stores: in
        ``rounds``, each sub-env's steps until its first episode of the round ended are counted
        (flat [counted]), and they alone are stored, or (``store_after_first``) every step is;
        otherwise ``data`` is both."""
        if not self.rounds:
            return data, data
        done = data["next", "done"].reshape(data.shape).cpu()
        after_first = (done.long().cumsum(-1) - done.long()) > 0  # after a done of this batch
        keep = ~(torch.from_numpy(self.env_done)[:, None] | after_first)
        self.env_done |= done.any(-1).numpy()
        counted = data[keep.to(data.device)]
        return counted, (data.reshape(-1) if self.store_after_first else counted)

    def add(self, stored: TensorDictBase, counted: TensorDictBase | None = None) -> None:
        """Note a batch's stored transitions and its counted steps (``counted``: the stored
        ones when not given). A robot has finished its round's episode when a counted step of
        it ends one."""
        counted = stored if counted is None else counted
        r = len(self.pending)
        self.pending += np.bincount(stored[MORPH_ID].reshape(-1).numpy(), minlength=r)
        morph = counted[MORPH_ID]
        self.counted += np.bincount(morph.reshape(-1).numpy(), minlength=r)
        self.finished[morph[counted["next", "done"].squeeze(-1)].numpy()] = True

    def robot_updates(self) -> list[int]:
        """The updates of each robot when a round ends: ``updates_per_step`` times its own
        counted steps, or (``mean_updates``) the robots' mean, floored as the originals'
        ``sum(iterations) // robots``."""
        if self.mean_updates:
            each = int(self.counted.sum()) // len(self.counted)
            return [round(each * self.updates_per_step)] * len(self.counted)
        return [round(n * self.updates_per_step) for n in self.counted]

    def batches(self, replay: rb.RobotReplay, warm: bool) -> Iterator[TensorDictBase]:
        round_over = self.kind == "paper" and self.finished.all()
        if not warm:  # random exploration, or a buffer still smaller than a batch
            self._clear()
            if round_over and self.rounds:
                self._end_round()
            return
        if round_over:
            # each robot in turn, from its own ring (robot_updates: how many)
            for robot, n in enumerate(self.robot_updates()):
                limbs = None if self.limbs is None else self.limbs[robot]
                for _ in range(n):
                    yield replay.sample_robot(robot, limbs=limbs)
            self._end_round()
        elif self.kind == "mixed":
            # one padded batch holds batch_size transitions of every robot (one gather)
            for _ in range(round(self.pending.sum() * self.updates_per_step / len(self.pending))):
                yield replay.sample_mixed()
        else:
            return
        self._clear()

    def _clear(self) -> None:
        self.pending[:] = 0
        self.counted[:] = 0

    def _end_round(self) -> None:
        self.finished[:] = False
        if self.rounds:
            self.env_done[:] = False
            self.reset_due = True

    def state_dict(self) -> dict[str, Any]:
        return {
            "pending": self.pending.tolist(),
            "counted": self.counted.tolist(),
            "finished": self.finished.tolist(),
            "env_done": self.env_done.tolist(),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.pending[:] = state["pending"]
        # a checkpoint from before counted steps were kept apart: they were the stored ones
        self.counted[:] = state.get("counted", state["pending"])
        self.finished[:] = state["finished"]
        if len(state.get("env_done", [])) == len(self.env_done):
            self.env_done[:] = state["env_done"]


#: the replay checkpoint's file in the run's buffers directory (the stored count in its name)
BUFFER_FILE = "replay-{stored}.pt"


class TD3(Algorithm):
    """TD3 behind the run loop: exploration, replay, update schedule, checkpoint state."""

    name = "td3"

    def __init__(self, recipe: Recipe, env: EnvBase, robots: Sequence[Robot]) -> None:
        n = len(robots)
        # compile.compile: auto resolved for this run (the recipe given keeps "auto")
        recipe, why = resolve_compile(recipe, n, actor_parameters(recipe, env))
        super().__init__(recipe, env, robots)
        self.choices.append(f"TD3 update compile.compile={why}")
        c: TD3Config = self.config
        try:
            c.check_random_phase(recipe.collector.total_frames, n)
        except ValueError as e:
            raise RecipeError(str(e)) from None
        #: env steps of uniform-random actions over all robots
        self.random_frames = c.random_frames(n)
        if one_update_thread(recipe) and torch.get_num_threads() != 1:
            self.choices.append(
                f"TD3 update on a {usable_cpus()}-core CPU: torch intra-op threads "
                f"{torch.get_num_threads()} -> 1 (compile.torch_threads sets them)"
            )
            torch.set_num_threads(1)
        self.learner = TD3Learner(recipe, env)
        capacity = rb.per_robot_capacity(n, c.buffer_size_per_robot, c.buffer_total_size)
        replay_device = recipe.device if recipe.compile.replay_on_device else "cpu"
        check_replay_memory(env, n, capacity, replay_device)  # allocated later: refuse it now
        self.replay = rb.RobotReplay(n, capacity, c.batch_size, device=replay_device)
        trim = trims_padding(recipe, self.learner)
        if trim and c.schedule == "paper" and len({r.num_limbs for r in robots}) > 1:
            self.choices.append(
                "TD3 one-robot batches at each robot's own limb count (td3.trim_padding)"
            )
        limbs = [r.num_limbs for r in robots] if trim else None
        self.schedule = UpdateSchedule(c, n, int(env.batch_size[0]), limbs)
        self.stored = 0
        self._to_store: TensorDictBase | None = None  # admit()'s batch to store, for process()
        self._probe: TensorDictBase | None = None  # td3.probe_interval's transitions
        self._extras: dict[str, float] = {}  # for the next log row
        self._buffer_file: str | None = None  # the replay file the last loaded state names

    @property
    def updates(self) -> int:  # the learner counts them
        return self.learner.updates

    def _frames_per_batch(self) -> int:
        return self.env.batch_size[0] * self.config.steps_per_batch

    def collect_settings(self, env_steps: int) -> CollectSettings:
        c, device = self.config, self.recipe.device
        # the actor, at less call cost, plus Gaussian noise
        explore = _with_noise(
            TensorChainModule(self.learner.actor, [ACTION]),
            self.env.full_action_spec[ACTION].to(device),
            c.exploration_noise,
        )
        fpb = self._frames_per_batch()
        random_left = _whole_batches(max(0, self.random_frames - env_steps), fpb)
        if self.schedule.rounds:  # fewer steps counted than collected: the loop ends the phase
            random_left = _whole_batches(RANDOM_UNTIL_TOLD, fpb) if random_left else 0
            return CollectSettings(explore, fpb, random_left, random_steps=self.random_frames)
        return CollectSettings(explore, fpb, random_left)

    def admit(self, data: TensorDictBase) -> TensorDictBase:
        # the steps counted; those stored besides them (round_steps: store_all_count_first)
        # wait for process(), which gets the counted ones
        counted, self._to_store = self.schedule.admit(data)
        return counted

    def reset_due(self) -> bool:
        due, self.schedule.reset_due = self.schedule.reset_due, False
        return due

    def store(
        self, data: TensorDictBase, env_steps: int, counted: TensorDictBase | None = None
    ) -> Iterator[TensorDictBase]:
        """Store a collected batch (``counted``: the steps of it the run counted, when not all
        of them, :meth:`admit`); the mini-batches of the update phase the schedule then asks
        for (none while a robot holds fewer than a batch, nor during the random phase unless
        ``update_during_random``)."""
        c = self.config
        self.stored += self.replay.extend(data)
        self.schedule.add(data, counted)
        random_done = c.update_during_random or env_steps >= self.random_frames
        warm = random_done and int(self.replay.sizes.min()) >= c.batch_size
        return self.schedule.batches(self.replay, warm)

    def process(self, data: TensorDictBase, env_steps: int) -> Iterator[dict[str, float]]:
        # ``data``: the counted steps (admit); the batch stored may hold more of the round
        stored, self._to_store = self._to_store, None
        batches = self.store(data if stored is None else stored, env_steps, counted=data)
        # the losses stay on the device during a phase: one synchronisation per phase
        yield from loss_rows([self.learner.step(batch) for batch in batches])
        self._probe_when_due(env_steps, env_steps - data.numel())

    def _probe_when_due(self, env_steps: int, before: int) -> None:
        """``td3.probe_interval``: the probe's measures once a multiple of it is crossed."""
        every = self.config.probe_interval
        if not every or env_steps // every == before // every:
            return
        from gcnt.rl.td3.probe import make_probe, probe_measures

        if self._probe is None:
            self._probe = make_probe(self.recipe, self.robots, self.config.probe_steps)
        self._extras |= probe_measures(self.learner, self._probe)

    def log_extras(self) -> dict[str, float]:
        out, self._extras = self._extras, {}
        return out

    def resolved(self) -> dict[str, Any]:
        c, fpb = self.config, self._frames_per_batch()
        return {
            "num_envs": int(self.env.batch_size[0]),
            "frames_per_batch": fpb,
            "init_random_frames": _whole_batches(self.random_frames, fpb),
            "compile": self.recipe.compile.compile,
            "buffer_per_robot": rb.per_robot_capacity(
                len(self.robots), c.buffer_size_per_robot, c.buffer_total_size
            ),
        }

    def state_dict(self) -> dict[str, Any]:
        state = {
            **self.learner.state_dict(),
            "stored": self.stored,
            "schedule": self.schedule.state_dict(),
        }
        if self.config.checkpoint_buffers:
            state["buffer_file"] = BUFFER_FILE.format(stored=self.stored)
        return state

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.learner.load_state_dict(state)
        self.stored = state.get("stored", 0)
        if "schedule" in state:
            self.schedule.load_state_dict(state["schedule"])
        self._buffer_file = state.get("buffer_file")

    def start_from(self, state: dict[str, Any]) -> None:
        # the actor, the critics and their targets; Adam, replay, schedule and counters fresh
        self.learner.load_networks(state)

    def buffers_state(self, directory: Path) -> bool:
        """Write the replay (atomically) as ``replay-<stored>.pt``, named in the learner state
        written next; the previous file stays until then, so that a run killed between the two
        writes resumes from a matching pair. Older files are removed."""
        if not self.config.checkpoint_buffers:
            return False
        directory = Path(directory)
        name = BUFFER_FILE.format(stored=self.stored)
        self.replay.save(directory / name)
        keep = {name, self._buffer_file}
        for old in directory.glob(BUFFER_FILE.format(stored="*")):
            if old.name not in keep:
                old.unlink(missing_ok=True)
        self._buffer_file = name
        return True

    def load_buffers(self, directory: Path) -> None:
        if self._buffer_file is None:
            log.warning("the checkpoint names no replay file; starting with an empty replay")
            return
        path = Path(directory) / self._buffer_file
        if not path.exists():
            raise FileNotFoundError(
                f"{path}: the replay checkpoint named by the run's checkpoint is missing"
            )
        self.replay.load(path)

    def policy_state(self) -> dict[str, Any]:
        return {"actor": network_weights(self.learner.actor)}

    @classmethod
    def eval_policy(
        cls, recipe: Recipe, state: dict[str, Any], env: EnvBase, *, deterministic: bool = True
    ):
        actor = make_net(recipe, env, "td3_actor")
        load_weights(actor, state["actor"])
        actor.eval()
        fast = TensorChainModule(actor, [ACTION])
        if deterministic:
            return fast
        spec = env.full_action_spec[ACTION].to(recipe.device)
        return _with_noise(fast, spec, recipe.algo_config.exploration_noise)


def _with_noise(actor: TensorChainModule, spec, sigma: float) -> TensorDictSequential:
    """``actor`` followed by constant Gaussian exploration noise of std ``sigma``."""
    return TensorDictSequential(actor, GaussianExploration(spec, sigma, ACTION))


#: the collector's random frames when the run loop ends its random phase (a whole number of
#: batches no run reaches)
RANDOM_UNTIL_TOLD = 2**62


def _whole_batches(frames: int, frames_per_batch: int) -> int:
    """``frames`` rounded up to whole collector batches."""
    return -(-frames // frames_per_batch) * frames_per_batch
