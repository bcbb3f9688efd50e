"""Padded, static per-robot tensors: the graph half of the TensorDict contract.

A run has a table of robots; ``morph_id`` indexes it. Everything here is static per robot, so
replay buffers store only ``morph_id`` and the policy chain restores the rest from this table
(see ``gcnt.nn.graph_lookup``), on env output and on buffer samples alike.

Keys of the table (batch [R] robots, limbs padded to K, A action slots per limb):

    limbs/mask         [R,K]    bool     real limb
    limbs/type         [R,K]    int64    global limb-type id (0 on padding)
    limbs/action_mask  [R,K,A]  bool     a motor drives this slot (``Robot.action_slots``)
    limbs/context      [R,K,C]  float32  static limb description (only if the env has one)
    graph/adj          [R,K,K]  bool
    graph/dist         [R,K,K]  uint8    hop distance clamped to DIST_PAD-1; DIST_PAD on padding
    graph/wl           [R,W]    float32  WL colour counts
    graph/parent       [R,K]    int64    parent limb index (-1 for torso and padding)
    graph/traversal    [R,K,3]  int64    SWAT pre/in/post-order positions (0 on padding)
    graph/ppr          [R,K,K]  float32  personalised PageRank (0 on padding)
    graph/laplacian    [R,K,K]  float32  normalised Laplacian (0 on padding)
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from tensordict import TensorDict

from gcnt import keys as K
from gcnt.morphology import DIST_PAD, Robot

#: Keys a policy may need from the table (``limbs/context`` only where the benchmark has one); the
#: env emits the contract's subset of them.
STATIC_KEYS: tuple[tuple[str, str], ...] = (
    K.MASK,
    K.TYPE,
    K.ACTION_MASK,
    K.CONTEXT,
    K.ADJ,
    K.DIST,
    K.WL,
    K.PARENT,
    K.TRAVERSAL,
    K.PPR,
    K.LAPLACIAN,
)


class RobotTooLargeError(ValueError):
    """A robot has more limbs or joints per limb than the padded size allows."""


def robot_table(
    robots: Sequence[Robot],
    max_limbs: int | None = None,
    num_actions: int | None = None,
    *,
    context: Sequence[np.ndarray] | None = None,
) -> TensorDict:
    """Build the padded static table of ``robots`` (batch [R]).

    ``max_limbs`` defaults to the largest robot; ``num_actions`` (A, action slots per limb) to the
    largest joints-per-limb of the robots' families. Slot ``a`` of limb ``l`` is marked in the
    action mask when a joint of the limb has action slot ``a`` (``Robot.action_slots(l)``).
    ``context``: one [num_limbs, C] array per robot, stored padded with zeros as
    ``limbs/context`` [R,K,C] float32.
    """
    if not robots:
        raise ValueError("robot_table needs at least one robot")
    k = max_limbs or max(r.num_limbs for r in robots)
    a = num_actions or max(r.max_joints_per_limb for r in robots)
    for r in robots:
        if r.num_limbs > k:
            raise RobotTooLargeError(
                f"robot {r.name!r} ({r.source}) has {r.num_limbs} limbs; this table/model allows "
                f"at most {k} (raise max_limbs)"
            )
        for limb in range(r.num_limbs):
            slots = r.action_slots(limb)
            if len(slots) != len(r.actuator_ids[limb]):
                raise ValueError(
                    f"robot {r.name!r}, limb {r.body_names[limb]!r}: {len(slots)} action slots "
                    f"for {len(r.actuator_ids[limb])} motors"
                )
            if slots and (max(slots) >= a or min(slots) < 0):
                raise RobotTooLargeError(
                    f"robot {r.name!r}, limb {r.body_names[limb]!r}: a motor in action slot "
                    f"{max(slots)}; only {a} action slots per limb"
                )
    if context is not None:
        if len(context) != len(robots):
            raise ValueError(f"context: {len(context)} arrays for {len(robots)} robots")
        widths = {np.shape(c)[-1] if np.ndim(c) == 2 else -1 for c in context}
        for r, c in zip(robots, context, strict=True):
            if np.ndim(c) != 2 or np.shape(c)[0] != r.num_limbs or len(widths) != 1:
                raise ValueError(
                    f"robot {r.name!r}: context of shape {np.shape(c)}; expected "
                    f"[{r.num_limbs} limbs, C] with the same C for every robot"
                )
    n, w = len(robots), len(robots[0].graph.wl)
    mask = np.zeros((n, k), bool)
    types = np.zeros((n, k), np.int64)
    amask = np.zeros((n, k, a), bool)
    adj = np.zeros((n, k, k), bool)
    dist = np.full((n, k, k), DIST_PAD, np.uint8)
    wl = np.zeros((n, w), np.float32)
    parent = np.full((n, k), -1, np.int64)
    trav = np.zeros((n, k, 3), np.int64)
    ppr = np.zeros((n, k, k), np.float32)
    lap = np.zeros((n, k, k), np.float32)
    for i, r in enumerate(robots):
        m, g = r.num_limbs, r.graph
        if len(g.wl) != w:
            raise ValueError(f"robot {r.name!r}: WL vector size {len(g.wl)} != {w}")
        mask[i, :m] = True
        types[i, :m] = r.global_types
        for limb in range(m):
            amask[i, limb, list(r.action_slots(limb))] = True
        adj[i, :m, :m] = g.adj
        dist[i, :m, :m] = np.clip(g.dist, 0, DIST_PAD - 1)
        wl[i] = g.wl
        parent[i, :m] = r.parents
        trav[i, :m] = g.traversal
        ppr[i, :m, :m] = g.ppr
        lap[i, :m, :m] = g.laplacian
    limbs = {
        "mask": torch.from_numpy(mask),
        "type": torch.from_numpy(types),
        "action_mask": torch.from_numpy(amask),
    }
    if context is not None:
        ctx = np.zeros((n, k, np.shape(context[0])[1]), np.float32)
        for i, c in enumerate(context):
            ctx[i, : len(c)] = c
        limbs["context"] = torch.from_numpy(ctx)
    return TensorDict(
        {
            "limbs": limbs,
            "graph": {
                "adj": torch.from_numpy(adj),
                "dist": torch.from_numpy(dist),
                "wl": torch.from_numpy(wl),
                "parent": torch.from_numpy(parent),
                "traversal": torch.from_numpy(trav),
                "ppr": torch.from_numpy(ppr),
                "laplacian": torch.from_numpy(lap),
            },
        },
        batch_size=[n],
    )


#: the limb axes of each static key (the table's axis numbers, robot axis 0): what
#: :func:`trim_table` cuts; ``graph/wl`` has none
LIMB_AXES: dict[tuple[str, str], tuple[int, ...]] = {
    K.MASK: (1,),
    K.TYPE: (1,),
    K.ACTION_MASK: (1,),
    K.CONTEXT: (1,),
    K.ADJ: (1, 2),
    K.DIST: (1, 2),
    K.WL: (),
    K.PARENT: (1,),
    K.TRAVERSAL: (1,),
    K.PPR: (1, 2),
    K.LAPLACIAN: (1, 2),
}


def trim_rows(sizes: Sequence[int], limbs: int) -> list[int] | None:
    """Which row stands for each robot in a table cut to its first ``limbs`` slots: the robot
    itself where it has at most ``limbs`` limbs, else the first robot that fits (a robot cut
    short would be a different, possibly inconsistent graph: its row is replaced so that every
    row of the cut table is a whole robot, and only the fitting robots' rows are ever read);
    None when no robot fits."""
    fits = [i for i, s in enumerate(sizes) if s <= limbs]
    if not fits:
        return None
    return [i if s <= limbs else fits[0] for i, s in enumerate(sizes)]


def trim_table(table: dict, rows: Sequence[int] | None, limbs: int) -> dict:
    """``table`` (static key -> [R, K, ...] tensor) cut to its first ``limbs`` limb slots on
    every limb axis (:data:`LIMB_AXES`), with the rows :func:`trim_rows` chose (``None``: every
    row as it is). Real limbs come first in every row (:func:`robot_table`), so a robot with at
    most ``limbs`` limbs keeps every real value; only padding is dropped."""
    out = {}
    moved = rows is not None and list(rows) != list(range(len(rows)))  # a row stands in
    index = None
    for key, value in table.items():
        if moved:
            if index is None or index.device != value.device:
                index = torch.tensor(list(rows), device=value.device)
            value = value.index_select(0, index)
        for axis in LIMB_AXES.get(key, ()):
            value = value.narrow(axis, 0, limbs)
        out[key] = value
    return out
