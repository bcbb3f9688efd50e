"""Shared helpers of the tests/test_nn_*.py files: robots, tables, batches, small configs."""

from __future__ import annotations

import functools

import torch
from tensordict import TensorDict

from gcnt.envs.robot_table import robot_table
from gcnt.nn.synthetic import random_robots, smpenv_like_robots

F_OBS = 19  # SMPENV limb observation width
NAMES = ("gcnt", "gcnt_no_gcn", "gcnt_no_wl", "gcnt_no_dist", "amorpheus", "swat", "smp", "mlp")
ROLES = ("td3_actor", "td3_critic", "ppo_actor", "ppo_critic")

_TRANSFORMER_SMALL = {"d_model": 16, "layers": 2, "heads": 2, "ff": 24}
#: small sizes per method: the properties tested do not depend on size
SMALL: dict[str, dict] = {
    "gcnt": {**_TRANSFORMER_SMALL, "gcn_width": 4, "gcn_layers": 2},
    "amorpheus": dict(_TRANSFORMER_SMALL),
    "swat": {**_TRANSFORMER_SMALL, "traversal_widths": (5, 5, 6)},
    "smp": {"msg_dim": 8, "hidden": 12},
    "mlp": {"hidden": (32, 32)},
}


def small(name: str) -> dict:
    return dict(SMALL["gcnt" if name.startswith("gcnt") else name])


@functools.cache
def robots():
    """The CWHH++ training robots (real SMPENV files when present) + two random trees."""
    return tuple(smpenv_like_robots()) + tuple(random_robots([6, 9], seed=3))


def table_of(rs, k: int | None = None, a: int = 1) -> TensorDict:
    return robot_table(list(rs), k, a)


def batch(table: TensorDict, ids, seed: int = 0, f: int = F_OBS) -> TensorDict:
    """Random obs/actions for robots ``ids`` of ``table``; padded slots hold garbage."""
    g = torch.Generator().manual_seed(seed)
    ids = torch.as_tensor(ids, dtype=torch.long)
    b = len(ids)
    k, a = table.get(("limbs", "action_mask")).shape[-2:]
    return TensorDict(
        {
            "morph_id": ids,
            "limbs": TensorDict(
                {
                    "obs": torch.randn(b, k, f, generator=g),
                    "action": torch.rand(b, k, a, generator=g) * 2 - 1,
                },
                [b, k],
            ),
        },
        [b],
    )


def place(src: TensorDict, dst: TensorDict, rows, n: int) -> TensorDict:
    """Copy the first ``n`` limb slots of ``src`` into rows ``rows`` of ``dst``."""
    for key in (("limbs", "obs"), ("limbs", "action")):
        d = dst.get(key).clone()
        d[rows, :n] = src.get(key)[:, :n]
        dst.set(key, d)
    return dst
