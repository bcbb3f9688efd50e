"""Shared helpers of the tests/test_nn_*.py files: robots, tables, batches, small configs.

Two settings: SMPENV-like (F = 19, A = 1, the CWHH++ robots) and UNIMAL-like (F = 52, A = 2,
random trees with a static limb context and a height map). Property tests run in float64
(:func:`double`), so that they check structure, not one CPU's float32 rounding.
"""

from __future__ import annotations

import functools
import zlib

import torch
from tensordict import TensorDict

from gcnt.envs.robot_table import robot_table
from gcnt.nn.synthetic import random_robots, smpenv_like_robots

F_OBS = 19  # SMPENV limb observation width
NAMES = ("gcnt", "gcnt_no_gcn", "gcnt_no_wl", "gcnt_no_dist", "amorpheus", "swat", "smp", "mlp")
ROLES = ("td3_actor", "td3_critic", "ppo_actor", "ppo_critic")

# UNIMAL-like setting (the widths of the UNIMAL contract; a small height map keeps tests fast:
# the network's handling does not depend on its width)
F_UNIMAL, A_UNIMAL, C_UNIMAL, H_SMALL = 52, 2, 35, 30
UNIMAL_NAMES = ("metamorph", "metamorph_star", "modumorph", "gcnt", "gcnt_hn", "sr")

_TRANSFORMER_SMALL = {"d_model": 16, "layers": 2, "heads": 2, "ff": 24}
#: small sizes per method: the properties tested do not depend on size
SMALL: dict[str, dict] = {
    "gcnt": {**_TRANSFORMER_SMALL, "gcn_width": 4, "gcn_layers": 2, "hn_width": 8},
    "amorpheus": dict(_TRANSFORMER_SMALL),
    "swat": {**_TRANSFORMER_SMALL, "traversal_widths": (5, 5, 6)},
    "smp": {"msg_dim": 8, "hidden": 12, "head_hidden": (16,)},
    "mlp": {"hidden": (32, 32)},
    "sr": {"hidden": (32, 32)},
    "metamorph": dict(_TRANSFORMER_SMALL),
    "metamorph_star": dict(_TRANSFORMER_SMALL),
    "modumorph": {**_TRANSFORMER_SMALL, "hn_width": 8, "attn_context_widths": (12, 16)},
}


def small(name: str) -> dict:
    return dict(SMALL["gcnt" if name.startswith("gcnt") else name])


@functools.cache
def robots():
    """The CWHH++ training robots (the SMPENV files shipped with gcnt) + two random trees."""
    return tuple(smpenv_like_robots()) + tuple(random_robots([6, 9], seed=3))


@functools.cache
def unimal_robots():
    """Random trees of UNIMAL sizes (the largest UNIMAL robot has 11 bodies)."""
    return tuple(random_robots([11, 4, 7, 2, 9, 5], seed=11))


def table_of(rs, k: int | None = None, a: int = 1, context: int = 0) -> TensorDict:
    """The robot table of ``rs``; with ``context``, a static limb context of that width that
    depends only on the robot (seeded by its name), zero on padding."""
    table = robot_table(list(rs), k, a)
    if context:
        mask = table.get(("limbs", "mask"))
        ctx = torch.zeros(*mask.shape, context)
        for i, r in enumerate(rs):
            g = torch.Generator().manual_seed(zlib.crc32(r.name.encode()))
            ctx[i, : r.num_limbs] = torch.rand(r.num_limbs, context, generator=g) * 2 - 1
        table.set(("limbs", "context"), ctx)
    return table


def unimal_table(k: int | None = None, rs=None) -> TensorDict:
    return table_of(unimal_robots() if rs is None else rs, k, A_UNIMAL, C_UNIMAL)


def batch(table: TensorDict, ids, seed: int = 0, f: int = F_OBS, hfield: int = 0) -> TensorDict:
    """Random obs/actions (and height maps) for robots ``ids`` of ``table``; padded slots hold
    garbage."""
    g = torch.Generator().manual_seed(seed)
    ids = torch.as_tensor(ids, dtype=torch.long)
    b = len(ids)
    k, a = table.get(("limbs", "action_mask")).shape[-2:]
    td = TensorDict(
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
    if hfield:
        td.set("hfield", torch.randn(b, hfield, generator=g))
    return td


def double(td: TensorDict) -> TensorDict:
    """``td`` with its floating tensors in float64."""
    return td.apply(lambda t: t.double() if t.is_floating_point() else t)


def place(src: TensorDict, dst: TensorDict, rows, n: int) -> TensorDict:
    """Copy the first ``n`` limb slots (and the height map) of ``src`` into rows ``rows`` of
    ``dst``."""
    for key in (("limbs", "obs"), ("limbs", "action")):
        d = dst.get(key).clone()
        d[rows, :n] = src.get(key)[:, :n]
        dst.set(key, d)
    if "hfield" in src.keys():
        h = dst.get("hfield").clone()
        h[rows] = src.get("hfield")
        dst.set("hfield", h)
    return dst
