"""PPO's benchmarks for ``gcnt bench-train``: the bare update of one iteration and training end
to end (:func:`run_ppo`), and collection alone with 1..W worker processes (:func:`run_collect`).

(1) the bare PPO update of one iteration (GAE, epochs of mini-batch steps, statistics; KL early
stop off so that every epoch runs) on data collected once, as env steps/s it could absorb (frames
per iteration / update time) and mini-batch updates/s; (2) ``gcnt train`` for ``--iterations``
iterations end to end (the first one left out as warm-up): env steps/s overall and in collection
alone. The ratio of end-to-end to bare env steps/s is the share of the time spent updating.
"""

from __future__ import annotations

import argparse
import json
import time

from gcnt.bench.common import (
    arithmetic,
    arithmetic_line,
    count_flops,
    device_line,
    matmul_peak_gflops,
    train_quietly,
)


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
    rows = train_quietly(recipe, fpb)[1:]  # the first iteration warms up
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
