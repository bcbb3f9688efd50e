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

from gcnt import keys as K
from gcnt.morphology import DIST_PAD
from gcnt.nn.init import init_like_original
from gcnt.nn.layers import (
    ContextTransformer,
    HyperLinear,
    TransformerEncoder,
    as_dtype,
    flatten_lead,
    mlp,
    scaled,
)

#: the height map enters every method the same way: MLP H → 64 → 64 (ReLU) of the root key
#: ``hfield``, joined to each limb's features; the decoder's hidden layers are the world's (the
#: originals' ``DECODER_DIMS``: none on FT and Incline, [64] on MT, [64, 64] on Obstacles), one
#: of this width where no world says
HFIELD_WIDTH = 64
DECODER_HIDDEN = 64

# --------------------------------------------------------------------------------------- input


class ActorInput(nn.Module):
    """Limb observations with padded limbs zeroed (so nothing from padding can leak, not even
    NaN through a zero attention weight)."""

    def forward(self, obs: Tensor, mask: Tensor) -> Tensor:
        return torch.where(mask.unsqueeze(-1), obs, 0.0)


class CriticInput(nn.Module):
    """Limb observation ‖ limb action; actions are masked by ``action_mask`` so that noise on
    torso or padded slots (TD3's target smoothing) never enters the critic."""

    def forward(self, obs: Tensor, action: Tensor, mask: Tensor, action_mask: Tensor) -> Tensor:
        action = torch.where(action_mask, as_dtype(action, obs.dtype), 0.0)
        return torch.where(mask.unsqueeze(-1), torch.cat([obs, action], -1), 0.0)


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


def normalized_adjacency(adj: Tensor, mask: Tensor, dtype: torch.dtype = torch.float32) -> Tensor:
    """Â = D̃^-½ (A + I) D̃^-½ over real limbs only (padded rows and columns are zero)."""
    m = mask.to(dtype)
    a = adj.to(dtype) * m.unsqueeze(-1) * m.unsqueeze(-2)
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
    """The GCN module: H⁰ = each limb's input projected to ``width`` (Linear, no bias), then
    ``layers`` :class:`GCNLayer`. The input is the one-hot limb type (``num_types`` types), or
    with ``context_dim`` the limb's static context (``limbs/context``, the hypernetworks' input).
    Â is built per sample from ``graph/adj`` with padding excluded, so padded limbs do not leak
    into real ones; the output is zero on padded limbs."""

    def __init__(self, num_types: int, width: int, layers: int, context_dim: int = 0) -> None:
        super().__init__()
        self.num_types, self.context_dim = num_types, context_dim
        self.embed = nn.Linear(context_dim or num_types, width, bias=False)
        self.layers = nn.ModuleList(GCNLayer(width) for _ in range(layers))
        self._graph_cache = None

    def graph(self, types: Tensor, adj: Tensor, mask: Tensor, what: str, dtype: torch.dtype):
        """The one-hot limb types (``what="types"``; ``types`` is the GCN's input, the limb
        context with ``context_dim``) or Â (``"a_hat"``) in ``dtype``: constants of
        the robot table, computed at the first call with these tensors and kept while they are
        unchanged (each update calls the GCN of every network on the same table). Compiled, they
        are part of the graph. The type ids are checked against ``num_types`` once per table,
        on the host, where the table is set (the chain's GraphLookup)."""
        compiling = torch.compiler.is_compiling()
        cache = self._graph_cache
        if (
            compiling
            or cache is None
            or any(a is not b for a, b in zip(cache[0], (types, adj, mask), strict=True))
            or cache[1] != (types._version, adj._version, mask._version)
        ):
            cache = ((types, adj, mask), (types._version, adj._version, mask._version), {})
            if not compiling:
                self._graph_cache = cache
        out = cache[2].get((what, dtype))
        if out is None:
            if what == "types":
                out = F.one_hot(types.clamp_min(0), self.num_types).to(dtype)
            else:
                out = normalized_adjacency(adj, mask, dtype)
            cache[2][(what, dtype)] = out
        return out

    def forward(self, limbs: Tensor, adj: Tensor, mask: Tensor) -> Tensor:
        dtype = self.embed.weight.dtype
        if self.context_dim:
            h = self.embed(limbs.to(dtype))
        else:
            h = self.embed(self.graph(limbs, adj, mask, "types", dtype))
        a_hat = self.graph(limbs, adj, mask, "a_hat", h.dtype)
        for layer in self.layers:
            h = layer(h, a_hat)
        return torch.where(mask.unsqueeze(-1), h, 0.0)


