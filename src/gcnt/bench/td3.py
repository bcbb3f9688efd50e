"""TD3's benchmarks for ``gcnt bench-train``: what an update costs, and what training adds to it.

Default recipe: the quick start (short episodes, so that the paper schedule, which updates when
episodes end, updates within the timed window). For each schedule, in one run:

1. the bare update (:func:`bare_update_rate`): the same networks on one fixed mini-batch shaped
   as the schedule samples it, no env, no buffer. Its updates/s; its operators (device kernels
   on a GPU, dispatched operators on a CPU) for the critic step and for the actor step (one per
   ``policy_delay`` updates) separately; its arithmetic (FLOPs of the matrix products) against
   the machine's matmul peak; and the previous layout's update (the two critics as two networks
   run in turn, ``TD3Learner(pair=True)``) timed in alternate rounds with it, so that the ratio
   new ÷ previous holds under one machine load;
2. ``gcnt train`` with the same recipe end to end (:func:`end_to_end_rate`), measured after the
   random-exploration phase: environment steps per second and updates per second. The ratio of
   end-to-end to bare updates/s is the fraction of time spent learning; 1.0 means the env,
   collector and buffers cost nothing. With one update per environment step (the paper), env
   steps/s equals updates/s in the long run. End to end collects in the recipe's own batches
   (``td3.steps_per_batch``), as ``gcnt train`` does;
3. the replay's mixed sample (:func:`replay_sample_ms`) against torchrl's per-robot buffers.

``--stacked-seeds S`` instead (:func:`run_stacked`): the update of 1..S seeds stacked (``gcnt
train --seeds``) against one seed's own.

The update runs on the torch threads training gives it (:func:`gcnt.rl.td3.learner.
one_update_thread`).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import statistics
import time

from gcnt.bench.common import (
    arithmetic,
    arithmetic_line,
    count_flops,
    count_operators,
    device_line,
    launch_line,
    matmul_peak_gflops,
    matrix_products,
    shapes_peak_gflops,
    train_quietly,
)


@contextlib.contextmanager
def on_this_thread(learner):
    """The learner's twin critics in turn on the calling thread while inside (the same
    operators as on two threads): torch's profiler and FLOP counter see the calling thread
    only, and would miss the critic of the helper thread."""
    from gcnt.rl.td3.twin import EachInTurn, InTurn

    runner = learner.twin
    learner.twin = EachInTurn() if runner.parallel else InTurn()
    try:
        yield learner
    finally:
        learner.twin = runner


def step_operators(learner, batch, device: str) -> dict:
    """Launches of one critic step and of one actor step (:func:`count_launches`), and per
    update (the actor step once every ``policy_delay`` updates), counted on one thread
    (:func:`on_this_thread`)."""
    with on_this_thread(learner):
        # once uncounted: where a helper process ran critic 2, this thread builds its views now
        learner.critic_step(batch)
        learner.actor_step(batch)
        critic, critic_work = count_operators(lambda: learner.critic_step(batch), device)
        actor, actor_work = count_operators(lambda: learner.actor_step(batch), device)
    delay = learner.config.policy_delay
    return {
        "critic_step": critic,
        "actor_step": actor,
        "per_update": critic + actor / delay,
        # of them, the operators that write data (a GPU's kernels; the rest are views)
        "working_per_update": critic_work + actor_work / delay,
    }


def bare_update_rate(recipe, n_updates: int, rounds: int = 5, against=None) -> dict:
    """Updates/s of the learner on fixed mini-batches shaped as the schedule samples them (the
    paper schedule: each robot's batch in turn, :func:`robot_batches`; median of ``rounds``
    rounds), and in alternate rounds of one run: the previous layout (``TD3Learner(pair=True)``:
    two critic networks, run as the recipe runs its critics), where the recipe runs the
    ensemble's members on two threads the ensemble in one vmapped call (``one_call``, the path
    of a GPU or a compiled step), and ``against`` (another recipe: the same update with other
    settings, on its own batches). The operators of each on the first batch
    (:func:`step_operators`) and the FLOPs per update (counted over one ``policy_delay`` period
    of every batch: a critic step each update, an actor step once a period)."""
    import torch

    from gcnt.rl.td3.learner import TD3Learner
    from gcnt.rl.td3.twin_process import InTwoProcesses

    env, batches = robot_batches(recipe)
    learners = {"new": TD3Learner(recipe, env), "previous": TD3Learner(recipe, env, pair=True)}
    feeds = {"new": batches, "previous": batches}
    if learners["new"].twin.parallel:
        learners["one_call"] = TD3Learner(recipe, env, twin_threads=False)
        feeds["one_call"] = batches
    if against is not None:
        other_env, feeds["against"] = robot_batches(against)
        learners["against"] = TD3Learner(against, other_env)
    period = recipe.td3.policy_delay
    out: dict = {"threads": torch.get_num_threads()}
    for name, learner in learners.items():
        for b in feeds[name]:  # warm-up (first calls allocate; the actor step has run)
            for _ in range(period + 1):
                learner.update(b)
        out[name] = {"operators": step_operators(learner, feeds[name][0], recipe.device)}
    with on_this_thread(learners["new"]) as learner:  # both critics' FLOPs counted
        products, (flops, _) = matrix_products(
            lambda: count_flops(lambda: [learner.update(b) for b in batches for _ in range(period)])
        )
    out["flops_per_update"] = flops / (period * len(batches))
    out["shapes_peak"] = shapes_peak_gflops(products, device=recipe.device)
    # whole policy_delay periods of every batch per round: every round holds the same steps
    cycle = period * len(batches)
    per_round = max(cycle, -(-n_updates // rounds // cycle) * cycle)
    seconds: dict[str, list[float]] = {k: [] for k in learners}
    for _ in range(rounds):
        for name, learner in learners.items():
            feed = feeds[name]
            t0 = time.perf_counter()
            rows = [learner.step(feed[i // period % len(feed)]) for i in range(per_round)]
            torch.stack([r["loss_critic"] for r in rows]).sum().item()  # wait for the device
            seconds[name].append((time.perf_counter() - t0) / per_round)
    for name in learners:
        out[name]["update_ms"] = 1e3 * statistics.median(seconds[name])
        out[name]["updates_per_s"] = 1e3 / out[name]["update_ms"]
    out["ratio_to_previous"] = out["new"]["update_ms"] / out["previous"]["update_ms"]
    if against is not None:
        out["ratio_to_against"] = out["new"]["update_ms"] / out["against"]["update_ms"]
    out["twin_threads"] = learners["new"].twin.parallel
    out["twin_processes"] = isinstance(learners["new"].twin, InTwoProcesses)
    return out


def _with_compile(recipe, compiled: bool):
    """A copy of ``recipe`` with ``compile.compile`` set (the rest as the recipe has it)."""
    import copy

    r = copy.deepcopy(recipe)
    r.compile.compile = compiled
    return r


def _threads_for(recipe) -> int:
    """torch's intra-op threads as training would set them for ``recipe``'s update."""
    import torch

    from gcnt.rl.td3.learner import one_update_thread

    return 1 if one_update_thread(recipe) else torch.get_num_threads()


def robot_batches(recipe) -> tuple:
    """The env (closed) and the mini-batches a schedule updates on: one mixed batch, or one batch
    of each robot (the paper schedule: at the robot's own limb count where training cuts it,
    :func:`gcnt.rl.td3.learner.trims_padding`; each robot's shapes compile once)."""
    from gcnt.rl.factories import make_env, train_robots
    from gcnt.rl.td3 import replay as rb
    from gcnt.rl.td3.learner import trims_padding

    c = recipe.td3
    robots = train_robots(recipe)
    env = make_env(recipe, robots)
    data = env.rollout(-(-c.batch_size // env.batch_size[0]) + 1, break_when_any_done=False)
    env.close()
    replay = rb.RobotReplay(len(robots), capacity=data.numel(), batch_size=c.batch_size)
    replay.extend(data)
    if c.schedule == "mixed":
        return env, [replay.sample_mixed().to(recipe.device)]
    cut = trims_padding(recipe)
    return env, [
        replay.sample_robot(i, limbs=r.num_limbs if cut else None).to(recipe.device)
        for i, r in enumerate(robots)
    ]


def compiled_vs_eager(
    recipe, n_updates: int, rounds: int = 5, compiled_threads: int | None = None
) -> dict:
    """The bare update compiled (``compile.compile=true``) against eager, each on the torch
    threads training gives it (``compiled_threads``: the compiled one on these instead; inductor
    generates its kernels for the threads set when it compiles), in alternate rounds of one run
    (median ms per update), and the compile time: the first updates of the compiled learner (each
    of the schedule's batch shapes through the critic and the actor step: both losses' forward
    and backward graphs) less as many compiled updates once warm."""
    import torch

    from gcnt.rl.accelerate import compile_seconds
    from gcnt.rl.td3.learner import TD3Learner

    env, batches = robot_batches(recipe)
    period = recipe.td3.policy_delay
    learners, threads = {}, {}
    for name, compiled in (("eager", False), ("compiled", True)):
        r = _with_compile(recipe, compiled)
        threads[name] = (
            _threads_for(r) if not compiled or not compiled_threads else compiled_threads
        )
        torch.manual_seed(0)
        learners[name] = TD3Learner(r, env)
    out: dict = {"threads": threads}
    first: dict[str, float] = {}
    for name, learner in learners.items():
        torch.set_num_threads(threads[name])
        t0 = time.perf_counter()
        for b in batches:  # every shape through both steps
            for _ in range(period):
                learner.update(b)
        first[name] = time.perf_counter() - t0
    calls = period * len(batches)
    per_round = max(period, -(-n_updates // rounds // period) * period)
    seconds: dict[str, list[float]] = {k: [] for k in learners}
    for i in range(rounds):
        for name, learner in learners.items():
            torch.set_num_threads(threads[name])
            b = batches[i % len(batches)]
            t0 = time.perf_counter()
            rows = [learner.step(b) for _ in range(per_round)]
            torch.stack([r["loss_critic"] for r in rows]).sum().item()
            seconds[name].append((time.perf_counter() - t0) / per_round)
    for name in learners:
        out[f"{name}_update_ms"] = 1e3 * statistics.median(seconds[name])
    c = learners["compiled"]
    out["compile_s"] = first["compiled"] - calls * out["compiled_update_ms"] / 1e3
    out["first_calls_s"] = compile_seconds(c.critic_step, c.actor_step)
    out["ratio"] = out["compiled_update_ms"] / out["eager_update_ms"]
    return out


def matmul_precision_check(recipe, n_updates: int, rounds: int = 5) -> dict:
    """The eager bare update with ``torch.set_float32_matmul_precision("medium")`` against the
    default ("highest") in alternate rounds (median ms), and how far the weights of two learners
    from the same initial weights, fed the same batch and noise, are apart after ``n_updates``
    updates under each (largest absolute difference over every online parameter)."""
    import torch

    from gcnt.rl.td3.learner import TD3Learner

    env, batches = robot_batches(recipe)
    r = _with_compile(recipe, False)
    torch.set_num_threads(_threads_for(r))
    learners = {}
    for name in ("highest", "medium"):
        torch.manual_seed(0)
        learners[name] = TD3Learner(r, env)
    before = torch.get_float32_matmul_precision()
    try:
        for name, learner in learners.items():
            torch.set_float32_matmul_precision(name)
            for k in range(n_updates):
                torch.manual_seed(1000 + k)  # the same target noise for both
                learner.update(batches[k % len(batches)])
        diff = max(
            (a - b).abs().max().item()
            for a, b in zip(learners["highest"]._online, learners["medium"]._online, strict=True)
        )
        scale = max(a.abs().max().item() for a in learners["highest"]._online)
        period = recipe.td3.policy_delay
        per_round = max(period, -(-n_updates // rounds // period) * period)
        seconds: dict[str, list[float]] = {k: [] for k in learners}
        for i in range(rounds):
            for name, learner in learners.items():
                torch.set_float32_matmul_precision(name)
                b = batches[i % len(batches)]
                t0 = time.perf_counter()
                rows = [learner.step(b) for _ in range(per_round)]
                torch.stack([x["loss_critic"] for x in rows]).sum().item()
                seconds[name].append((time.perf_counter() - t0) / per_round)
    finally:
        torch.set_float32_matmul_precision(before)
    out = {f"{k}_update_ms": 1e3 * statistics.median(v) for k, v in seconds.items()}
    out["ratio"] = out["medium_update_ms"] / out["highest_update_ms"]
    out["max_weight_diff"] = diff
    out["max_weight"] = scale
    out["updates_compared"] = n_updates
    return out


def replay_sample_ms(recipe, repeats: int = 50, capacity: int = 1000) -> dict:
    """ms per mixed mini-batch (batch_size of every robot): torchrl's per-robot
    ReplayBufferEnsemble (the previous layout) against the one [robots, capacity] storage."""
    from gcnt.rl.factories import make_env, train_robots
    from gcnt.rl.td3 import replay as rb

    c = recipe.td3
    robots = train_robots(recipe)
    env = make_env(recipe, robots)
    data = env.rollout(max(c.batch_size, 20), break_when_any_done=False)
    env.close()
    one = rb.RobotReplay(len(robots), capacity, c.batch_size)
    one.extend(data)
    ensemble = make_ensemble(len(robots), capacity, c.batch_size)
    ensemble_store(ensemble, data)
    out = {}
    for name, sample in (
        ("ensemble", lambda: ensemble_sample_mixed(ensemble)),
        ("one_storage", one.sample_mixed),
    ):
        sample()
        t0 = time.perf_counter()
        for _ in range(repeats):
            sample()
        out[name] = (time.perf_counter() - t0) / repeats * 1e3
    return out


def end_to_end_rate(recipe, warmup: int, steps: int) -> dict:
    """Env steps/s and updates/s of ``gcnt train`` over ``steps`` env steps after ``warmup``
    random ones, collected in the recipe's own batches (``td3.steps_per_batch`` lockstep steps).
    The warm-up covers at least a mini-batch of every robot, so that each timed step is followed
    by its updates (the schedule waits for full mini-batches: steps before that would count as
    time without updates).

    A metrics row is logged after every collected batch, with the rates of that batch alone;
    the timed window is the batches the policy acted in (after the random phase, rounded up to
    whole batches as training rounds it): their steps, updates and seconds summed. The batch
    that ends the random phase is left out: it is collected with random actions."""
    from gcnt.rl.factories import train_robots

    robots = len(train_robots(recipe))
    warmup = max(warmup, recipe.td3.batch_size * robots)
    recipe.td3.init_random_frames = warmup
    recipe.td3.random_counted = "total"  # the warm-up is over all robots, whatever the recipe's
    # training rounds the random phase up to whole batches: the timed steps come after that
    batch = robots * recipe.td3.steps_per_batch
    recipe.collector.total_frames = -(-warmup // batch) * batch + max(steps, batch)
    all_rows = train_quietly(recipe, 1)
    random_end = recipe.resolved["init_random_frames"]
    prev = [r for r in all_rows if r["env_steps"] <= random_end]
    rows = [r for r in all_rows if r["env_steps"] > random_end]
    if not prev or not rows:
        from gcnt.recipes import RecipeError

        raise RecipeError(
            f"bench-train: no batch after the random phase ({random_end} env steps) within "
            f"{warmup + steps}: raise --steps"
        )
    start, rows, rounds = _whole_rounds(prev[-1], rows, recipe.td3.schedule)
    secs = sum(
        (r["env_steps"] - p["env_steps"]) / r["env_steps_per_s"]
        for p, r in zip([start, *rows], rows, strict=False)
    )
    span = rows[-1]["env_steps"] - start["env_steps"] if rows else 0
    updates = rows[-1]["updates"] - start["updates"] if rows else 0
    return {
        "env_steps_per_s": span / secs if secs else float("nan"),
        "updates_per_s": updates / secs if secs else float("nan"),
        "updates": updates,
        "env_steps": span,
        "rounds": rounds,
    }


def _whole_rounds(start: dict, rows: list[dict], schedule: str) -> tuple[dict, list[dict], int]:
    """The timed window as whole collection rounds: under the paper schedule (updates only when
    every robot has ended an episode), from the end of the first update phase to the end of the
    last (``rows`` after ``start``; an empty window when fewer than two phases fell in it), so
    that its steps and updates are those of whole rounds; under the mixed schedule, every batch
    (each ends with its updates). Also the number of rounds (update phases) in the window."""
    before = [start, *rows[:-1]]
    ends = [
        i for i, (p, r) in enumerate(zip(before, rows, strict=True)) if r["updates"] > p["updates"]
    ]
    if schedule != "paper":
        return start, rows, len(ends)
    if len(ends) < 2:
        return start, [], 0
    return rows[ends[0]], rows[ends[0] + 1 : ends[-1] + 1], len(ends) - 1


def stacked_update_ms(recipe, max_seeds: int, n_updates: int) -> dict:
    """ms per update (critic step, plus the actor step every ``policy_delay``) on one fixed
    mixed mini-batch: one seed's own :class:`TD3Learner` step, and S = 1..``max_seeds`` seeds
    stacked (:class:`StackedTD3Learner`, the same batch and noise for every seed)."""
    import torch

    from gcnt.keys import ACTION
    from gcnt.rl.td3.learner import TD3Learner
    from gcnt.rl.td3.loss import target_noise
    from gcnt.rl.td3.stacked import StackedTD3Learner

    c = recipe.td3
    env, (batch, *_) = robot_batches(recipe)  # mixed: the one batch
    learners = []
    for seed in range(max_seeds):
        torch.manual_seed(seed)
        learners.append(TD3Learner(recipe, env))
    single = TD3Learner(recipe, env)

    def time_steps(step, arg) -> float:
        for _ in range(2 * c.policy_delay):  # warm-up
            step(arg)
        t0 = time.perf_counter()
        out = [step(arg) for _ in range(n_updates)]
        torch.stack([row["loss_critic"] for row in out]).sum().item()  # wait for the device
        return (time.perf_counter() - t0) / n_updates * 1e3

    threads = torch.get_num_threads()
    out = {"single_ms": time_steps(single.step, batch), "stacked_ms": {}}
    out["single_threads"] = f"{threads} torch threads"
    out["stacked_threads"] = threads
    noise = target_noise(batch.get(ACTION), c.policy_noise, c.noise_clip)
    for s in range(1, max_seeds + 1):
        stacked = StackedTD3Learner(learners[:s])
        out["stacked_ms"][s] = time_steps(
            stacked.step, stacked.stack_batches([batch] * s, [noise] * s)
        )
    return out


def training_threads(recipe) -> None:
    """torch's intra-op threads as ``gcnt train`` sets them for ``recipe``'s TD3 update."""
    import torch

    from gcnt.rl.td3.learner import one_update_thread

    if one_update_thread(recipe):
        torch.set_num_threads(1)


def run_stacked(args: argparse.Namespace, recipe) -> int:
    """``--stacked-seeds S``: the stacked update against one seed's, in one run."""

    from gcnt.recipes import RecipeError

    if args.stacked_seeds < 1:
        raise RecipeError(f"--stacked-seeds must be >= 1, got {args.stacked_seeds}")
    recipe.td3.schedule = "mixed"
    ms = stacked_update_ms(recipe, args.stacked_seeds, args.updates)
    out = {
        "recipe": args.recipe,
        "algo": "td3",
        "network": recipe.network.name,
        "device": recipe.device,
        "batch_size": recipe.td3.batch_size,
        "single_seed_threads": ms["single_threads"],
        "stacked_torch_threads": ms["stacked_threads"],
        "single_seed_update_ms": ms["single_ms"],
        "stacked_update_ms": ms["stacked_ms"],
        # time of S seeds' updates made together, in units of one seed's own update
        "ratio": {s: t / ms["single_ms"] for s, t in ms["stacked_ms"].items()},
    }
    if args.json:
        print(json.dumps(out))
        return 0
    print(
        f"one seed's own TD3 update: {ms['single_ms']:.2f} ms ({recipe.network.name}, "
        f"mixed batch of {recipe.td3.batch_size} per robot, {ms['single_threads']})"
    )
    for s, t in ms["stacked_ms"].items():
        print(
            f"{s} seed(s) stacked ({ms['stacked_threads']} torch threads): {t:8.2f} ms per update "
            "of all of them = "
            f"{out['ratio'][s]:.2f}x one seed's update ({out['ratio'][s] / s:.2f}x per seed)"
        )
    return 0


def run_commits(args: argparse.Namespace) -> int:
    """``--commits A,B``: :func:`gcnt.bench.commits.compare_commits`, printed."""
    from gcnt.bench.commits import CommitBenchError, compare_commits
    from gcnt.recipes import RecipeError

    commits = [c for c in args.commits.split(",") if c]
    if len(commits) != 2:
        raise RecipeError(f"--commits takes two commits, A,B; got {args.commits!r}")
    try:
        out = compare_commits(args.recipe, args.overrides, commits, args.updates, args.rounds)
    except CommitBenchError as e:
        raise RecipeError(str(e)) from None
    if args.json:
        print(json.dumps(out))
        return 0
    for c, sha in out["commits"].items():
        rounds = ", ".join(f"{x:.1f}" for x in out["rounds_ms"][c])
        print(
            f"{c:>12s} ({sha[:9]}) bare TD3 update {out['update_ms'][c]:8.2f} ms (rounds: {rounds})"
        )
    a, b = commits
    print(
        f"{b} ÷ {a}: {out['ratio']:.3f} (medians of {args.rounds} alternate rounds; each a fresh "
        "process per commit, on the torch threads training gives the update)"
    )
    return 0


def run_td3(args: argparse.Namespace, recipe) -> int:
    """Both schedules in one run: the bare update (new and previous), end to end, and the
    replay sample time."""
    import copy

    import torch

    peak = matmul_peak_gflops(device=recipe.device, amp=recipe.compile.amp)
    out = {
        "recipe": args.recipe,
        "algo": "td3",
        "network": recipe.network.name,
        "batch_size": recipe.td3.batch_size,
        "updates_per_step": recipe.td3.updates_per_step,
        "matmul_peak_gflops": peak,
        "replay_sample_ms": replay_sample_ms(recipe),
        "schedules": {},
    }
    for schedule in ("paper", "mixed"):
        r = copy.deepcopy(recipe)
        r.td3.schedule = schedule
        against = None
        if args.against:
            from gcnt.recipes import load_recipe

            against = load_recipe(args.recipe, [*args.overrides, *args.against])
            against.td3.schedule = schedule
        m = bare_update_rate(r, args.updates, rounds=args.rounds, against=against)
        bare = m["new"]["updates_per_s"]
        compiled = compiled_vs_eager(r, args.updates) if args.compiled else None
        e2e = end_to_end_rate(r, args.warmup, args.steps)
        out["schedules"][schedule] = {
            "bare_updates_per_s": bare,
            "bare_update_ms": m["new"]["update_ms"],
            "torch_threads": m["threads"],
            "operators": m["new"]["operators"],
            "previous_update_ms": m["previous"]["update_ms"],
            "previous_operators": m["previous"]["operators"],
            "twin_threads": m["twin_threads"],
            "twin_processes": m["twin_processes"],
            "one_call": m.get("one_call"),
            # new ÷ previous bare update time, alternate rounds of one run
            "ratio_to_previous": m["ratio_to_previous"],
            "against": m.get("against"),
            "ratio_to_against": m.get("ratio_to_against"),
            "arithmetic": arithmetic(m["flops_per_update"], bare, peak),
            # the matmul rate at the update's own product shapes, and the update's share of it
            "shapes_peak_gflops": m["shapes_peak"]["gflops"],
            "share_of_shapes_peak": arithmetic(
                m["flops_per_update"], bare, m["shapes_peak"]["gflops"]
            )["share_of_peak"],
            "compiled": compiled,
            "rounds": e2e["rounds"],
            "launches_per_update": m["new"]["operators"]["per_update"],
            "end_to_end_env_steps_per_s": e2e["env_steps_per_s"],
            "end_to_end_updates_per_s": e2e["updates_per_s"],
            "updates": e2e["updates"],
            # time per update end to end vs bare: what the env, collector and replay add
            "ratio": e2e["updates_per_s"] / bare if e2e["updates"] else float("nan"),
        }
    if args.json:
        print(json.dumps(out))
        return 0
    rs = out["replay_sample_ms"]
    print(
        f"replay sample (mixed, {recipe.td3.batch_size} of each robot): ensemble "
        f"{rs['ensemble']:.2f} ms, one storage {rs['one_storage']:.2f} ms"
    )
    what = "device kernels" if torch.device(recipe.device).type == "cuda" else "operators"
    for schedule, row in out["schedules"].items():
        ops, prev = row["operators"], row["previous_operators"]
        print(
            f"{schedule:6s} bare TD3 update {row['bare_updates_per_s']:8.2f} updates/s "
            f"({row['bare_update_ms']:.1f} ms, {row['torch_threads']} torch threads)"
        )
        print(
            f"       {what}: critic step {ops['critic_step']:,}, actor step {ops['actor_step']:,} "
            f"(every {recipe.td3.policy_delay} updates): {ops['per_update']:,.0f} per update; "
            f"previous (two critic networks) {prev['critic_step']:,} / {prev['actor_step']:,}: "
            f"{prev['per_update']:,.0f}"
        )
        if what == "operators":
            print(
                f"       of them writing data (a GPU's kernels; the rest are views): "
                f"{ops['working_per_update']:,.0f} per update, previous "
                f"{prev['working_per_update']:,.0f}"
            )
        how = "members in one call"
        if row["twin_threads"]:
            two = "processes" if row["twin_processes"] else "threads"
            how = f"members on two {two}"
        print(
            f"       critic ensemble, {how}; previous update (two critic networks) "
            f"{row['previous_update_ms']:.1f} ms; new ÷ previous {row['ratio_to_previous']:.2f} "
            "(alternate rounds)"
        )
        if row["against"]:
            print(
                f"       against ({' '.join(args.against)}): {row['against']['update_ms']:.1f} "
                f"ms; recipe ÷ against {row['ratio_to_against']:.3f} (alternate rounds)"
            )
        one = row["one_call"]
        if one:
            print(
                f"       the ensemble in one vmapped call (a GPU's path): {one['update_ms']:.1f} "
                f"ms, {one['operators']['per_update']:,.0f} {what} per update "
                f"({one['operators']['working_per_update']:,.0f} writing data)"
            )
        print(arithmetic_line(row["arithmetic"], peak))
        print(
            f"       matmul rate at the update's own product shapes (each alone, its call "
            f"included): {row['shapes_peak_gflops']:.1f} GFLOP/s; the update runs at "
            f"{100 * row['share_of_shapes_peak']:.1f}% of it"
        )
        if row["compiled"]:
            c = row["compiled"]
            print(
                f"       compiled ÷ eager bare update {c['ratio']:.2f} (compiled "
                f"{c['compiled_update_ms']:.1f} ms on {c['threads']['compiled']} torch threads, "
                f"eager {c['eager_update_ms']:.1f} ms on {c['threads']['eager']}; alternate "
                "rounds)"
            )
            print(f"       compile time {c['compile_s']:.1f} s (first calls, every batch shape)")
        print(launch_line(row["launches_per_update"], row["bare_update_ms"], recipe.device))
        if not row["updates"]:
            print(
                f"{schedule:6s} no whole round in the {args.steps} timed env steps (the paper "
                "schedule updates when every robot has ended an episode; the window runs from "
                "one update phase to a later one): raise --steps, or use a recipe with shorter "
                "episodes"
            )
            continue
        rounds = f", {row['rounds']} whole rounds" if schedule == "paper" else ""
        print(
            f"{schedule:6s} end to end {row['end_to_end_env_steps_per_s']:8.2f} env steps/s, "
            f"{row['end_to_end_updates_per_s']:.2f} updates/s ({row['updates']} updates"
            f"{rounds}); "
            f"ratio to the bare update {row['ratio']:.3f} (the share of the time spent in "
            "updates; the rest is the env, collection and replay)"
        )
        if row["ratio"] > 1.05:
            print(
                "       a share above 1 cannot be: the machine's load changed between the bare "
                "and the end-to-end measurement; measure on an idle machine"
            )
    print(device_line(recipe.device))
    return 0


def make_ensemble(num_robots: int, capacity: int, batch_size: int, device="cpu"):
    """Per-robot torchrl buffers (a ``ReplayBufferEnsemble``) routed by ``morph_id``: what
    :class:`~gcnt.rl.td3.replay.RobotReplay` is measured against."""
    from torchrl.data import LazyTensorStorage, ReplayBuffer, ReplayBufferEnsemble

    from gcnt.keys import MORPH_ID

    buffers = [
        ReplayBuffer(storage=LazyTensorStorage(capacity, device=device), batch_size=batch_size)
        for _ in range(num_robots)
    ]
    return ReplayBufferEnsemble(
        *buffers, routing_key=MORPH_ID, sample_from_all=True, batch_size=batch_size * num_robots
    )


def ensemble_store(replay, data) -> int:
    from gcnt.rl.td3 import replay as rb

    flat = data.select(*rb.STORED_KEYS).reshape(-1)
    replay.extend(flat)
    return flat.numel()


def ensemble_sample_mixed(replay):
    return replay.sample().exclude("index").reshape(-1)
