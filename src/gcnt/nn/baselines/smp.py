"""SMP (Huang et al. 2020): shared modular policies that pass messages along the limb tree.

The structure and sizes of the original code's both-way policy (``huangwl18/modular-rl``,
``src/ModularActor.py``: ``ActorUp``, ``ActorDownAction``; ``src/ModularCritic.py``:
``CriticUp``, ``CriticDownAction``; ``src/utils.py``: ``MLPBase``), one module set shared by
all limbs:

* bottom-up, leaves first: ``h = normalize(Linear(input → hidden))``, then
  ``tanh(Linear(tanh([h ‖ children's up-messages]) → hidden))``, then
  ``up = normalize(Linear(hidden → msg_dim))``;
* top-down, torso first: ``x = [up ‖ parent's down-message]`` (zeros at the torso);
  ``down = normalize(MLP(tanh(x)))``, the MLP 2·msg_dim → 400 → 300 → msg_dim (ReLU);
* output per limb: an actor's action from ``MLP(tanh(x))`` (2·msg_dim → 400 → 300 → A, then the
  role's tanh); a TD3 critic's Q from ``MLP([up ‖ limb action ‖ parent's message])`` without tanh
  (2·msg_dim + A → 400 → 300 → 1), as ``CriticDownAction``'s ``baseQ``. With a height map its
  encoding joins the head's input.

The input of a TD3 critic's bottom-up module is the limb's observation ‖ action, as in
``CriticUp``. Messages are L2-normalised (``normalize_messages``).

Vectorised over the batch by tree depth: each pass runs one step per depth level (the deepest
level in the batch bounds the loop), updating only the limbs at that level; no loop over samples.

Differences from the original code, on purpose: children's messages are summed (any number of
children, order-free) instead of concatenated in ``max_children`` fixed slots, so a parent sends
one down-message (msg_dim wide) to all its children instead of one slice per child slot; and each
of TD3's twin critics has its own message trunk (the original's twin Q heads share one).
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
from gcnt.nn.layers import as_dtype, flatten_lead, mlp

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
    return x, lead, parent, mask, depth, message_levels(depth, parent.shape[-1])


def message_levels(depth: Tensor, k: int) -> int:
    """The deepest level the message passes run to: the batch's deepest limb, read on the host.
    While a CUDA graph is captured or torch.compile traces, that read (a device sync, a data-
    dependent graph break) is not allowed, so every level a tree of ``k`` limbs can have runs
    instead: levels below the deepest limb select no limb and change nothing."""
    # is_compiling() first: torch.compile then never reads the capture flag, which it would
    # otherwise guard on and recompile for when a CUDA graph captures the compiled step
    if torch.compiler.is_compiling():
        return k - 1
    if depth.is_cuda and torch.cuda.is_current_stream_capturing():
        return k - 1
    return int(depth.max()) if depth.numel() else -1


class SMPUp(_Messages):
    """The bottom-up pass: every limb's up-message from its input and its children's
    up-messages (summed), leaves first."""

    def __init__(self, in_dim: int, msg_dim: int, hidden: int, normalize: bool = True) -> None:
        super().__init__(normalize)
        self.msg_dim = msg_dim
        self.fc1 = nn.Linear(in_dim, hidden)
        self.fc2 = nn.Linear(hidden + msg_dim, hidden)
        self.fc3 = nn.Linear(hidden, msg_dim)

    def forward(self, x: Tensor, parent: Tensor, mask: Tensor) -> Tensor:
        x, lead, parent, mask, depth, levels = _flat_tree(x, parent, mask)
        n, k, _ = x.shape
        # child[n, i, j]: limb j is a real child of limb i
        child = (parent.unsqueeze(-2) == torch.arange(k, device=x.device).view(1, k, 1)) & (
            mask.unsqueeze(-2)
        )
        child = as_dtype(child, x.dtype)
        h = self._norm(self.fc1(x))  # the limb's own part: the same at every level
        up = x.new_zeros(n, k, self.msg_dim)
        for lvl in range(levels, -1, -1):
            z = torch.tanh(self.fc2(torch.tanh(torch.cat([h, child @ up], -1))))
            new = self._norm(self.fc3(z))
            up = torch.where((depth == lvl).unsqueeze(-1), new, up)
        return up.reshape(*lead, k, self.msg_dim)


class SMPDown(_Messages):
    """The top-down pass: every limb's [up-message ‖ parent's down-message] (zeros at the torso),
    torso first; its own down-message to its children comes from an MLP of the tanh of that.
    Returns the [up ‖ parent's message] of every limb (width 2·msg_dim), which the head reads."""

    def __init__(self, msg_dim: int, head_hidden: tuple[int, ...], normalize: bool = True) -> None:
        super().__init__(normalize)
        self.msg_dim = msg_dim
        self.msg = mlp(2 * msg_dim, head_hidden, msg_dim)

    def forward(self, up: Tensor, parent: Tensor, mask: Tensor) -> Tensor:
        up, lead, parent, mask, depth, levels = _flat_tree(up, parent, mask)
        n, k, _ = up.shape
        has_parent = (parent >= 0).unsqueeze(-1)
        idx = parent.clamp_min(0).unsqueeze(-1).expand(n, k, self.msg_dim)
        down = up.new_zeros(n, k, self.msg_dim)
        for lvl in range(0, levels):  # the deepest level sends no message
            from_parent = torch.where(has_parent, down.gather(1, idx), 0.0)
            new = self._norm(self.msg(torch.tanh(torch.cat([up, from_parent], -1))))
            down = torch.where((depth == lvl).unsqueeze(-1), new, down)
        from_parent = torch.where(has_parent, down.gather(1, idx), 0.0)
        return torch.cat([up, from_parent], -1).reshape(*lead, k, 2 * self.msg_dim)


class SMPHead(nn.Module):
    """The per-limb output MLP (``MLPBase``): an actor reads tanh([up ‖ parent's message]); a
    TD3 critic reads [up ‖ limb action ‖ parent's message] (no tanh); the height-map encoding,
    if any, is joined to the input."""

    def __init__(
        self,
        msg_dim: int,
        out_dim: int,
        hidden: tuple[int, ...],
        *,
        action_dim: int = 0,
        hfield_width: int = 0,
    ) -> None:
        super().__init__()
        self.msg_dim, self.action_dim, self.hfield = msg_dim, action_dim, hfield_width > 0
        self.net = mlp(2 * msg_dim + action_dim + hfield_width, hidden, out_dim)

    def forward(self, features: Tensor, *parts: Tensor) -> Tensor:
        it = iter(parts)
        if self.action_dim:  # a critic: the limb's action sits at the end of limbs/input
            action = next(it)[..., -self.action_dim :]
            up, from_parent = features.split(self.msg_dim, -1)
            x = torch.cat([up, action, from_parent], -1)
        else:
            x = torch.tanh(features)
        if self.hfield:
            h = next(it)
            x = torch.cat([x, h.unsqueeze(-2).expand(*x.shape[:-1], h.shape[-1])], -1)
        return self.net(x)


def smp_backbone(cfg: SMPConfig, io: NetIO, table: TensorDictBase) -> Backbone:
    head_keys = [K.FEATURES] + ([K.INPUT] if io.action_dim else [])
    head_keys += [K.HFIELD_EMBED] if io.hfield_width else []
    head = SMPHead(
        cfg.msg_dim,
        io.out_dim,
        cfg.head_hidden,
        action_dim=io.action_dim,
        hfield_width=io.hfield_width,
    )
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
                    SMPDown(cfg.msg_dim, cfg.head_hidden, cfg.normalize_messages),
                    [MSG_UP, K.PARENT, K.MASK],
                    [K.FEATURES],
                ),
            ),
            ("head", TensorDictModule(head, head_keys, [K.OUT])),
        ],
        static_keys=(K.PARENT,),
        name="SMP",
    )
