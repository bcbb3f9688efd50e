"""``gcnt bench-train --parts``: where a TD3 update's time goes, and what the second thread buys
in each part.

The bare update of the recipe's schedule (:func:`gcnt.bench.td3.robot_batches`) is timed part by
part: the critic step (the target actor, the target critics, the critics' forward and backward,
the optimiser tail) and the actor step (the actor's loss and gradients, the optimiser tail, the
soft target update), each in ms per update. Where the recipe runs its twin critics on two threads
(:mod:`gcnt.rl.td3.twin`), the same update also runs with the same operators in turn on one
thread (:class:`~gcnt.rl.td3.twin.EachInTurn`), in alternate rounds, so that each part's ratio
(two threads ÷ one) says how much of it the second core takes. A part that stays near 1 is bound
by what one thread does: small operators, each holding the GIL to dispatch, or work that runs on
the calling thread only.

Each part is timed by wrapping, for the measurement only, the learner's own methods
(``critic_step``, ``actor_step``, ``_target_action``, ``_twin``, ``_actor_grads``) and the
module's ``apply_gradients`` and ``soft_update``; they are restored afterwards.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import statistics
import time
from collections import Counter
from collections.abc import Callable, Iterator

#: the parts in the order printed: (key, label, indented under a step)
PARTS = (
    ("critic_step", "critic step", False),
    ("target_actor", "target actor", True),
    ("target_critics", "target critics", True),
    ("critics", "critics, forward and backward", True),
    ("critic_tail", "optimiser tail", True),
    ("actor_step", "actor step (its share per update)", False),
    ("actor", "actor loss and gradients", True),
    ("actor_tail", "optimiser tail", True),
    ("soft_update", "soft target update", True),
    ("update", "whole update", False),
)


@contextlib.contextmanager
def timed_parts(learner, seconds: Counter) -> Iterator[None]:
    """While inside, add each part's wall time to ``seconds`` (keys of :data:`PARTS`, but
    ``update``)."""
    from gcnt.rl.td3 import learner as module

    step = ["critic"]  # the step whose optimiser tail runs next

    def timed(fn: Callable, key: Callable[..., str] | str) -> Callable:
        def wrapper(*args, **kwargs):
            name = key(*args) if callable(key) else key
            start = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                seconds[name] += time.perf_counter() - start

        return wrapper

    def entering(name: str, fn: Callable) -> Callable:
        def wrapper(*args, **kwargs):
            step[0] = name
            return fn(*args, **kwargs)

        return timed(wrapper, f"{name}_step")

    def twin_part(critics, *_args) -> str:
        return "target_critics" if critics is learner.target_critics else "critics"

    methods = {
        "critic_step": entering("critic", learner.critic_step),
        "actor_step": entering("actor", learner.actor_step),
        "_target_action": timed(learner._target_action, "target_actor"),
        "_twin": timed(learner._twin, twin_part),
        "_actor_grads": timed(learner._actor_grads, "actor"),
    }
    before = {name: learner.__dict__.get(name) for name in methods}
    functions = {
        "apply_gradients": timed(module.apply_gradients, lambda *a: f"{step[0]}_tail"),
        "soft_update": timed(module.soft_update, "soft_update"),
    }
    saved = {name: getattr(module, name) for name in functions}
    learner.__dict__.update(methods)
    for name, fn in functions.items():
        setattr(module, name, fn)
    try:
        yield
    finally:
        for name, fn in saved.items():
            setattr(module, name, fn)
        for name, fn in before.items():
            if fn is None:
                learner.__dict__.pop(name, None)
            else:
                learner.__dict__[name] = fn


def update_feed(recipe, n_updates: int, rounds: int) -> tuple:
    """A TD3 learner for ``recipe``, the batches of one round in the order the schedule updates
    on them (about ``n_updates / rounds`` updates, whole ``policy_delay`` periods of every batch:
    :func:`gcnt.bench.td3.robot_batches`), and the updates of one such period."""
    from gcnt.bench.td3 import robot_batches
    from gcnt.rl.td3.learner import TD3Learner

    env, batches = robot_batches(recipe)
    learner = TD3Learner(recipe, env)
    period = recipe.td3.policy_delay
    cycle = period * len(batches)
    per_round = max(cycle, -(-n_updates // rounds // cycle) * cycle)
    return learner, [batches[i // period % len(batches)] for i in range(per_round)], cycle


def warm_up(learner, feed: list, cycle: int) -> None:
    """One ``policy_delay`` period of every batch (first calls allocate; the actor step runs)."""
    for b in feed[:cycle]:
        learner.update(b)


def round_seconds(learner, feed: list) -> float:
    """The wall time of one round: an update on each batch of ``feed``, waited for on the
    device."""
    import torch

    start = time.perf_counter()
    losses = [learner.step(b)["loss_critic"] for b in feed]
    torch.stack(losses).sum().item()
    return time.perf_counter() - start


def update_parts(recipe, n_updates: int, rounds: int) -> dict:
    """Each part's ms per update (the median of ``rounds`` rounds of about ``n_updates`` updates
    each, whole ``policy_delay`` periods of every batch; None for a part the update does not
    enter), as the recipe runs the twin critics and, where that is on two threads, in turn on one
    thread (alternate rounds)."""
    import torch

    from gcnt.rl.td3.twin import EachInTurn
    from gcnt.rl.td3.twin_process import InTwoProcesses

    learner, feed, cycle = update_feed(recipe, n_updates, rounds)
    per_round = len(feed)
    runners = {"as_run": learner.twin}
    if learner.twin.parallel:
        runners = {"in_turn": EachInTurn(), **runners}
    for runner in runners.values():
        learner.twin = runner
        warm_up(learner, feed, cycle)
    rows: dict[str, list[dict]] = {name: [] for name in runners}
    for _ in range(rounds):
        for name, runner in runners.items():
            learner.twin = runner
            seconds: Counter = Counter()
            with timed_parts(learner, seconds):
                seconds["update"] = round_seconds(learner, feed)
            rows[name].append({k: 1e3 * v / per_round for k, v in seconds.items()})
    learner.twin = runners["as_run"]
    out: dict = {"threads": torch.get_num_threads(), "updates_per_round": per_round}
    # where the recipe runs critic 2 in a helper process, the parts are this process's share
    out["twin_processes"] = isinstance(runners["as_run"], InTwoProcesses)
    for name, got in rows.items():
        # a part the update never enters (the actor's halves where the critics run in turn): None
        out[name] = {
            key: statistics.median(r.get(key, 0.0) for r in got)
            if any(key in r for r in got)
            else None
            for key, _, _ in PARTS
        }
    return out


def run_parts(args: argparse.Namespace, recipe) -> int:
    """``--parts``: :func:`update_parts`, printed (or as JSON)."""
    out = update_parts(recipe, args.updates, args.rounds)
    out["recipe"], out["schedule"] = args.recipe, recipe.td3.schedule
    if args.json:
        print(json.dumps(out))
        return 0
    two = "in_turn" in out
    at_once = "two processes (this one's parts)" if out["twin_processes"] else "two threads"
    head = f"in turn, one thread -> {at_once} (ratio)" if two else "as the recipe runs it"
    print(
        f"the bare TD3 update by part, ms per update ({recipe.td3.schedule} schedule, "
        f"{out['threads']} torch threads; medians of {args.rounds} rounds of "
        f"{out['updates_per_round']} updates): {head}"
    )
    for key, label, indented in PARTS:
        now = out["as_run"][key]
        if now is None:
            continue
        if key == "critics" and not two:  # one vmapped call: the step backpropagates after it
            label = "critics, forward (the backward in the step)"
        name = f"  {label}" if indented else label
        if not two:
            print(f"  {name:46s} {now:8.2f}")
            continue
        before = out["in_turn"][key]
        ratio = f"({now / before:.2f})" if before else ""
        print(f"  {name:46s} {before:8.2f} -> {now:8.2f} {ratio}")
    run = out["as_run"]
    rest = run["update"] - run["critic_step"] - run["actor_step"]
    print(f"  {'outside the two steps':46s} {rest:8.2f} (the step's batch handling, the losses)")
    return 0
