"""SMP (Huang et al. 2020): shared modular policies that pass messages along the limb tree.

Bottom-up: every limb's MLP maps [its input ‖ sum of its children's up-messages] to an
up-message (``msg_dim``). Top-down: every limb's MLP maps [its up-message ‖ its parent's
down-message] to a hidden vector (``hidden``), from which a Linear makes the down-message it sends
to its children; the shared head reads [hidden ‖ raw limb input (‖ height-map embedding)].
Messages are L2-normalised.

Vectorised over the batch by tree depth: each pass runs one step per depth level (the deepest
level in the batch bounds the loop), updating only the limbs at that level; no loop over samples.

Simplifications against the original code, on purpose: children's messages are summed (any
number of children, order-free) instead of concatenated in fixed child slots, and a parent sends
one message to all its children.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule
from torch import Tensor, nn

from gcnt import keys as K
from gcnt.nn.chain import Backbone, NetIO
from gcnt.nn.config import SMPConfig
from gcnt.nn.layers import flatten_lead, mlp
from gcnt.nn.stages import limb_head_stage

MSG_UP = ("limbs", "msg_up")


def tree_depth(parent: Tensor, mask: Tensor) -> Tensor:
    """Depth of every limb (torso 0) from the parent array [N, K]; -1 on padding."""
    k = parent.shape[-1]
    has_parent = parent >= 0
    p = parent.clamp_min(0)
    depth = torch.zeros_like(parent)
    for _ in range(k):
        depth = torch.where(has_parent, depth.gather(-1, p) + 1, torch.zeros_like(depth))
    return torch.where(mask, depth, torch.full_like(depth, -1))


class _Messages(nn.Module):
    def __init__(self, normalize: bool) -> None:
        super().__init__()
        self.normalize = normalize

    def _norm(self, m: Tensor) -> Tensor:
        return F.normalize(m, dim=-1) if self.normalize else m


def _flat_tree(x: Tensor, parent: Tensor, mask: Tensor):
    """Flatten leading batch dims of per-limb ``x`` [*L, K, D], ``parent`` and ``mask`` [*L, K];
    return them with the leading shape, the limb depths and the deepest level."""
    x, lead = flatten_lead(x, 2)
    parent, _ = flatten_lead(parent, 1)
    mask, _ = flatten_lead(mask, 1)
    depth = tree_depth(parent, mask)
    levels = int(depth.max()) if depth.numel() else -1
    return x, lead, parent, mask, depth, levels


class SMPUp(_Messages):
    def __init__(self, in_dim: int, msg_dim: int, hidden: int, normalize: bool = True) -> None:
        super().__init__(normalize)
        self.msg_dim = msg_dim
        self.net = mlp(in_dim + msg_dim, (hidden, hidden), msg_dim)

    def forward(self, x: Tensor, parent: Tensor, mask: Tensor) -> Tensor:
        x, lead, parent, mask, depth, levels = _flat_tree(x, parent, mask)
        n, k, _ = x.shape
        # child[n, i, j]: limb j is a real child of limb i
        child = (parent.unsqueeze(-2) == torch.arange(k, device=x.device).view(1, k, 1)) & (
            mask.unsqueeze(-2)
        )
        child = child.to(x.dtype)
        up = x.new_zeros(n, k, self.msg_dim)
        for lvl in range(levels, -1, -1):
            new = self._norm(self.net(torch.cat([x, child @ up], -1)))
            up = torch.where((depth == lvl).unsqueeze(-1), new, up)
        return up.reshape(*lead, k, self.msg_dim)


class SMPDown(_Messages):
    def __init__(self, msg_dim: int, hidden: int, normalize: bool = True) -> None:
        super().__init__(normalize)
        self.msg_dim, self.hidden = msg_dim, hidden
        self.net = mlp(2 * msg_dim, (hidden,), hidden)
        self.msg = nn.Linear(hidden, msg_dim)

    def forward(self, up: Tensor, parent: Tensor, mask: Tensor) -> Tensor:
        up, lead, parent, mask, depth, levels = _flat_tree(up, parent, mask)
        n, k, _ = up.shape
        has_parent = (parent >= 0).unsqueeze(-1)
        idx = parent.clamp_min(0).unsqueeze(-1).expand(n, k, self.msg_dim)
        down = up.new_zeros(n, k, self.msg_dim)
        feats = up.new_zeros(n, k, self.hidden)
        for lvl in range(0, levels + 1):
            from_parent = torch.where(has_parent, down.gather(1, idx), down.new_zeros(()))
            h = F.relu(self.net(torch.cat([up, from_parent], -1)))
            sel = (depth == lvl).unsqueeze(-1)
            feats = torch.where(sel, h, feats)
            down = torch.where(sel, self._norm(self.msg(h)), down)
        return feats.reshape(*lead, k, self.hidden)


def smp_backbone(cfg: SMPConfig, io: NetIO, table: TensorDictBase) -> Backbone:
    head = limb_head_stage(cfg.hidden, io.out_dim, raw_dim=io.in_dim, hfield_width=io.hfield_width)
    return Backbone(
        [
            (
                "up",
                TensorDictModule(
                    SMPUp(io.in_dim, cfg.msg_dim, cfg.hidden, cfg.normalize_messages),
                    [K.INPUT, K.PARENT, K.MASK],
                    [MSG_UP],
                ),
            ),
            (
                "down",
                TensorDictModule(
                    SMPDown(cfg.msg_dim, cfg.hidden, cfg.normalize_messages),
                    [MSG_UP, K.PARENT, K.MASK],
                    [K.FEATURES],
                ),
            ),
            ("head", head),
        ],
        static_keys=(K.PARENT,),
        name="SMP",
    )
