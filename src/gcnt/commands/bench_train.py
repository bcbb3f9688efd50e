"""``gcnt bench-train``: what the training pipeline costs on top of the learning itself.

Default recipe: the quick start (``recipes/quickstart.yaml``: short episodes, so that the paper
schedule, which updates when episodes end, updates within the timed window). In one run: (1) the bare TD3 update rate (same networks, same mini-batch, no env, no buffer) and
(2) ``gcnt train`` with the same recipe end to end, measured after the random-exploration phase:
environment steps per second and updates per second. The ratio of end-to-end to bare updates/s is
the fraction of time spent learning; 1.0 means the env, collector and buffers cost nothing. With
one update per environment step (the paper), env steps/s equals updates/s in the long run; over a
short window the paper schedule's not-yet-trained pending steps make env steps/s look higher.
End to end collects in the recipe's own batches (``td3.steps_per_batch``, 50 lockstep steps by
default), as ``gcnt train`` does.

PPO recipes (``algo: ppo``): (1) the bare PPO update of one iteration (GAE, epochs of mini-batch
steps, statistics; KL early stop off so that every epoch runs) on data collected once, as env
steps/s it could absorb (frames per iteration / update time) and mini-batch updates/s; (2) ``gcnt
train`` for ``--iterations`` iterations end to end (the first one left out as warm-up): env steps/s
overall and in collection alone. The ratio of end-to-end to bare env steps/s is the share of the
time spent updating.

Beside each bare rate: the update's arithmetic, the floating-point operations of its matrix
products (torch's ``FlopCounterMode`` over one update, or one PPO iteration, counted during the
warm-up), the GFLOP/s the bare update achieves with them, and that as a share of the machine's
matmul peak measured in the same run (:func:`matmul_peak_gflops`: a large float32 matrix product
on torch's threads as configured). A small share means the update is bound by per-call
overhead, not by arithmetic.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import os
import re
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

from gcnt.recipes import QUICKSTART, default_recipe


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "recipe",
        nargs="?",
        default=None,
        # written out: argparse's intermixed parsing hides a positional's default while it
        # prints --help, so "%(default)s" would fail there
        help=f"recipe file (default: {QUICKSTART}, found from any folder)",
    )
    p.add_argument("overrides", nargs="*", help="dotted recipe overrides")
    p.add_argument("--updates", type=int, default=30, help="bare updates to time")
    p.add_argument("--steps", type=int, default=400, help="env steps to time end to end")
    p.add_argument("--warmup", type=int, default=200, help="random-action steps before timing")
    p.add_argument(
        "--iterations",
        type=int,
        default=3,
        help="PPO: iterations to run end to end (the first is warm-up)",
    )
    p.add_argument(
        "--stacked-seeds",
        type=int,
        metavar="S",
        help="TD3 instead: bare update time of 1..S seeds stacked (gcnt train --seeds) against "
        "one seed's own update, mixed schedule",
    )
    p.add_argument(
        "--workers",
        metavar="W1,W2,...",
        help="PPO instead: collection alone (no update), env steps/s of the single collector "
        "and of torchrl's multi-process collector with each of these worker counts, in one run",
    )
    p.add_argument("--json", action="store_true", help="print JSON only")


def recipe_and_overrides(recipe: str, overrides: list[str]) -> tuple[str, list[str]]:
    """``gcnt bench-train key=value ...`` without a recipe: the quick start with those
    overrides (argparse takes the first word for the optional recipe); no recipe at all: the
    quick start (:func:`gcnt.recipes.default_recipe`: from any folder)."""
    if recipe is None:
        return default_recipe(), list(overrides)
    if "=" in recipe and not Path(recipe).exists():
        return default_recipe(), [recipe, *overrides]
    return recipe, list(overrides)


def matmul_peak_gflops(
    size: int | None = None, repeats: int = 5, device: str = "cpu", amp: bool = False
) -> float:
    """GFLOP/s of the best of ``repeats`` ``size`` × ``size`` matrix products on ``device``, in
    the update's precision: float32 (on a GPU with torch's TF32 setting as configured), bfloat16
    with ``amp``. The arithmetic limit the updates are measured against. On a CPU the products
    run on torch's threads as configured (size 1024); on a GPU they are timed with CUDA events
    (size 8192, so that the product fills the device)."""
    import torch

    dev = torch.device(device)
    cuda = dev.type == "cuda"
    size = size or (8192 if cuda else 1024)
    dtype = torch.bfloat16 if amp else torch.float32
    a = torch.randn(size, size, device=dev, dtype=dtype)
    b = torch.randn(size, size, device=dev, dtype=dtype)
    torch.mm(a, b)  # warm-up
    best = float("inf")
    for _ in range(repeats):
        if cuda:
            start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
            start.record()
            torch.mm(a, b)
            end.record()
            end.synchronize()
            seconds = start.elapsed_time(end) / 1e3
        else:
            t0 = time.perf_counter()
            torch.mm(a, b)
            seconds = time.perf_counter() - t0
        best = min(best, seconds)
    return 2 * size**3 / best / 1e9


def device_line(device: str) -> str:
    """What the update runs on: the GPU's name and its peak memory so far, or the CPU threads."""
    import torch

    dev = torch.device(device)
    if dev.type == "cuda":
        name = torch.cuda.get_device_name(dev)
        mem = torch.cuda.max_memory_allocated(dev) / 2**30
        return f"device: {name}, {mem:.2f} GiB peak memory allocated"
    return f"device: CPU, {torch.get_num_threads()} torch threads"


