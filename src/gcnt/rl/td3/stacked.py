"""Several seeds' TD3 learners updated together: parameters stacked, losses under one vmap.

S :class:`~gcnt.rl.td3.learner.TD3Learner` of one recipe (one per seed) keep their own modules,
optimisers and update counts. :class:`StackedTD3Learner` holds their online and target parameters
stacked along a leading seed dimension (leaves [S, ...]) and computes the critic and the actor
losses of every seed with one ``torch.vmap`` call over (stacked parameters, stacked per-seed
batches): inside it, the first learner's chains run with one seed's parameters swapped in
(``TensorDictBase.to_module``). One Adam per role over the stacked leaves makes the same steps as S
separate Adams, since Adam is elementwise and the seeds share hyperparameters and step count; the
gradient-norm clip (``td3.max_grad_norm``) is computed per seed (:func:`clip_grad_norm_per_seed`).

Nothing random runs inside vmap: each seed's target-smoothing noise and replay draws are made
outside, with that seed's global random state swapped in (:class:`SeedRNG`), so that a seed
consumes the same random numbers as it would training alone.

:meth:`StackedTD3Learner.pull` copies the seeds' weights, optimiser states and update counts into
the stack (at the start, and after a seed's state was loaded); :meth:`StackedTD3Learner.push`
writes them back, so that each seed's collector policy, checkpoints and evaluation read its own
updated modules. :class:`StackedTD3` runs the update phase of S TD3 algorithms (their replays and
schedules) on one collected batch each; ``gcnt.rl.td3.stacked_loop`` is the training loop around it.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Sequence
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictParams
from torch import nn
from torch.nn.attention import sdpa_kernel

from gcnt.keys import ACTION, MORPH_ID
from gcnt.rl.accelerate import accelerate, compile_step, optimizer_kwargs
from gcnt.rl.td3.ensemble import VMAP_SDPA
from gcnt.rl.td3.learner import (
    TD3,
    TD3Learner,
    apply_gradients,
    delayed_update,
    loss_rows,
    soft_update,
)
from gcnt.rl.td3.loss import target_noise
from gcnt.rl.td3.tensor_chain import has_dropout
from gcnt.run.directory import rng_state, set_rng_state

#: where a stacked batch carries each seed's target-smoothing noise (shaped like the action)
NOISE = "target_noise"
#: hyperparameters that must agree for one stacked optimiser to equal the seeds' own
_SHARED = ("lr", "gamma", "tau", "policy_delay", "policy_noise", "noise_clip", "max_grad_norm")


def _online(learner: TD3Learner) -> nn.Module:
    return nn.ModuleDict({"actor": learner.actor, "critics": learner.critics})


def _target(learner: TD3Learner) -> nn.Module:
    return nn.ModuleDict({"actor": learner.target_actor, "critics": learner.target_critics})


def _stack(modules: Sequence[nn.Module]) -> TensorDict:
    """The parameters (not buffers) of same-shaped ``modules``, stacked: leaves [S, ...], keyed
    as the modules nest them (what ``to_module`` swaps in).

    Not ``TensorDict.from_modules``: it stacks the buffers too, so the robot table that every
    chain holds as buffers (``GraphLookup``) would be copied once per seed (checked with
    tensordict 0.14: a [S, ...] copy of each table buffer), and swapped in needlessly at every
    loss call."""
    per_module = [dict(m.named_parameters()) for m in modules]
    out = TensorDict(batch_size=[len(modules)])
    for name in per_module[0]:
        out.set(tuple(name.split(".")), torch.stack([p[name].detach() for p in per_module]))
    return out


def _leaves(td: TensorDictBase, module: nn.Module) -> list[torch.Tensor]:
    """``td``'s leaves in ``module.parameters()`` order."""
    return [td.get(tuple(name.split("."))) for name, _ in module.named_parameters()]


def clip_grad_norm_per_seed(params: Sequence[torch.Tensor], max_norm: float) -> torch.Tensor:
    """``torch.nn.utils.clip_grad_norm_`` applied to each seed's slice (dim 0) of the stacked
    ``params``' gradients on its own: the seed's total 2-norm over all params, and its gradients
    scaled by ``min(1, max_norm / (norm + 1e-6))``. Returns the per-seed norms [S]."""
    grads = [p.grad for p in params if p.grad is not None]
    if not grads:
        return torch.zeros(0)
    norms = torch.stack([torch.linalg.vector_norm(g.flatten(1), 2, dim=1) for g in grads])
    total = torch.linalg.vector_norm(norms, 2, dim=0)  # [S]
    coef = (max_norm / (total + 1e-6)).clamp(max=1.0)
    for g in grads:
        g.mul_(coef.view(-1, *([1] * (g.dim() - 1))))
    return total


