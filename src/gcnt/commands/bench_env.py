"""``gcnt bench-env``: a benchmark's batched env against the physical limit of raw ``mj_step``.

The env is built through the benchmark registry (``--benchmark``, default smpenv:
``get_benchmark(name).make_env``). Measures, in one run and interleaved round by round (so that
load from other processes hits both alike):

(a) env steps/s — sub-env control steps per second (N × batched steps), with observations,
    uniform random actions, rewards, terminations and the partial resets of
    ``step_and_maybe_reset`` (the path a collector takes);
(b) raw steps/s — a plain single-threaded loop over the same robots' ``MjData`` (same models and
    frame skip): random controls, ``mj_step`` × frame_skip, and ``mj_resetData`` when the env's
    task rules end the episode or the time limit is reached (so that both loops simulate
    comparable states). No observations, no torch.

and prints both and their ratio (env / raw; above 1 means the env's threads hide featurisation and
TorchRL overhead behind parallel physics). On worlds with a height map (UNIMAL MT and Obstacles)
it also prints the height map's share of the env's step time. The robots default to the
benchmark's training split (``Benchmark.train_split``: CWHH++:train, Unimal:train), one sub-env
each; ``--world`` picks the benchmark's world.
"""

from __future__ import annotations

import argparse
import json
import logging
import statistics
import time

import mujoco
import numpy as np
import torch

from gcnt import keys as K

log = logging.getLogger(__name__)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--benchmark", default="smpenv", help="benchmark whose env to measure (default smpenv)"
    )
    p.add_argument(
        "--world", default=None, help="the benchmark's world, if it has several (default: its own)"
    )
    p.add_argument(
        "--robots",
        nargs="+",
        default=None,
        help="robot names, .xml paths or Benchmark:split (default: the benchmark's training split, "
        "e.g. CWHH++:train for smpenv, Unimal:train for unimal)",
    )
    p.add_argument("--copies", type=int, default=1, help="sub-envs per robot (default 1)")
    p.add_argument("--steps", type=int, default=300, help="batched steps per round (default 300)")
    p.add_argument("--rounds", type=int, default=5, help="interleaved rounds (default 5)")
    p.add_argument(
        "--threads",
        type=int,
        default=None,
        help="env physics threads (default: automatic, up to all CPUs)",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", action="store_true", help="print one JSON object instead of text")


def _env_round(env, td, actions: torch.Tensor, steps: int):
    t = time.perf_counter()
    for s in range(steps):
        td.set(K.ACTION, actions[s % len(actions)])
        _, td = env.step_and_maybe_reset(td)
    return time.perf_counter() - t, td


class _RawLoop:
    """The same robots as plain MjData, stepped one after another on one thread."""

    def __init__(self, env, seed: int):
        self.items = []
        for i, r in enumerate(env.robots):
            model = env.sim(i)[0]
            data = mujoco.MjData(model)
            rules = env.rules_factory(r, model, float(env.dt[i]))
            rules.begin(data)
            self.items.append((model, data, data.ctrl, rules))
        self.frame_skip = env.frame_skip
        self.limit = env.max_episode_steps
        self.elapsed = np.zeros(len(self.items), np.int64)
        rng = np.random.default_rng(seed)
        self.ctrls = [rng.uniform(-1, 1, (64, m.nu)) for m, *_ in self.items]
        self.resets = 0

    def round(self, steps: int) -> float:
        fs, step, reset = self.frame_skip, mujoco.mj_step, mujoco.mj_resetData
        t = time.perf_counter()
        for s in range(steps):
            for j, (m, d, ctrl, rules) in enumerate(self.items):
                ctrl[:] = self.ctrls[j][s % 64]
                step(m, d, fs)
                self.elapsed[j] += 1
                if rules.step(d, 0.0)[1] or self.elapsed[j] >= self.limit:
                    reset(m, d)
                    rules.begin(d)
                    self.elapsed[j] = 0
                    self.resets += 1
        return time.perf_counter() - t


def run(args: argparse.Namespace) -> int:
    from gcnt.envs.benchmark import get_benchmark
    from gcnt.morphology.catalogues import resolve_robots

    bench = get_benchmark(args.benchmark)
    specs = args.robots
    if not specs:
        if not bench.train_split:
            raise ValueError(
                f"benchmark {bench.name!r} names no training split (Benchmark.train_split); "
                "pass --robots"
            )
        specs = [bench.train_split]
    robots = resolve_robots(specs) * args.copies
    env = bench.make_env(robots, seed=args.seed, num_threads=args.threads, world=args.world)
    world = bench.check_world(args.world)
    n = len(robots)
    gen = torch.Generator().manual_seed(args.seed)
    shape = env.action_spec[K.ACTION].shape
    actions = torch.rand((64, *shape), generator=gen) * 2 - 1
    raw = _RawLoop(env, args.seed)

    td = env.reset()
    _, td = _env_round(env, td, actions, 20)  # warm up both
    raw.round(20)
    env_rates, raw_rates = [], []
    hfield_start = getattr(env, "hfield_seconds", None)
    env_s = 0.0
    for _ in range(args.rounds):
        dt, td = _env_round(env, td, actions, args.steps)
        env_s += dt
        env_rates.append(n * args.steps / dt)
        raw_rates.append(n * args.steps / raw.round(args.steps))
    hfield_share = None
    if hfield_start is not None and env.observation_spec.get(K.HFIELD, None) is not None:
        hfield_share = (env.hfield_seconds - hfield_start) / env_s
    env.close()
    used = env.thread_use
    multi = sum(v for k, v in used.items() if k > 1) / max(1, sum(used.values()))
    env_med, raw_med = statistics.median(env_rates), statistics.median(raw_rates)
    result = {
        "benchmark": bench.name,
        "world": world,
        "robots": n,
        "distinct_robots": len(env.distinct_robots),
        "max_limbs": env.max_limbs,
        "threads": env.num_threads,
        "share_of_steps_multithreaded": round(multi, 3),
        "frame_skip": env.frame_skip,
        "batched_steps_per_round": args.steps,
        "rounds": args.rounds,
        "env_steps_per_s": round(env_med, 1),
        "raw_steps_per_s": round(raw_med, 1),
        "ratio": round(env_med / raw_med, 3),
        "env_steps_per_s_rounds": [round(x, 1) for x in env_rates],
        "raw_steps_per_s_rounds": [round(x, 1) for x in raw_rates],
        "ratio_rounds": [round(a / b, 3) for a, b in zip(env_rates, raw_rates, strict=True)],
        "hfield_share_of_env_time": None if hfield_share is None else round(hfield_share, 4),
    }
    if args.json:
        print(json.dumps(result))
    else:
        where = f", world {world}" if world else ""
        hf = (
            ""
            if hfield_share is None
            else f"  height map share of env step time     : {hfield_share:10.1%}\n"
        )
        print(
            f"{env.name} ({bench.name}{where}): {n} sub-envs ({result['distinct_robots']} distinct robots), K={env.max_limbs}, "
            f"up to {env.num_threads} threads ({multi:.0%} of steps used more than one), "
            f"frame_skip {env.frame_skip}; median of {args.rounds} "
            f"interleaved rounds of {args.steps} batched steps\n"
            f"  env steps/s (obs, random actions, resets): {env_med:10.1f}\n"
            f"  raw mj_step loop steps/s (1 thread)      : {raw_med:10.1f}\n"
            f"  ratio env/raw                            : {env_med / raw_med:10.3f}\n"
            f"{hf}"
            f"  per round ratios: {result['ratio_rounds']}"
        )
    return 0