def count_flops(fn) -> tuple[int, object]:
    """Floating-point operations of the matrix products ``fn()`` runs (torch's
    ``FlopCounterMode``: matmul, linear, batched and attention products; elementwise work is not
    counted), and what ``fn`` returned."""
    import torch
    from torch.utils import flop_counter as fc

    aten = torch.ops.aten
    # torch's counter has formulas for the GPU attention kernels only; the CPU kernel does the
    # same products
    cpu_attention = {
        aten._scaled_dot_product_flash_attention_for_cpu: lambda q, k, v, *_, **__: (
            fc.sdpa_flop_count(q, k, v)
        ),
        aten._scaled_dot_product_flash_attention_for_cpu_backward: lambda g, q, k, v, *_, **__: (
            fc.sdpa_backward_flop_count(g, q, k, v)
        ),
    }
    counter = fc.FlopCounterMode(display=False, custom_mapping=cpu_attention)
    with counter:
        out = fn()
    return counter.get_total_flops(), out


#: the lines torch's profiler (kineto) writes to the process's stderr whenever it starts and
#: stops, e.g. ``USDT:2026-01-01 10:00:00 123:123 SyncActivityProfilerHandler.cpp:52]
#: profiler_start``
PROFILER_LINE = re.compile(r"^(USDT|STAGE):\d{4}-\d\d-\d\d [\d:.]+ \d+:\d+ \w+\.cpp:\d+\] ")


@contextlib.contextmanager
def without_profiler_lines() -> Iterator[None]:
    """Keep torch's profiler lines (:data:`PROFILER_LINE`, written by C++ straight to file
    descriptor 2) out of the report: stderr goes to a temporary file meanwhile, and every other
    line written there is passed on afterwards."""
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as caught:
        os.dup2(caught.fileno(), 2)
        try:
            yield
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            caught.seek(0)
            text = caught.read().decode(errors="replace")
            kept = [line for line in text.splitlines(True) if not PROFILER_LINE.match(line)]
            sys.stderr.write("".join(kept))
            sys.stderr.flush()