class StackedTD3Learner:
    """The update steps of S :class:`TD3Learner` (one recipe, S seeds) as one vmapped step.

    Args:
        learners: the seeds' learners, built from the same recipe (networks, robots and
            ``td3:`` hyperparameters alike; seeds differ).
    """

    def __init__(self, learners: Sequence[TD3Learner]) -> None:
        if len(learners) < 1:
            raise ValueError("StackedTD3Learner needs at least one learner")
        self.learners = list(learners)
        first = self.learners[0]
        self.config, self.accel, self.device = first.config, first.accel, first.device
        for other in self.learners[1:]:
            for key in _SHARED:
                if getattr(other.config, key) != getattr(self.config, key):
                    raise ValueError(f"stacked seeds: td3.{key} differs between the learners")
        for name in ("actor", "critics"):
            if has_dropout(getattr(first, name)):
                raise ValueError(
                    f"stacked seeds: the {name} has dropout, whose draws inside one vmap would "
                    "differ from the seeds' own; train these seeds one by one"
                )
        # the losses run on a copy of the first learner's networks, with each seed's parameters
        # swapped in (swapping them into a seed's own modules would replace its tensors)
        self.shell = first.loss_shell()
        self._online_module, self._target_module = _online(self.shell), _target(self.shell)
        self.online = TensorDictParams(_stack([_online(lr) for lr in self.learners]))
        self.target = _stack([_target(lr) for lr in self.learners])
        self.actor_leaves = _leaves(self.online["actor"], first.actor)
        self.critic_leaves = _leaves(self.online["critics"], first.critics)
        self._online_leaves = self.actor_leaves + self.critic_leaves
        self._target_leaves = _leaves(self.target["actor"], first.target_actor) + _leaves(
            self.target["critics"], first.target_critics
        )
        opt_kw = optimizer_kwargs(self.accel, self.device)
        self.actor_opt = torch.optim.Adam(self.actor_leaves, lr=self.config.lr, **opt_kw)
        self.critic_opt = torch.optim.Adam(self.critic_leaves, lr=self.config.lr, **opt_kw)
        # compile.compile: the seeds' vmapped losses as one graph each (as TD3Learner's)
        self.critic_forward = compile_step(
            self._critic_losses, self.accel, fullgraph=True, name="stacked TD3 critic loss"
        )
        self.actor_forward = compile_step(
            self._actor_losses, self.accel, fullgraph=True, name="stacked TD3 actor loss"
        )
        self.critic_step = accelerate(self._critic_step, self.accel, self.device)
        self.actor_step = accelerate(self._actor_step, self.accel, self.device)
        self.updates = 0
        self.pull()

    @property
    def num_seeds(self) -> int:
        return len(self.learners)

    # ------------------------------------------------------------------ one seed, inside vmap
    def _seed_critic_loss(self, online, target, batch, ids) -> torch.Tensor:
        with online.to_module(self._online_module), target.to_module(self._target_module):
            return self.shell.critic_loss(batch, batch.get(NOISE), ids)

    def _seed_actor_loss(self, online, batch, ids) -> torch.Tensor:
        with online.to_module(self._online_module):
            return self.shell.actor_loss(batch, ids)

    # ------------------------------------------------------------------ the two steps
    # As TD3Learner's: TensorDict in and out, no gradient left behind. ``batch`` is [S, N]: each
    # seed's mini-batch and its NOISE; its morph_id rows are alike (checked by stack_batches).
    def _critic_losses(self, batch: TensorDictBase) -> torch.Tensor:
        """Every seed's critic loss [S] (what ``compile.compile`` compiles)."""
        ids = batch.get(MORPH_ID)[0]
        with sdpa_kernel(VMAP_SDPA):
            return torch.vmap(self._seed_critic_loss, (0, 0, 0, None))(
                self.online, self.target, batch, ids
            )

    def _actor_losses(self, batch: TensorDictBase) -> torch.Tensor:
        """Every seed's actor loss [S] (critic 1 fixed; compiled as :meth:`_critic_losses`)."""
        ids = batch.get(MORPH_ID)[0]
        with sdpa_kernel(VMAP_SDPA):
            return torch.vmap(self._seed_actor_loss, (0, 0, None))(self.online, batch, ids)

    def _critic_step(self, batch: TensorDictBase) -> TensorDictBase:
        """One critic update of every seed; returns ``loss_critic`` [S]."""
        o = self.config
        loss = self.critic_forward(batch)
        loss.sum().backward()  # the seeds share no parameter: each gets its own gradient
        apply_gradients(
            self.critic_opt, self.critic_leaves, o.max_grad_norm, clip_grad_norm_per_seed
        )
        return TensorDict({"loss_critic": loss.detach()})

    def _actor_step(self, batch: TensorDictBase) -> TensorDictBase:
        """One actor update of every seed (critic 1 fixed) and the soft target update; returns
        ``loss_actor`` [S]."""
        o = self.config
        loss = self.actor_forward(batch)
        with sdpa_kernel(VMAP_SDPA):
            grads = torch.autograd.grad(loss.sum(), self.actor_leaves, allow_unused=True)
        # contiguous, as backward() would lay them out: vmap returns some gradients strided, and
        # CPU's fused Adam then read them in the wrong order (seen with torch 2.13)
        for p, g in zip(self.actor_leaves, grads, strict=True):
            p.grad = None if g is None else g.contiguous()
        apply_gradients(self.actor_opt, self.actor_leaves, o.max_grad_norm, clip_grad_norm_per_seed)
        soft_update(self._target_leaves, self._online_leaves, o.tau)
        return TensorDict({"loss_actor": loss.detach()})

    def stack_batches(
        self, batches: Sequence[TensorDictBase], noises: Sequence[torch.Tensor]
    ) -> TensorDictBase:
        """The seeds' mini-batches and target noises as one [S, N] batch on the device."""
        if len(batches) != self.num_seeds or len(noises) != self.num_seeds:
            raise ValueError(
                f"stacked seeds: {len(batches)} batches and {len(noises)} noises for "
                f"{self.num_seeds} seeds"
            )
        ids = [b.get(MORPH_ID) for b in batches]
        if ids[0].device.type == "cpu":  # a free check on the host (no device synchronisation)
            for i, other in enumerate(ids[1:], 1):
                if not torch.equal(other, ids[0]):
                    raise ValueError(
                        f"stacked seeds: seed {i}'s mini-batch holds other robots in other "
                        "places than seed 0's (the stacked update needs the mixed schedule's "
                        "layout)"
                    )
        batch = torch.stack([b.to(self.device) for b in batches])
        batch.set(NOISE, torch.stack([n.to(self.device) for n in noises]))
        return batch

    def step(self, batch: TensorDictBase) -> dict[str, torch.Tensor]:
        """One critic update of every seed, plus an actor and target update every
        ``policy_delay`` calls; losses [S] stay on the device. Seeds' modules are written by
        :meth:`push`."""
        return delayed_update(self, batch)

    # ------------------------------------------------------------------ seeds <-> stack
    def _optimisers(self) -> list[tuple[torch.optim.Optimizer, list, str, str]]:
        return [
            (self.actor_opt, self.actor_leaves, "actor_opt", "actor_params"),
            (self.critic_opt, self.critic_leaves, "critic_opt", "critic_params"),
        ]

    @torch.no_grad()
    def pull(self) -> None:
        """Copy the seeds' weights, Adam states and update counts into the stack."""
        counts = {lr.updates for lr in self.learners}
        if len(counts) > 1:
            raise ValueError(f"stacked seeds: the learners have made {sorted(counts)} updates")
        self.updates = counts.pop()
        stacked = zip(self._online_leaves, self._target_leaves, strict=True)
        for j, (online, target) in enumerate(stacked):
            online.copy_(torch.stack([lr._online[j] for lr in self.learners]))
            target.copy_(torch.stack([lr._target[j] for lr in self.learners]))
        for opt, leaves, opt_name, params_name in self._optimisers():
            for j, leaf in enumerate(leaves):
                states = [
                    getattr(lr, opt_name).state.get(getattr(lr, params_name)[j])
                    for lr in self.learners
                ]
                opt.state.pop(leaf, None)
                if all(not s for s in states):
                    continue
                if any(not s for s in states):
                    raise ValueError(f"stacked seeds: only some seeds have {opt_name} state")
                opt.state[leaf] = _stack_adam_state(states, opt_name)

    @torch.no_grad()
    def push(self) -> None:
        """Write the stack's weights, Adam states and update count into each seed's learner."""
        for i, lr in enumerate(self.learners):
            torch._foreach_copy_(lr._online, [leaf[i] for leaf in self._online_leaves])
            torch._foreach_copy_(lr._target, [leaf[i] for leaf in self._target_leaves])
            for opt, leaves, opt_name, params_name in self._optimisers():
                own, params = getattr(lr, opt_name), getattr(lr, params_name)
                for leaf, p in zip(leaves, params, strict=True):
                    state = opt.state.get(leaf)
                    if state:
                        own.state[p] = {
                            k: v.clone() if k == "step" else v[i].clone() for k, v in state.items()
                        }
            lr.updates = self.updates


