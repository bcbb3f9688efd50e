"""``gcnt bench-nn``: forward + backward time of GCNT against its Transformer base.

gcnt bench-nn                          SMPENV: GCNT vs AMORPHEUS, TD3 actor and critic, CPU
gcnt bench-nn --benchmark unimal       UNIMAL: GCNT vs MetaMorph*, PPO actor and critic
gcnt bench-nn --device cuda --repeats 50

Widths (F, A, height map) and the size preset come from the benchmark record (see
``gcnt params`` for the UNIMAL fallback). The batch is every robot × ``--samples-per-robot``
(SMPENV: the 25 CWHH++ training robots; UNIMAL: random trees padded to 12 limbs). Each repeat
times, for each method and role, one forward pass of the whole chain (graph lookup included) on
the mixed batch and one backward pass of a scalar loss. Methods are interleaved within a repeat
so that machine noise hits both alike; the median is reported, with GCNT's overhead as the ratio
of the medians. Threads: torch's default.
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch
from tensordict import TensorDict

from gcnt import keys as K
from gcnt.analysis.params import ALGORITHM, counting_table, network_kwargs, setup_of
from gcnt.nn import count_parameters, make_network

#: GCNT and the Transformer it is built on, per benchmark
BASE = {"smpenv": "amorpheus", "unimal": "metamorph_star"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--benchmark", default="smpenv", help="smpenv (default) or unimal")
    parser.add_argument(
        "--world", default=None, help="world to size the height map for (default: the first)"
    )
    parser.add_argument("--samples-per-robot", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=10, help="timed repeats (after 2 warm-up)")
    parser.add_argument("--device", default="cpu", help="torch device (default: cpu)")
    parser.add_argument("--seed", type=int, default=0)


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def make_batch(
    num_robots: int,
    per_robot: int,
    k: int,
    obs_dim: int,
    num_actions: int,
    device,
    seed: int = 0,
    hfield_dim: int = 0,
) -> TensorDict:
    g = torch.Generator().manual_seed(seed)
    b = num_robots * per_robot
    td = TensorDict(
        {
            K.MORPH_ID: torch.arange(num_robots).repeat_interleave(per_robot),
            "limbs": TensorDict(
                {
                    "obs": torch.randn(b, k, obs_dim, generator=g),
                    "action": torch.rand(b, k, num_actions, generator=g) * 2 - 1,
                },
                [b, k],
            ),
        },
        [b],
    )
    if hfield_dim:
        td.set(K.HFIELD, torch.randn(b, hfield_dim, generator=g))
    return td.to(device)


def _loss(out: TensorDict, role: str) -> torch.Tensor:
    if role == "td3_actor":
        return out.get(K.ACTION).sum()
    if role == "ppo_actor":
        return out.get(K.LOC).sum()
    return out.get(K.Q if role == "td3_critic" else K.VALUE).mean()


def _step(net, role: str, td: TensorDict) -> None:
    # a PPO actor's parameter chain (the distribution adds nothing to time)
    chain = net.module[0] if role == "ppo_actor" else net
    _loss(chain(td.clone(False)), role).backward()
    net.zero_grad(set_to_none=True)


def bench(
    per_robot: int = 100,
    repeats: int = 10,
    device: str = "cpu",
    seed: int = 0,
    benchmark: str = "smpenv",
    world: str | None = None,
) -> dict:
    dev = torch.device(device)
    torch.manual_seed(seed)
    setup = setup_of(benchmark)
    worlds = dict(setup.worlds)
    if world is not None and world not in worlds:
        raise ValueError(f"unknown world {world!r} for {benchmark} (known: {', '.join(worlds)})")
    world = world if world is not None else setup.worlds[0][0]
    hfield = worlds[world]
    algo = ALGORITHM.get(setup.benchmark, "ppo")
    roles = (f"{algo}_actor", f"{algo}_critic")
    methods = ("gcnt", BASE.get(setup.benchmark, "amorpheus"))
    table = counting_table(setup)
    n, k = table.get(K.MASK).shape
    td = make_batch(n, per_robot, k, setup.obs_dim, setup.num_actions, dev, seed, hfield)
    kw = network_kwargs(setup, table, hfield, world)
    nets = {(m, r): make_network(m, r, **kw).to(dev) for m in methods for r in roles}
    times: dict[tuple[str, str], list[float]] = {key: [] for key in nets}
    for i in range(repeats + 2):
        for key, net in nets.items():
            _sync(dev)
            t0 = time.perf_counter()
            _step(net, key[1], td)
            _sync(dev)
            if i >= 2:
                times[key].append(time.perf_counter() - t0)
    med = {key: statistics.median(v) for key, v in times.items()}
    return {
        "benchmark": setup.benchmark,
        "methods": methods,
        "roles": roles,
        "robots": n,
        "batch": td.batch_size[0],
        "limbs": k,
        "threads": torch.get_num_threads(),
        "device": str(dev),
        "median_s": med,
        "params": {key: count_parameters(net) for key, net in nets.items()},
        "ratio": {r: med[(methods[0], r)] / med[(methods[1], r)] for r in roles},
    }


def run(args: argparse.Namespace) -> int:
    res = bench(
        args.samples_per_robot, args.repeats, args.device, args.seed, args.benchmark, args.world
    )
    print(
        f"{res['benchmark']}: {res['robots']} robots × {args.samples_per_robot} samples: "
        f"B={res['batch']}, K={res['limbs']}, device {res['device']}, {res['threads']} threads, "
        f"median of {args.repeats} forward+backward passes"
    )
    head = f"{'role':<12}{'method':<16}{'params':>10}{'ms':>10}"
    print(head)
    print("-" * len(head))
    gcnt, base = res["methods"]
    for r in res["roles"]:
        for m in res["methods"]:
            ms = res["median_s"][(m, r)] * 1e3
            print(f"{r:<12}{m:<16}{res['params'][(m, r)]:>10,}{ms:>10.1f}")
        print(f"{r:<12}{f'{gcnt}/{base}':<26}{res['ratio'][r]:>10.2f}x")
    return 0