def count_launches(fn, device: str = "cpu") -> int:
    """What bounds a small update from below when its arithmetic is cheap: the calls it makes.
    On a GPU, the device kernels ``fn()`` launches (torch's profiler: events on the CUDA
    device); on a CPU, the operators it dispatches (profiled ``aten::`` ops not called from
    inside another). Each costs a few microseconds whatever its size, so ``count x a few us``
    is the update's launch floor."""
    import torch
    from torch.autograd import DeviceType
    from torch.profiler import ProfilerActivity, profile

    cuda = torch.device(device).type == "cuda"
    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if cuda else [])
    with without_profiler_lines():
        with profile(activities=activities) as prof:
            fn()
            if cuda:
                torch.cuda.synchronize(device)
        events = prof.events()
    if cuda:
        return sum(1 for e in events if e.device_type == DeviceType.CUDA)

    def nested(e) -> bool:
        parent = e.cpu_parent
        while parent is not None:
            if parent.name.startswith("aten::"):
                return True
            parent = parent.cpu_parent
        return False

    return sum(1 for e in events if e.name.startswith("aten::") and not nested(e))


def arithmetic(flops_per_update: float, updates_per_s: float, peak: float) -> dict:
    """The arithmetic figures of an update rate: FLOPs per update, GFLOP/s, share of ``peak``."""
    gflops = flops_per_update * updates_per_s / 1e9
    return {
        "flops_per_update": flops_per_update,
        "gflops_per_s": gflops,
        "share_of_peak": gflops / peak,
    }


def arithmetic_line(a: dict, peak: float, unit: str = "update") -> str:
    return (
        f"       {a['flops_per_update'] / 1e6:,.1f} MFLOP per {unit} in matrix products: "
        f"{a['gflops_per_s']:.2f} GFLOP/s = {100 * a['share_of_peak']:.1f}% of the "
        f"{peak:.1f} GFLOP/s matmul peak"
    )


def launch_line(launches: float, update_ms: float, device: str) -> str:
    """How close an update is to its launch floor: its launches and the time per launch (a few
    microseconds per launch means the launches, not the arithmetic, set the update's time)."""
    import torch

    what = "device kernels" if torch.device(device).type == "cuda" else "dispatched operators"
    return (
        f"       {launches:,.0f} {what} per update: {1e3 * update_ms / max(launches, 1):.1f} us "
        "per launch"
    )