def _stack_adam_state(states: list[dict[str, Any]], what: str) -> dict[str, Any]:
    steps = {float(s["step"]) for s in states}
    if len(steps) > 1:
        raise ValueError(f"stacked seeds: the seeds' {what} step counts differ ({sorted(steps)})")
    return {
        k: states[0][k].clone() if k == "step" else torch.stack([s[k] for s in states])
        for k in states[0]
    }


class SeedRNG:
    """Each seed's global random state (:func:`gcnt.run.directory.rng_state`: torch CPU and CUDA,
    NumPy, Python), swapped in while working for that seed."""

    def __init__(self, num_seeds: int) -> None:
        self.states: list[dict[str, Any] | None] = [None] * num_seeds

    def capture(self, seed_index: int) -> None:
        """Take the current global state as seed ``seed_index``'s."""
        self.states[seed_index] = rng_state()

    @contextlib.contextmanager
    def active(self, seed_index: int) -> Iterator[None]:
        """Seed ``seed_index``'s state is the global one inside; what it draws there is kept for
        its next turn, and the state from before is restored after."""
        state = self.states[seed_index]
        if state is None:
            raise RuntimeError(f"SeedRNG: no state captured for seed {seed_index}")
        outside = rng_state()
        set_rng_state(state)
        try:
            yield
        finally:
            self.states[seed_index] = rng_state()
            set_rng_state(outside)


