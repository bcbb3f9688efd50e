"""``gcnt bench-train --processes``: what a second process, rather than a second thread, gets from
the second core for a TD3 update.

The bare update of the recipe's schedule (:func:`gcnt.bench.td3_parts.update_feed`), with the
twin critics in turn on one thread, is timed alone, then in this process and in a second one
(spawned, the same recipe) at once, started together at a barrier. Two processes that each keep
their time alone would do twice the work: the bound on what splitting an update across two
processes could give, against the twin critics' threads, which share one interpreter's lock
(``--parts`` measures those).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import statistics
import threading
from typing import Any

#: how long either process waits at the barrier for the other (building the env and learner
#: takes seconds; a process that fails before it never comes)
BARRIER_S = 600.0


def _in_turn(recipe, n_updates: int, rounds: int):
    """A learner with its twin critics in turn on one thread, warmed up, and a function that
    times ``rounds`` rounds of its update (ms per update each)."""
    from gcnt.bench.td3 import training_threads
    from gcnt.bench.td3_parts import round_seconds, update_feed, warm_up
    from gcnt.rl.td3.twin import EachInTurn

    training_threads(recipe)
    learner, feed, cycle = update_feed(recipe, n_updates, rounds)
    if learner.twin.parallel:
        learner.twin = EachInTurn()
    warm_up(learner, feed, cycle)

    def timed_rounds() -> list[float]:
        return [1e3 * round_seconds(learner, feed) / len(feed) for _ in range(rounds)]

    return timed_rounds, len(feed)


def _second(recipe_path: str, overrides: list[str], n_updates: int, rounds: int, barrier, queue):
    """The spawned process: the same update, its rounds started at the barrier."""
    try:
        from gcnt.recipes import load_recipe

        timed_rounds, _ = _in_turn(load_recipe(recipe_path, overrides), n_updates, rounds)
        barrier.wait(BARRIER_S)
        queue.put(timed_rounds())
    except BaseException as e:
        barrier.abort()
        queue.put(f"{type(e).__name__}: {e}")


def process_scaling(
    recipe, recipe_path: str, overrides: list[str], n_updates: int, rounds: int
) -> dict:
    """ms per update alone, and of each of two processes at once (medians of ``rounds``)."""
    timed_rounds, per_round = _in_turn(recipe, n_updates, rounds)
    alone = timed_rounds()
    ctx = multiprocessing.get_context("spawn")
    barrier, queue = ctx.Barrier(2), ctx.Queue()
    # a daemon: ended with this process, should it stop (Ctrl-C) or fail first
    proc = ctx.Process(
        target=_second,
        args=(recipe_path, list(overrides), n_updates, rounds, barrier, queue),
        daemon=True,
    )
    proc.start()
    try:
        try:
            barrier.wait(BARRIER_S)
        except threading.BrokenBarrierError:
            got = queue.get(timeout=30) if proc.is_alive() or not queue.empty() else None
            raise RuntimeError(f"the second process did not start its rounds: {got}") from None
        together = timed_rounds()
        other: Any = queue.get(timeout=BARRIER_S)
    except BaseException:
        proc.terminate()
        raise
    finally:
        proc.join(30)
        if proc.is_alive():
            proc.terminate()
            proc.join(10)
    if isinstance(other, str):
        raise RuntimeError(f"the second process failed: {other}")
    a, t, o = (statistics.median(x) for x in (alone, together, other))
    return {
        "updates_per_round": per_round,
        "alone_ms": a,
        "together_ms": [t, o],
        # updates per second of both processes at once over one alone: 2.0 if each keeps its pace
        "throughput_ratio": (1 / t + 1 / o) / (1 / a),
    }


def run_processes(args: argparse.Namespace, recipe) -> int:
    """``--processes``: :func:`process_scaling`, printed (or as JSON)."""
    out = process_scaling(recipe, args.recipe, args.overrides, args.updates, args.rounds)
    out["recipe"] = args.recipe
    if args.json:
        print(json.dumps(out))
        return 0
    t, o = out["together_ms"]
    print(
        f"the bare TD3 update, twin critics in turn on one thread (medians of {args.rounds} rounds "
        f"of {out['updates_per_round']} updates): alone {out['alone_ms']:.2f} ms; two processes at "
        f"once {t:.2f} and {o:.2f} ms each: {out['throughput_ratio']:.2f}x the updates per second "
        "of one (2.00: the second core fully used; the twin critics' threads: gcnt bench-train "
        "--parts)"
    )
    return 0