def gcn_stage(num_types: int, width: int, layers: int, context_dim: int = 0) -> TensorDictModule:
    """The GCN over limb types (``limbs/type``), or over the limb context with ``context_dim``.
    Its backbone bounds the type ids in the robot table (``Backbone.limits``)."""
    limbs = K.CONTEXT if context_dim else K.TYPE
    return TensorDictModule(
        LimbGCN(num_types, width, layers, context_dim), [limbs, K.ADJ, K.MASK], [K.GCN]
    )


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
        ppr, lap = as_dtype(ppr, self.lin.weight.dtype), as_dtype(lap, self.lin.weight.dtype)
        n = mask.sum(-1).clamp_min(1).to(ppr.dtype)[..., None, None]
        pair = mask.unsqueeze(-1) & mask.unsqueeze(-2) & (dist != DIST_PAD)
        hop = torch.where(pair, as_dtype(dist, ppr.dtype) / n, 0.0)
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
            bias = as_dtype(bias, x.dtype)
        return self.encoder(x, mask, bias).reshape(*lead, *x.shape[1:])


def encoder_of(cfg, bias_mode: str = "per_layer") -> TransformerEncoder:
    """The shared Transformer encoder at the sizes of a Transformer config (d_model, layers,
    heads, ff, dropout, norm_first, final_norm)."""
    return TransformerEncoder(
        cfg.d_model,
        cfg.layers,
        cfg.heads,
        cfg.ff,
        cfg.dropout,
        norm_first=cfg.norm_first,
        final_norm=cfg.final_norm,
        bias_mode=bias_mode,
    )


def transformer_stage(
    encoder: TransformerEncoder, in_key=K.HIDDEN, with_bias: bool = False
) -> TensorDictModule:
    in_keys = [in_key, K.MASK] + ([K.ATTN_BIAS] if with_bias else [])
    return TensorDictModule(LimbTransformer(encoder, with_bias), in_keys, [K.FEATURES])


class ContextLimbTransformer(nn.Module):
    """Runs a :class:`ContextTransformer` (ModuMorph's fixed attention) on [*, K, d] tokens with
    the context embedding [*, K, d] and the limb mask; flattens the leading dims."""

    def __init__(self, encoder: ContextTransformer) -> None:
        super().__init__()
        self.encoder = encoder

    def forward(self, x: Tensor, ctx: Tensor, mask: Tensor) -> Tensor:
        x, lead = flatten_lead(x, 2)
        ctx, _ = flatten_lead(ctx, 2)
        mask, _ = flatten_lead(mask, 1)
        return self.encoder(x, as_dtype(ctx, x.dtype), mask).reshape(*lead, *x.shape[1:])


def context_transformer_stage(encoder: ContextTransformer, in_key=K.EMBED) -> TensorDictModule:
    return TensorDictModule(
        ContextLimbTransformer(encoder), [in_key, K.ATTN_CONTEXT, K.MASK], [K.FEATURES]
    )


# ------------------------------------------------------------------- position embedding


class PositionEmbedding(nn.Module):
    """A learned embedding of each limb's slot index (its depth-first pre-order position), added
    to the token, then dropout (MetaMorph). ``max_limbs`` rows, initialised N(0, 1); slots past
    ``max_limbs`` (padding only: the chain rejects larger robots) get no embedding."""

    def __init__(self, max_limbs: int, d_model: int, dropout: float = 0.0) -> None:
        super().__init__()
        self.max_limbs = max_limbs
        self.pe = nn.Parameter(torch.randn(max_limbs, d_model))
        self.drop = nn.Dropout(dropout) if dropout > 0 else nn.Identity()  # no op at p=0

    def forward(self, embed: Tensor) -> Tensor:
        k = embed.shape[-2]
        pe = as_dtype(self.pe[:k], embed.dtype)
        if k > self.max_limbs:
            pe = torch.cat([pe, pe.new_zeros(k - self.max_limbs, pe.shape[-1])])
        return self.drop(embed + pe)


