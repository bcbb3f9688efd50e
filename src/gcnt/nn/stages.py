"""One stage per module: the torch modules of GCNT's pipeline and the TensorDictModules wrapping
them. Every stage accepts any number of leading batch dims (e.g. [T, B]) before the limb dim.

A chain (see :mod:`gcnt.nn.gcnt` and :mod:`gcnt.nn.registry`) reads ``limbs/input`` (limb obs, or
obs ‖ masked action for a critic; zero on padding) and the static keys restored by
:class:`gcnt.nn.GraphLookup`, and writes ``limbs/features`` for the per-limb head.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from tensordict.nn import TensorDictModule
from torch import Tensor, nn

from gcnt.morphology import DIST_PAD
from gcnt.nn import keys as K
from gcnt.nn.layers import TransformerEncoder, flatten_lead, mlp, scaled

# --------------------------------------------------------------------------------------- input


class ActorInput(nn.Module):
    """Limb observations with padded limbs zeroed (so nothing from padding can leak, not even
    NaN through a zero attention weight)."""

    def forward(self, obs: Tensor, mask: Tensor) -> Tensor:
        return torch.where(mask.unsqueeze(-1), obs, obs.new_zeros(()))


class CriticInput(nn.Module):
    """Limb observation ‖ limb action; actions are masked by ``action_mask`` so that noise on
    torso or padded slots (TD3's target smoothing) never enters the critic."""

    def forward(self, obs: Tensor, action: Tensor, mask: Tensor, action_mask: Tensor) -> Tensor:
        zero = torch.zeros((), dtype=obs.dtype, device=obs.device)
        action = torch.where(action_mask, action.to(obs.dtype), zero)
        return torch.where(mask.unsqueeze(-1), torch.cat([obs, action], -1), zero)


def input_stage(critic: bool) -> TensorDictModule:
    if critic:
        return TensorDictModule(CriticInput(), [K.OBS, K.ACTION, K.MASK, K.ACTION_MASK], [K.INPUT])
    return TensorDictModule(ActorInput(), [K.OBS, K.MASK], [K.INPUT])


# ------------------------------------------------------------------------------ limb encoder


class LimbEncoder(nn.Module):
    """The limb-observation module: an MLP ``F → d`` applied to every limb (one Linear when
    ``hidden`` is empty), optionally scaled by √d as in AMORPHEUS."""

    def __init__(
        self, in_dim: int, d_model: int, hidden: Sequence[int] = (), scale: bool = True
    ) -> None:
        super().__init__()
        self.d_model = d_model
        self.scale = scale
        self.net = mlp(in_dim, hidden, d_model)

    def forward(self, x: Tensor) -> Tensor:
        return scaled(self.net(x), self.d_model, self.scale)


def limb_encoder_stage(
    in_dim: int, d_model: int, hidden: Sequence[int] = (), scale: bool = True
) -> TensorDictModule:
    return TensorDictModule(LimbEncoder(in_dim, d_model, hidden, scale), [K.INPUT], [K.EMBED])


# ------------------------------------------------------------------------------------- GCN


def normalized_adjacency(adj: Tensor, mask: Tensor) -> Tensor:
    """Â = D̃^-½ (A + I) D̃^-½ over real limbs only (padded rows and columns are zero)."""
    m = mask.to(torch.float32)
    a = adj.to(torch.float32) * m.unsqueeze(-1) * m.unsqueeze(-2)
    a = a + torch.diag_embed(m)
    deg = a.sum(-1)
    dinv = torch.where(deg > 0, deg.clamp_min(1e-12).rsqrt(), torch.zeros_like(deg))
    return dinv.unsqueeze(-1) * a * dinv.unsqueeze(-2)


class GCNLayer(nn.Module):
    """GCNT's improved GCN layer: H' = ReLU(Â H W₁) W₂ + H (biases on both linear maps)."""

    def __init__(self, width: int) -> None:
        super().__init__()
        self.w1 = nn.Linear(width, width)
        self.w2 = nn.Linear(width, width)

    def forward(self, h: Tensor, a_hat: Tensor) -> Tensor:
        return self.w2(F.relu(self.w1(a_hat @ h))) + h


class LimbGCN(nn.Module):
    """The GCN module: H⁰ = one-hot limb type projected to ``width`` (Linear, no bias), then
    ``layers`` :class:`GCNLayer`. Â is built per sample from ``graph/adj`` with padding excluded,
    so padded limbs do not leak into real ones; the output is zero on padded limbs."""

    def __init__(self, num_types: int, width: int, layers: int) -> None:
        super().__init__()
        self.num_types = num_types
        self.embed = nn.Linear(num_types, width, bias=False)
        self.layers = nn.ModuleList(GCNLayer(width) for _ in range(layers))

    def forward(self, types: Tensor, adj: Tensor, mask: Tensor) -> Tensor:
        if types.device.type == "cpu" and types.numel() and int(types.max()) >= self.num_types:
            raise ValueError(f"limb type id {int(types.max())} >= num_limb_types {self.num_types}")
        h = self.embed(F.one_hot(types.clamp_min(0), self.num_types).to(self.embed.weight.dtype))
        a_hat = normalized_adjacency(adj, mask).to(h.dtype)
        for layer in self.layers:
            h = layer(h, a_hat)
        return torch.where(mask.unsqueeze(-1), h, h.new_zeros(()))


def gcn_stage(num_types: int, width: int, layers: int) -> TensorDictModule:
    return TensorDictModule(LimbGCN(num_types, width, layers), [K.TYPE, K.ADJ, K.MASK], [K.GCN])


# ------------------------------------------------------------------------ morphology fusion


class MorphologyFusion(nn.Module):
    """[GCN ‖ WL] of each limb (WL counts are the same for every limb of a robot), projected to
    d and added to the limb embedding. Either part may be absent (ablations)."""

    def __init__(self, d_model: int, gcn_width: int, wl_dim: int) -> None:
        super().__init__()
        self.use_gcn, self.use_wl = gcn_width > 0, wl_dim > 0
        if not (self.use_gcn or self.use_wl):
            raise ValueError("MorphologyFusion needs the GCN or the WL part")
        self.proj = nn.Linear(gcn_width + wl_dim, d_model)

    def forward(self, embed: Tensor, *parts: Tensor) -> Tensor:
        feats = []
        it = iter(parts)
        if self.use_gcn:
            feats.append(next(it))
        if self.use_wl:
            wl = next(it).to(embed.dtype)
            feats.append(wl.unsqueeze(-2).expand(*embed.shape[:-1], wl.shape[-1]))
        return embed + self.proj(torch.cat(feats, -1))


def fusion_stage(d_model: int, gcn_width: int, wl_dim: int) -> TensorDictModule:
    in_keys = [K.EMBED] + ([K.GCN] if gcn_width else []) + ([K.WL] if wl_dim else [])
    return TensorDictModule(MorphologyFusion(d_model, gcn_width, wl_dim), in_keys, [K.HIDDEN])


# ------------------------------------------------------------------------ distance bias


class DistanceBias(nn.Module):
    """Learnable hop-distance bias R_h(D_ij): an embedding over distances clamped to
    ``max_dist``, one value per head, ``tables`` of them (one per layer, or 1 shared).

    Output [*, tables, H, K, K]. Zero-initialised, so training starts from the plain
    Transformer. Padding pairs get a finite value here; the encoder masks padded keys.
    """

    def __init__(self, max_dist: int, heads: int, tables: int) -> None:
        super().__init__()
        self.max_dist, self.heads, self.tables = max_dist, heads, tables
        self.embed = nn.Embedding(max_dist + 1, tables * heads)
        nn.init.zeros_(self.embed.weight)

    def forward(self, dist: Tensor) -> Tensor:
        d = dist.long().clamp(0, self.max_dist)
        b = self.embed(d)  # [*, K, K, tables*H]
        b = b.unflatten(-1, (self.tables, self.heads))  # [*, K, K, T, H]
        return b.movedim((-2, -1), (-4, -3))  # [*, T, H, K, K]


def distance_bias_stage(max_dist: int, heads: int, tables: int) -> TensorDictModule:
    return TensorDictModule(DistanceBias(max_dist, heads, tables), [K.DIST], [K.ATTN_BIAS])


class RelationalBias(nn.Module):
    """SWAT's relational bias: Linear(3 → heads) of [PPR, normalised Laplacian, hop dist / N]
    per limb pair (N = the robot's limb count), for the first layer. Output [*, 1, H, K, K]."""

    def __init__(self, heads: int) -> None:
        super().__init__()
        self.lin = nn.Linear(3, heads)

    def forward(self, ppr: Tensor, lap: Tensor, dist: Tensor, mask: Tensor) -> Tensor:
        n = mask.sum(-1).clamp_min(1).to(ppr.dtype)[..., None, None]
        pair = mask.unsqueeze(-1) & mask.unsqueeze(-2) & (dist != DIST_PAD)
        hop = torch.where(pair, dist.to(ppr.dtype) / n, ppr.new_zeros(()))
        feats = torch.stack([ppr, lap, hop], -1)  # [*, K, K, 3]
        return self.lin(feats).movedim(-1, -3).unsqueeze(-4)  # [*, 1, H, K, K]


def relational_bias_stage(heads: int) -> TensorDictModule:
    return TensorDictModule(
        RelationalBias(heads), [K.PPR, K.LAPLACIAN, K.DIST, K.MASK], [K.ATTN_BIAS]
    )


# ------------------------------------------------------------------------ transformer


class LimbTransformer(nn.Module):
    """Runs a :class:`TransformerEncoder` on [*, K, d] tokens with the limb mask and an optional
    additive bias [*, Lb, H, K, K]; flattens the leading dims."""

    def __init__(self, encoder: TransformerEncoder, with_bias: bool) -> None:
        super().__init__()
        self.encoder = encoder
        self.with_bias = with_bias

    def forward(self, x: Tensor, mask: Tensor, bias: Tensor | None = None) -> Tensor:
        x, lead = flatten_lead(x, 2)
        mask, _ = flatten_lead(mask, 1)
        if bias is not None:
            bias, _ = flatten_lead(bias, 4)
            bias = bias.to(x.dtype)
        return self.encoder(x, mask, bias).reshape(*lead, *x.shape[1:])


def transformer_stage(
    encoder: TransformerEncoder, in_key=K.HIDDEN, with_bias: bool = False
) -> TensorDictModule:
    in_keys = [in_key, K.MASK] + ([K.ATTN_BIAS] if with_bias else [])
    return TensorDictModule(LimbTransformer(encoder, with_bias), in_keys, [K.FEATURES])


# ------------------------------------------------------------------------ per-limb head


class LimbHead(nn.Module):
    """The decoder shared by every method: Linear(features ‖ raw limb input → out) per limb
    (the raw input residual is AMORPHEUS's; GCNT keeps it)."""

    def __init__(self, feat_dim: int, in_dim: int, out_dim: int) -> None:
        super().__init__()
        self.lin = nn.Linear(feat_dim + in_dim, out_dim)

    def forward(self, features: Tensor, x: Tensor) -> Tensor:
        return self.lin(torch.cat([features, x.to(features.dtype)], -1))


def limb_head_stage(feat_dim: int, in_dim: int, out_dim: int) -> TensorDictModule:
    return TensorDictModule(LimbHead(feat_dim, in_dim, out_dim), [K.FEATURES, K.INPUT], [K.OUT])