def bare_update_rate(recipe, n_updates: int, rounds: int = 5) -> dict:
    """Updates/s on one fixed mini-batch shaped as the recipe's schedule samples it (median of
    ``rounds`` rounds), and the FLOPs per update (counted over one ``policy_delay`` period of the
    warm-up: a critic step each update, an actor step once). When the learner runs its twin
    critics on two threads (``compile.twin_threads``), the same learner with the critics in turn
    is timed too, in alternate rounds: ``in_turn_updates_per_s``."""
    import statistics

    import torch

    from gcnt.rl.factories import make_env, train_robots
    from gcnt.rl.td3 import replay as rb
    from gcnt.rl.td3.learner import TD3Learner
    from gcnt.rl.td3.twin import InTurn

    c = recipe.td3
    robots = train_robots(recipe)
    env = make_env(recipe, robots)
    steps = -(-c.batch_size // env.batch_size[0]) + 1
    data = env.rollout(steps, break_when_any_done=False)
    replay = rb.RobotReplay(len(robots), capacity=data.numel(), batch_size=c.batch_size)
    replay.extend(data)
    batch = replay.sample_mixed() if c.schedule == "mixed" else replay.sample_robot(0)
    learner = TD3Learner(recipe, env)
    env.close()
    threads = torch.get_num_threads()  # before the twin critics set it to 1
    learner.update(batch)
    period = c.policy_delay
    # on one thread: torch's flop counter sees only the thread it was entered on
    configured, learner.twin = learner.twin, InTurn()
    flops, _ = count_flops(lambda: [learner.update(batch) for _ in range(period)])
    launches = count_launches(lambda: [learner.update(batch) for _ in range(period)], recipe.device)
    runners = {"updates_per_s": configured}
    if configured.parallel:
        # the baseline: the critics in turn with torch's threads as they were
        runners["in_turn_updates_per_s"] = InTurn()
    # whole policy_delay periods per round, so that every round holds the same actor steps
    per_round = max(period, -(-n_updates // rounds // period) * period)
    rates: dict[str, list[float]] = {k: [] for k in runners}
    for _ in range(rounds):
        for key, runner in runners.items():
            learner.twin = runner
            torch.set_num_threads(1 if runner.parallel else threads)
            t0 = time.perf_counter()
            for _ in range(per_round):
                learner.update(batch)
            rates[key].append(per_round / (time.perf_counter() - t0))
    learner.twin = configured
    torch.set_num_threads(1 if configured.parallel else threads)
    out = {k: statistics.median(v) for k, v in rates.items()}
    out["twin_threads"] = configured.parallel
    out["in_turn_threads"] = threads
    out["flops_per_update"] = flops / period
    out["launches_per_update"] = launches / period
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


def _train_quietly(recipe, log_interval: int) -> list[dict]:
    """Train ``recipe`` in a temporary run directory (no logger backend, progress bar,
    checkpoints or evaluation; a metrics row every ``log_interval`` steps); its metrics rows."""
    from gcnt.rl.loop import train
    from gcnt.rl.run_dir import RunDir

    with tempfile.TemporaryDirectory() as tmp:
        recipe.run_dir = tmp
        recipe.logger.backend, recipe.logger.progress = "none", False
        recipe.logger.log_interval = log_interval
        recipe.checkpoint_interval = 10**12
        recipe.eval.episodes = 0
        run = RunDir(tmp)
        run.create(recipe)
        train(recipe, run)
        return run.read_metrics()


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

    warmup = max(warmup, recipe.td3.batch_size * len(train_robots(recipe)))
    recipe.td3.init_random_frames = warmup
    recipe.collector.total_frames = warmup + steps
    all_rows = _train_quietly(recipe, 1)
    random_end = recipe.resolved["init_random_frames"]
    prev = [r for r in all_rows if r["env_steps"] <= random_end]
    rows = [r for r in all_rows if r["env_steps"] > random_end]
    if not prev or not rows:
        from gcnt.recipes import RecipeError

        raise RecipeError(
            f"bench-train: no batch after the random phase ({random_end} env steps) within "
            f"{warmup + steps}: raise --steps"
        )
    secs = sum(
        (r["env_steps"] - p["env_steps"]) / r["env_steps_per_s"]
        for p, r in zip([prev[-1], *rows], rows, strict=False)
    )
    span = rows[-1]["env_steps"] - prev[-1]["env_steps"]
    updates = rows[-1]["updates"] - prev[-1]["updates"]
    return {
        "env_steps_per_s": span / secs,
        "updates_per_s": updates / secs,
        "updates": updates,
        "env_steps": span,
    }


def run(args: argparse.Namespace) -> int:
    from gcnt.recipes import load_recipe

    args.recipe, args.overrides = recipe_and_overrides(args.recipe, args.overrides)
    recipe = load_recipe(args.recipe, args.overrides)
    # the report alone on the terminal: the training it times logs warnings only
    logger = logging.getLogger("gcnt")
    level = logger.level
    logger.setLevel(logging.WARNING)
    try:
        return _measure(args, recipe)
    finally:
        logger.setLevel(level)


def _measure(args: argparse.Namespace, recipe) -> int:
    from gcnt.recipes import RecipeError

    if not args.json:
        print(f"recipe: {args.recipe} ({recipe.algo}, {recipe.network.name})")
    if recipe.algo == "ppo":
        if args.workers:
            return run_collect(args, recipe)
        return run_ppo(args, recipe)
    if recipe.algo != "td3":
        raise RecipeError(
            f"bench-train measures TD3 and PPO recipes; {args.recipe} has algo {recipe.algo}"
        )
    if args.stacked_seeds is not None:
        return run_stacked(args, recipe)
    return run_td3(args, recipe)


def stacked_update_ms(recipe, max_seeds: int, n_updates: int) -> dict:
    """ms per update (critic step, plus the actor step every ``policy_delay``) on one fixed
    mixed mini-batch: one seed's own :class:`TD3Learner` step, and S = 1..``max_seeds`` seeds
    stacked (:class:`StackedTD3Learner`, the same batch and noise for every seed)."""
    import torch

    from gcnt.keys import ACTION
    from gcnt.rl.factories import make_env, train_robots
    from gcnt.rl.td3 import replay as rb
    from gcnt.rl.td3.learner import TD3Learner
    from gcnt.rl.td3.loss import target_noise
    from gcnt.rl.td3.stacked import StackedTD3Learner

    c = recipe.td3
    robots = train_robots(recipe)
    env = make_env(recipe, robots)
    data = env.rollout(-(-c.batch_size // env.batch_size[0]) + 1, break_when_any_done=False)
    replay = rb.RobotReplay(len(robots), capacity=data.numel(), batch_size=c.batch_size)
    replay.extend(data)
    batch = replay.sample_mixed().to(recipe.device)
    learners = []
    for seed in range(max_seeds):
        torch.manual_seed(seed)
        learners.append(TD3Learner(recipe, env))
    env.close()
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
    # the seed's own update may run its twin critics on two threads with one torch thread; the
    # stacked update (one vmap, as gcnt train --seeds runs it) keeps torch's threads
    out["single_threads"] = (
        "twin critics on two threads, 1 torch thread"
        if single.twin.parallel
        else f"{threads} torch threads"
    )
    torch.set_num_threads(threads)
    out["stacked_threads"] = threads
    noise = target_noise(batch.get(ACTION), c.policy_noise, c.noise_clip)
    for s in range(1, max_seeds + 1):
        stacked = StackedTD3Learner(learners[:s])
        out["stacked_ms"][s] = time_steps(
            stacked.step, stacked.stack_batches([batch] * s, [noise] * s)
        )
    return out


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


def run_td3(args: argparse.Namespace, recipe) -> int:
    """Both schedules in one run: the bare update, end to end, and the replay sample time."""
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
    threads = torch.get_num_threads()
    for schedule in ("paper", "mixed"):
        r = copy.deepcopy(recipe)
        r.td3.schedule = schedule
        torch.set_num_threads(threads)  # twin critics set it to 1: each measurement starts alike
        measured = bare_update_rate(r, args.updates)
        bare = measured["updates_per_s"]
        torch.set_num_threads(threads)
        e2e = end_to_end_rate(r, args.warmup, args.steps)
        out["schedules"][schedule] = {
            "bare_updates_per_s": bare,
            "twin_threads": measured["twin_threads"],
            "bare_in_turn_updates_per_s": measured.get("in_turn_updates_per_s"),
            "in_turn_torch_threads": measured["in_turn_threads"],
            "bare_update_ms": 1e3 / bare,
            "arithmetic": arithmetic(measured["flops_per_update"], bare, peak),
            "launches_per_update": measured["launches_per_update"],
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
    for schedule, row in out["schedules"].items():
        print(
            f"{schedule:6s} bare TD3 update {row['bare_updates_per_s']:8.2f} updates/s "
            + (
                f"({row['bare_update_ms']:.1f} ms, twin critics on two threads, 1 torch thread)"
                if row["twin_threads"]
                else f"({row['bare_update_ms']:.1f} ms, {row['in_turn_torch_threads']} torch threads)"
            )
        )
        if row["twin_threads"]:
            turn = row["bare_in_turn_updates_per_s"]
            print(
                f"       the critics in turn on {row['in_turn_torch_threads']} torch threads "
                f"(compile.twin_threads=false): {turn:.2f} updates/s ({1e3 / turn:.1f} ms); "
                f"twin threads are {row['bare_updates_per_s'] / turn:.2f}x that"
            )
        print(arithmetic_line(row["arithmetic"], peak))
        print(launch_line(row["launches_per_update"], row["bare_update_ms"], recipe.device))
        if not row["updates"]:
            print(
                f"{schedule:6s} no update in the {args.steps} timed env steps (the paper schedule "
                "updates when episodes end): raise --steps, or use a recipe with shorter episodes"
            )
            continue
        print(
            f"{schedule:6s} end to end {row['end_to_end_env_steps_per_s']:8.2f} env steps/s, "
            f"{row['end_to_end_updates_per_s']:.2f} updates/s ({row['updates']} updates); "
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


def ppo_bare_rate(recipe) -> dict:
    """One PPO iteration's update (GAE + all epochs, KL stop off) on data collected once."""
    import torch
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    from gcnt.rl.device import on_device
    from gcnt.rl.loop import prepare

    recipe.algo_config.kl_stop = 0.0
    prep = prepare(recipe)
    algo, o = prep.algo, recipe.algo_config
    policy = on_device(algo.policy(), recipe.device)
    with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
        data = prep.env.rollout(o.steps_per_env, policy, break_when_any_done=False)
    # the warm-up iteration counts the FLOPs
    flops, _ = count_flops(lambda: list(algo.process(data.clone(), data.numel())))
    t0 = time.perf_counter()
    updates = len(list(algo.process(data.clone(), data.numel())))
    update_s = time.perf_counter() - t0
    prep.env.close()
    return {"frames": data.numel(), "update_s": update_s, "updates": updates, "flops": flops}


def ppo_end_to_end(recipe, iterations: int) -> dict:
    fpb = recipe.algo_config.num_envs * recipe.algo_config.steps_per_env
    recipe.algo_config.kl_stop = 0.0
    recipe.collector.total_frames = fpb * max(2, iterations)
    rows = _train_quietly(recipe, fpb)[1:]  # the first iteration warms up
    secs = sum(fpb / r["env_steps_per_s"] for r in rows)
    collect = [r["collect_env_steps_per_s"] for r in rows if r.get("collect_env_steps_per_s")]
    return {
        "env_steps_per_s": fpb * len(rows) / secs,
        "collect_env_steps_per_s": sum(collect) / len(collect) if collect else float("nan"),
        "update_s": sum(r["update_s"] for r in rows) / len(rows),
    }


def run_ppo(args: argparse.Namespace, recipe) -> int:
    import torch

    peak = matmul_peak_gflops(device=recipe.device, amp=recipe.compile.amp)
    bare = ppo_bare_rate(recipe)
    e2e = ppo_end_to_end(recipe, args.iterations)
    bare_steps = bare["frames"] / bare["update_s"]
    out = {
        "recipe": args.recipe,
        "algo": "ppo",
        "network": recipe.network.name,
        "collector": recipe.algo_config.collector,
        "frames_per_iteration": bare["frames"],
        "threads": torch.get_num_threads(),
        "bare_update_s": bare["update_s"],
        "bare_updates_per_s": bare["updates"] / bare["update_s"],
        "bare_env_steps_per_s": bare_steps,
        "matmul_peak_gflops": peak,
        # one update = the whole iteration (GAE, every epoch's mini-batch steps)
        "arithmetic": arithmetic(bare["flops"], 1 / bare["update_s"], peak),
        "end_to_end_env_steps_per_s": e2e["env_steps_per_s"],
        "collect_env_steps_per_s": e2e["collect_env_steps_per_s"],
        "end_to_end_update_s": e2e["update_s"],
        "ratio": e2e["env_steps_per_s"] / bare_steps,
    }
    if args.json:
        print(json.dumps(out))
    else:
        print(
            f"bare PPO update:   {bare['update_s']:8.2f} s per iteration of {bare['frames']} "
            f"frames = {bare_steps:.0f} env steps/s, {out['bare_updates_per_s']:.2f} "
            f"mini-batch updates/s ({recipe.network.name}, {out['threads']} torch threads)"
        )
        print(arithmetic_line(out["arithmetic"], peak, "iteration"))
        print(
            f"end to end:        {e2e['env_steps_per_s']:8.2f} env steps/s "
            f"(collection alone {e2e['collect_env_steps_per_s']:.0f}/s, update "
            f"{e2e['update_s']:.2f} s per iteration; collector {out['collector']})"
        )
        print(f"ratio (end-to-end ÷ bare env steps/s): {out['ratio']:.3f}")
        print(device_line(recipe.device))
    return 0


def collect_rate(recipe, workers: int, batches: int) -> dict:
    """Env steps/s of PPO's collection alone over ``batches`` batches of one iteration's frames
    (after one warm-up batch), as ``gcnt train`` collects them: the single collector
    (``workers`` 0) or torchrl's multi-process collector over ``workers`` worker processes; the
    policy's weights are sent to the workers after every batch, as training does."""
    import copy

    import torch

    from gcnt.rl.loop import make_collector, prepare

    r = copy.deepcopy(recipe)
    o = r.algo_config
    o.collector, o.workers = ("multi", workers) if workers else ("single", 1)
    prep = prepare(r)
    settings = prep.algo.collect_settings(0)
    multi = settings.env_makers is not None
    collector = make_collector(r, prep.env, settings)
    if multi:
        prep.env.close()
    frames, times = 0, []
    try:
        t0 = time.perf_counter()
        with torch.no_grad():
            for i, data in enumerate(collector):
                if i:  # the first batch warms up (worker start, first compiled kernels)
                    times.append(time.perf_counter() - t0)
                    frames += data.numel()
                if multi:
                    collector.update_policy_weights_()
                if i == batches:
                    break
                t0 = time.perf_counter()
    finally:
        collector.shutdown()
        if not multi:
            prep.env.close()
    return {"workers": workers, "env_steps_per_s": frames / sum(times), "batches": len(times)}


def run_collect(args: argparse.Namespace, recipe) -> int:
    """``--workers``: the single collector, then each worker count, in one run."""
    from gcnt.envs.stepper import usable_cpus

    counts = [int(w) for w in str(args.workers).split(",") if w.strip()]
    if any(w < 1 for w in counts):
        raise ValueError(f"--workers: counts must be >= 1, got {args.workers}")
    o = recipe.algo_config
    bad = [w for w in counts if o.num_envs % w]
    if bad:
        raise ValueError(f"--workers: {bad} do not divide ppo.num_envs={o.num_envs}")
    batches = max(2, args.iterations)
    single = collect_rate(recipe, 0, batches)
    rows = [collect_rate(recipe, w, batches) for w in counts]
    out = {
        "recipe": args.recipe,
        "frames_per_batch": o.num_envs * o.steps_per_env,
        "single": single,
        "multi": rows,
        "usable_cpus": usable_cpus(),
    }
    if args.json:
        print(json.dumps(out))
        return 0
    base = single["env_steps_per_s"]
    print(
        f"collection alone, {out['frames_per_batch']} frames per batch, {single['batches']} "
        f"timed batches each, {out['usable_cpus']} usable CPUs"
    )
    print(f"single collector        {base:10.0f} env steps/s  1.00x")
    for row in rows:
        rate = row["env_steps_per_s"]
        print(
            f"multi, {row['workers']:2d} worker(s)     {rate:10.0f} env steps/s  {rate / base:.2f}x"
        )
    return 0


# ------------------------------------------------------------ the torchrl baseline of the replay
# torchrl's per-robot buffers routed by ``morph_id``, the layout RobotReplay is measured against
# here and checked against in the tests (same stored rows, same loss).


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
