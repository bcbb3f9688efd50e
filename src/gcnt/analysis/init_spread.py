"""How large each method's outputs are before any training: the initial spread of the PPO action
means and values (UNIMAL) or of the TD3 actor's pre-tanh actions (SMPENV).

A policy whose initial action means spread far beyond the action range starts as a saturated
bang-bang policy (actions are clipped at ±1); the original MetaMorph/ModuMorph code starts near
zero (embedding U(±0.1), last decoder layer U(±0.01)). The probe feeds unit-normal limb
observations (what observation normalisation gives) of real training robots to freshly built
networks at the paper's sizes and reports the standard deviation over robots, samples and real
limbs (action slots with a motor only), per method and seed.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDict

from gcnt import keys as K

#: the methods compared on each benchmark
METHODS = {
    "unimal": ("metamorph", "metamorph_star", "modumorph", "gcnt", "gcnt_hn"),
    "smpenv": ("amorpheus", "swat", "smp", "gcnt"),
}
#: the training robots probed on each benchmark
ROBOTS = {"unimal": "Unimal:train", "smpenv": "CWHH++:train"}


def _probe_batch(table, obs_dim: int, samples: int, seed: int, hfield_dim: int) -> TensorDict:
    """``samples`` unit-normal observations of every robot of ``table`` (zero on padding)."""
    g = torch.Generator().manual_seed(seed)
    r, k = table[K.MASK].shape
    ids = torch.arange(r).repeat_interleave(samples)
    td = TensorDict(
        {K.MORPH_ID: ids, K.OBS: torch.randn(len(ids), k, obs_dim, generator=g)},
        batch_size=[len(ids)],
    )
    if hfield_dim:
        td[K.HFIELD] = torch.randn(len(ids), hfield_dim, generator=g)
    return td


def _real(values: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """The entries of per-limb ``values`` [B, K, A] where ``mask`` [B, K, A] is True."""
    return values[mask.expand_as(values)]


@torch.no_grad()
def initial_spread(
    benchmark: str = "unimal",
    methods: Sequence[str] | None = None,
    seeds: Sequence[int] = (0, 1, 2),
    num_robots: int = 8,
    samples: int = 16,
    world: str | None = None,
    **overrides,
) -> list[dict]:
    """One row per (method, seed): ``action_std`` (std of the initial action means; TD3: of the
    pre-tanh actions) and ``value_std`` (PPO: std of the initial per-robot values; TD3: std of
    the first critic's per-limb Q on the actor's actions), at the benchmark's preset sizes with
    ``overrides`` on every network."""
    from gcnt.envs.benchmark import get_benchmark
    from gcnt.morphology import resolve_robots
    from gcnt.nn import make_network

    bench = get_benchmark(benchmark)
    robots = resolve_robots([ROBOTS[bench.name]])[:num_robots]
    env = bench.make_env(robots, seed=0, num_threads=1, world=world)
    table = env.table
    obs_dim = env.observation_spec[K.OBS].shape[-1]
    slots = env.full_action_spec[K.ACTION].shape[-1]
    spec = env.observation_spec.get(K.HFIELD, None)
    hfield = spec.shape[-1] if spec is not None else 0
    env.close()
    algo = "ppo" if bench.name == "unimal" else "td3"
    rows = []
    for method in methods or METHODS[bench.name]:
        for seed in seeds:
            torch.manual_seed(seed)
            kw = dict(
                table=table,
                obs_dim=obs_dim,
                num_actions=slots,
                preset=bench.name,
                hfield_dim=hfield,
                keep_intermediates=True,
                **overrides,
            )
            actor = make_network(method, f"{algo}_actor", **kw).eval()
            critic = make_network(method, f"{algo}_critic", **kw).eval()
            td = _probe_batch(table, obs_dim, samples, 1000 + seed, hfield)
            out = actor(td.clone())
            amask = table[K.ACTION_MASK][td[K.MORPH_ID]]
            if algo == "ppo":
                action = _real(out[K.LOC], amask)
                value = critic(td.clone())[K.VALUE].flatten()
            else:
                action = _real(out[K.OUT], amask)  # before the tanh
                q_in = td.clone()
                q_in[K.ACTION] = out[K.ACTION]
                value = _real(critic(q_in)[K.LIMB_Q], table[K.MASK][td[K.MORPH_ID]].unsqueeze(-1))
            rows.append(
                {
                    "method": method,
                    "seed": seed,
                    "action_std": float(action.std()),
                    "value_std": float(value.std()),
                }
            )
    return rows
