"""``gcnt bench-nn``: forward + backward time of GCNT against AMORPHEUS at the paper's SMPENV sizes.

gcnt bench-nn                          25 CWHH++ robots × 100 samples (B = 2500, K = 9), CPU
gcnt bench-nn --device cuda --repeats 50

Each repeat times, for each method and role (TD3 actor, TD3 critic), one forward pass of the whole
chain (graph lookup included) on the mixed batch and one backward pass of a scalar loss. Methods
are interleaved within a repeat so that machine noise hits both alike; the median is reported,
with GCNT's overhead as the ratio of the medians. Threads: torch's default.
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch
from tensordict import TensorDict

from gcnt.envs.robot_table import robot_table
from gcnt.nn import count_parameters, make_network
from gcnt.nn.synthetic import smpenv_like_robots

METHODS = ("gcnt", "amorpheus")
ROLES = ("td3_actor", "td3_critic")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--samples-per-robot", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=10, help="timed repeats (after 2 warm-up)")
    parser.add_argument("--device", default="cpu", help="torch device (default: cpu)")
    parser.add_argument("--seed", type=int, default=0)


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def make_batch(num_robots: int, per_robot: int, k: int, device, seed: int = 0) -> TensorDict:
    g = torch.Generator().manual_seed(seed)
    b = num_robots * per_robot
    return TensorDict(
        {
            "morph_id": torch.arange(num_robots).repeat_interleave(per_robot),
            "limbs": TensorDict(
                {
                    "obs": torch.randn(b, k, 19, generator=g),
                    "action": torch.rand(b, k, 1, generator=g) * 2 - 1,
                },
                [b, k],
            ),
        },
        [b],
    ).to(device)


def _step(net, role: str, td: TensorDict) -> None:
    out = net(td.clone(False))
    loss = out["limbs", "action"].sum() if role == "td3_actor" else out["state_action_value"].mean()
    loss.backward()
    net.zero_grad(set_to_none=True)


def bench(per_robot: int = 100, repeats: int = 10, device: str = "cpu", seed: int = 0) -> dict:
    dev = torch.device(device)
    torch.manual_seed(seed)
    robots = smpenv_like_robots()
    table = robot_table(robots, None, 1)
    k = table.get(("limbs", "mask")).shape[-1]
    td = make_batch(len(robots), per_robot, k, dev, seed)
    nets = {
        (m, r): make_network(m, r, table=table, obs_dim=19, num_actions=1, preset="smpenv").to(dev)
        for m in METHODS
        for r in ROLES
    }
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
        "robots": len(robots),
        "batch": td.batch_size[0],
        "limbs": k,
        "threads": torch.get_num_threads(),
        "device": str(dev),
        "median_s": med,
        "params": {key: count_parameters(n) for key, n in nets.items()},
        "ratio": {r: med[("gcnt", r)] / med[("amorpheus", r)] for r in ROLES},
    }


def run(args: argparse.Namespace) -> int:
    res = bench(args.samples_per_robot, args.repeats, args.device, args.seed)
    print(
        f"{res['robots']} robots × {args.samples_per_robot} samples: B={res['batch']}, "
        f"K={res['limbs']}, device {res['device']}, {res['threads']} threads, "
        f"median of {args.repeats} forward+backward passes"
    )
    head = f"{'role':<12}{'method':<11}{'params':>10}{'ms':>10}"
    print(head)
    print("-" * len(head))
    for r in ROLES:
        for m in METHODS:
            ms = res["median_s"][(m, r)] * 1e3
            print(f"{r:<12}{m:<11}{res['params'][(m, r)]:>10,}{ms:>10.1f}")
        print(f"{r:<12}{'GCNT/AMORPHEUS':<21}{res['ratio'][r]:>10.2f}x")
    return 0