def position_embedding_stage(max_limbs: int, d_model: int, dropout: float) -> TensorDictModule:
    return TensorDictModule(PositionEmbedding(max_limbs, d_model, dropout), [K.EMBED], [K.HIDDEN])


# ------------------------------------------------------------------- context, hypernetwork


def context_width(table, owner: str) -> int:
    """C, the width of ``limbs/context`` in the robot table; a ValueError if it has none."""
    if K.CONTEXT not in table.keys(True):
        raise ValueError(
            f"{owner} reads the static limb context ('limbs', 'context') from the robot table, "
            "which has none (UNIMAL robot tables carry it)"
        )
    return int(table.get(K.CONTEXT).shape[-1])


#: ModuMorph's context embeddings (``context_embed_HN``, ``context_embed_attention``) start with
#: weights U(±0.1) (its ``HN_EMBED_INIT`` and ``EMBED_INIT``); their other layers keep PyTorch's
#: defaults
CONTEXT_EMBED_BOUND = 0.1


class ContextMLP(nn.Module):
    """An MLP over each limb's static context ``limbs/context`` [*, K, C] with a ReLU after
    every layer, its first layer's weight U(±:data:`CONTEXT_EMBED_BOUND`), as ModuMorph's."""

    def __init__(self, ctx_dim: int, widths: Sequence[int]) -> None:
        super().__init__()
        self.net = mlp(ctx_dim, widths[:-1], widths[-1], final_activation=True)
        first = self.net[0]
        nn.init.uniform_(first.weight, -CONTEXT_EMBED_BOUND, CONTEXT_EMBED_BOUND)

    def forward(self, ctx: Tensor) -> Tensor:
        return self.net(as_dtype(ctx, self.net[0].weight.dtype))


def context_stage(ctx_dim: int, widths: Sequence[int], out_key) -> TensorDictModule:
    return TensorDictModule(ContextMLP(ctx_dim, widths), [K.CONTEXT], [out_key])


class HyperEncoder(nn.Module):
    """The limb-observation embedding generated per limb from its context embedding:
    ``HyperLinear(F → d)(x, h)``, scaled by √d (ModuMorph; embedding weights start U(±0.1))."""

    def __init__(self, hn_dim: int, in_dim: int, d_model: int, scale: bool = True) -> None:
        super().__init__()
        self.d_model, self.scale = d_model, scale
        self.lin = HyperLinear(hn_dim, in_dim, d_model, weight_bound=0.1)

    def forward(self, x: Tensor, h: Tensor) -> Tensor:
        return scaled(self.lin(as_dtype(x, h.dtype), h), self.d_model, self.scale)


def hyper_encoder_stage(hn_dim: int, in_dim: int, d_model: int, scale: bool) -> TensorDictModule:
    return TensorDictModule(
        HyperEncoder(hn_dim, in_dim, d_model, scale), [K.INPUT, K.HN_CONTEXT], [K.EMBED]
    )


# ------------------------------------------------------------------------ height map


class HFieldEncoder(nn.Module):
    """The height map's MLP ``H → 64 → 64`` (ReLU after both), one vector per sample."""

    def __init__(self, hfield_dim: int, width: int = HFIELD_WIDTH) -> None:
        super().__init__()
        self.net = mlp(hfield_dim, (width,), width, final_activation=True)

    def forward(self, hfield: Tensor) -> Tensor:
        return self.net(as_dtype(hfield, self.net[0].weight.dtype))


def hfield_stage(hfield_dim: int) -> TensorDictModule:
    return TensorDictModule(HFieldEncoder(hfield_dim), [K.HFIELD], [K.HFIELD_EMBED])


# ------------------------------------------------------------------------ per-limb head


def _decoder_input(features: Tensor, parts: Sequence[Tensor], raw: bool, hfield: bool) -> Tensor:
    feats = [features]
    it = iter(parts)
    if raw:
        feats.append(next(it).to(features.dtype))
    if hfield:
        h = next(it).to(features.dtype)  # [*, W]: the same for every limb of a sample
        feats.append(h.unsqueeze(-2).expand(*features.shape[:-1], h.shape[-1]))
    return torch.cat(feats, -1) if len(feats) > 1 else features