class StackedTD3:
    """The update phase of S :class:`~gcnt.rl.td3.learner.TD3` algorithms (one recipe, S seeds), each
    with its own replay and schedule, on one collected batch each: the stored steps, then as many
    stacked updates as each seed's schedule yields (the same number: mixed schedule, same robots,
    lockstep), then the weights pushed back to the seeds."""

    def __init__(self, algos: Sequence[TD3], rng: SeedRNG) -> None:
        self.algos = list(algos)
        kinds = {a.config.schedule for a in self.algos}
        if kinds != {"mixed"}:
            raise ValueError(
                f"stacked seeds need td3.schedule=mixed; got {', '.join(sorted(kinds))}"
            )
        self.rng = rng
        self.learner = StackedTD3Learner([a.learner for a in self.algos])

    def process(
        self, datas: Sequence[TensorDictBase], env_steps: Sequence[int]
    ) -> list[list[dict[str, float]]]:
        """Store each seed's batch and run the updates its schedule asks for; one list of loss
        rows per seed (as :meth:`TD3.process` yields them)."""
        phases = []
        for algo, data, steps in zip(self.algos, datas, env_steps, strict=True):
            phases.append(algo.store(data, steps))
        o, device = self.learner.config, self.learner.device
        losses = []
        while True:
            batches, noises = [], []
            for i, phase in enumerate(phases):
                with self.rng.active(i):  # the draws TD3.process and TD3Learner.step make
                    batch = next(phase, None)
                    if batch is not None:
                        batch = batch.to(device) if batch.device != device else batch
                        noises.append(target_noise(batch.get(ACTION), o.policy_noise, o.noise_clip))
                batches.append(batch)
            done = [b is None for b in batches]
            if all(done):
                break
            if any(done):
                raise RuntimeError(
                    f"stacked seeds: seeds {[i for i, d in enumerate(done) if d]} have fewer "
                    "updates in this phase than the others"
                )
            losses.append(self.learner.step(self.learner.stack_batches(batches, noises)))
        rows: list[list[dict[str, float]]] = [[] for _ in self.algos]
        if losses:  # nothing to write back before the first update
            self.learner.push()
        for per_seed in loss_rows(losses):  # losses [S] each: one value per seed
            for i in range(len(self.algos)):
                rows[i].append({k: v[i] for k, v in per_seed.items()})
        return rows