class LimbHead(nn.Module):
    """The per-limb decoder shared by every method: [features ‖ raw limb input (AMORPHEUS's
    residual, if ``raw_dim``) ‖ encoded height map (if ``hfield_width``)] → hidden… → out, the
    same MLP for every limb. ``hidden`` is () without a height map and (64,) with one."""

    def __init__(
        self,
        feat_dim: int,
        out_dim: int,
        *,
        raw_dim: int = 0,
        hfield_width: int = 0,
        hidden: Sequence[int] = (),
    ) -> None:
        super().__init__()
        self.raw, self.hfield = raw_dim > 0, hfield_width > 0
        self.net = mlp(feat_dim + raw_dim + hfield_width, hidden, out_dim)

    def forward(self, features: Tensor, *parts: Tensor) -> Tensor:
        return self.net(_decoder_input(features, parts, self.raw, self.hfield))


class HyperHead(nn.Module):
    """The decoder with per-limb weights generated from the limb's context embedding (ModuMorph):
    one :class:`HyperLinear` per layer (ReLU between), weights starting U(±0.01). Same inputs as
    :class:`LimbHead`, after the context embedding."""

    def __init__(
        self,
        hn_dim: int,
        feat_dim: int,
        out_dim: int,
        *,
        raw_dim: int = 0,
        hfield_width: int = 0,
        hidden: Sequence[int] = (),
    ) -> None:
        super().__init__()
        self.raw, self.hfield = raw_dim > 0, hfield_width > 0
        dims = [feat_dim + raw_dim + hfield_width, *hidden, out_dim]
        self.layers = nn.ModuleList(
            HyperLinear(hn_dim, a, b, weight_bound=0.01)
            for a, b in zip(dims[:-1], dims[1:], strict=True)
        )

    def forward(self, h: Tensor, features: Tensor, *parts: Tensor) -> Tensor:
        x = _decoder_input(features, parts, self.raw, self.hfield)
        for i, layer in enumerate(self.layers):
            x = layer(x, h)
            if i < len(self.layers) - 1:
                x = F.relu(x)
        return x


def limb_head_stage(
    feat_dim: int,
    out_dim: int,
    *,
    raw_dim: int = 0,
    hfield_width: int = 0,
    hyper_dim: int = 0,
    hidden: Sequence[int] = (),
) -> TensorDictModule:
    """The decoder stage ``limbs/features`` (‖ ``limbs/input`` if ``raw_dim``) (‖ ``hfield_embed``
    if ``hfield_width``) → ``hidden`` (ReLU) → ``limbs/out``; per-limb generated weights if
    ``hyper_dim`` (the hypernetwork context width, read from ``limbs/hn_context``)."""
    hidden = tuple(hidden)
    in_keys = (
        [K.FEATURES] + ([K.INPUT] if raw_dim else []) + ([K.HFIELD_EMBED] if hfield_width else [])
    )
    kw = dict(raw_dim=raw_dim, hfield_width=hfield_width, hidden=hidden)
    if hyper_dim:
        return TensorDictModule(
            HyperHead(hyper_dim, feat_dim, out_dim, **kw), [K.HN_CONTEXT, *in_keys], [K.OUT]
        )
    return TensorDictModule(LimbHead(feat_dim, out_dim, **kw), in_keys, [K.OUT])


def token_ends(cfg, io) -> tuple[TensorDictModule, TensorDictModule]:
    """The two ends of a Transformer over limb tokens (AMORPHEUS, SWAT): the limb encoder
    (``limbs/input`` → ``limbs/embed``, scaled by ``cfg.input_scale``) and the decoder over
    [features ‖ raw input (‖ height-map embedding)] with the world's hidden layers, both
    initialised as ``cfg.init`` names."""
    encoder = limb_encoder_stage(io.in_dim, cfg.d_model, (), cfg.input_scale)
    head = limb_head_stage(
        cfg.d_model,
        io.out_dim,
        raw_dim=io.in_dim,
        hfield_width=io.hfield_width,
        hidden=io.decoder_hidden,
    )
    init_like_original(cfg.init, embeddings=[encoder.module], decoder=head.module)
    return encoder, head
