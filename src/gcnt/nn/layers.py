"""Plain torch building blocks shared by GCNT and the baselines (no method imports another).

* :class:`EncoderLayer`: the Transformer encoder layer of the package (GCNT, AMORPHEUS, SWAT,
  MetaMorph): multi-head self-attention (:func:`attention`) with an additive float mask (a
  learned bias plus ``-inf`` on padded keys), then a ReLU feed-forward block, with post-LN
  (AMORPHEUS) or pre-LN (MetaMorph) residuals. Its parameter shapes and initial attention
  weights match ``torch.nn.TransformerEncoderLayer``'s.
* :class:`ContextAttentionLayer`: ModuMorph's "fixed attention" layer (queries and keys from a
  static context embedding, values from the token stream).
* :class:`HyperLinear`: a per-limb linear map whose weight and bias a hypernetwork generates from
  the limb's context embedding (ModuMorph, GCNT+HN).
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn


def mlp(
    in_dim: int,
    hidden: Sequence[int],
    out_dim: int,
    activation=nn.ReLU,
    final_activation: bool = False,
) -> nn.Sequential:
    """Linear layers ``in → hidden… → out`` with ``activation`` between them (and after the last
    one if ``final_activation``)."""
    dims = [in_dim, *hidden, out_dim]
    layers: list[nn.Module] = []
    for i, (a, b) in enumerate(zip(dims[:-1], dims[1:], strict=True)):
        layers.append(nn.Linear(a, b))
        if i < len(dims) - 2 or final_activation:
            layers.append(activation())
    return nn.Sequential(*layers)


def as_dtype(x: Tensor, dtype: torch.dtype) -> Tensor:
    """``x`` in ``dtype``: ``x`` itself when it already is (``Tensor.to`` would still dispatch an
    operator, and a network's forward asks this of tensors that mostly are)."""
    return x if x.dtype == dtype else x.to(dtype)


def last_linear(net: nn.Module) -> nn.Linear:
    """The last ``nn.Linear`` of ``net`` (for output-layer initialisation)."""
    found = [m for m in net.modules() if isinstance(m, nn.Linear)]
    if not found:
        raise ValueError(f"no Linear layer in {type(net).__name__}")
    return found[-1]


#: on a CPU, sequences up to this many tokens take :func:`attention`'s batched-matmul path
SHORT_SEQUENCE = 32


def attention(q: Tensor, k: Tensor, v: Tensor, attn_mask: Tensor, dropout_p: float = 0.0) -> Tensor:
    """softmax(q·kᵀ/√d_h + attn_mask)·v for ``q, k, v`` [N, H, L, d_h] and an additive float
    mask broadcastable to [N, H, L, L]: ``F.scaled_dot_product_attention``'s result.

    Robots have a handful of limbs, and for so few tokens torch's CPU kernels are slow where
    the arithmetic is tiny: the flash kernel tiles for long sequences (0.8 ms for 384 robots × 2
    heads × 5 limbs on one core, a batched matmul 0.4 ms), and ``torch.softmax`` over a last dim
    of 5 costs ~20 ns per element. On a CPU, without attention dropout and for up to
    :data:`SHORT_SEQUENCE` tokens, the same formula therefore runs as two batched matmuls and a
    softmax from elementwise ops (max-subtracted, as every softmax kernel does); anything else
    goes to ``F.scaled_dot_product_attention``.
    """
    n, h, length, d = q.shape
    if q.device.type != "cpu" or dropout_p > 0 or length > SHORT_SEQUENCE:
        return F.scaled_dot_product_attention(q, k, v, attn_mask=attn_mask, dropout_p=dropout_p)
    b = n * h
    mask = attn_mask.expand(n, h, length, length).reshape(b, length, length)
    logits = torch.baddbmm(
        mask,
        q.reshape(b, length, d),
        k.reshape(b, length, d).transpose(1, 2),
        alpha=1.0 / math.sqrt(d),
    )
    # the max only keeps exp() in range: it cancels out of the result, so no gradient through it
    e = (logits - logits.amax(-1, keepdim=True).detach()).exp()
    weights = e / e.sum(-1, keepdim=True)
    return torch.bmm(weights, v.reshape(b, length, d)).view(n, h, length, d)


def key_padding_bias(mask: Tensor, dtype: torch.dtype) -> Tensor:
    """Additive attention mask [N, 1, 1, K]: 0 on real keys, -inf on padded ones."""
    return as_dtype(torch.where(mask[:, None, None, :], 0.0, float("-inf")), dtype)


class EncoderLayer(nn.Module):
    """Transformer encoder layer whose attention logits take an additive bias.

    ``forward(x [N, K, d], attn_mask [N, H or 1, K, K] float)``: the mask is added to
    ``q·k/√d_h`` before the softmax (bias + ``-inf`` on padded keys).
    """

    def __init__(
        self, d_model: int, heads: int, ff: int, dropout: float = 0.0, norm_first: bool = False
    ) -> None:
        super().__init__()
        if d_model % heads:
            raise ValueError(f"d_model {d_model} not divisible by heads {heads}")
        self.heads = heads
        self.dropout = dropout
        self.norm_first = norm_first
        self.qkv = nn.Linear(d_model, 3 * d_model)
        self.proj = nn.Linear(d_model, d_model)
        self.ff1 = nn.Linear(d_model, ff)
        self.ff2 = nn.Linear(ff, d_model)
        self.norm1 = nn.LayerNorm(d_model)
        self.norm2 = nn.LayerNorm(d_model)
        self.drop = nn.Dropout(dropout) if dropout > 0 else nn.Identity()  # no op at p=0
        self.reset_attention_parameters()

    def reset_attention_parameters(self) -> None:
        """``nn.MultiheadAttention``'s initial weights, which every original Transformer method
        uses (AMORPHEUS, SWAT, MetaMorph, ModuMorph): the stacked Q/K/V in-projection
        xavier-uniform over its [3d, d] weight, zero in- and out-projection biases; the
        out-projection weight keeps ``nn.Linear``'s default."""
        nn.init.xavier_uniform_(self.qkv.weight)
        nn.init.zeros_(self.qkv.bias)
        nn.init.zeros_(self.proj.bias)

    def attention(self, x: Tensor, attn_mask: Tensor) -> Tensor:
        n, k, d = x.shape
        q, kk, v = self.qkv(x).view(n, k, 3, self.heads, d // self.heads).permute(2, 0, 3, 1, 4)
        out = attention(q, kk, v, attn_mask, self.dropout if self.training else 0.0)
        return self.proj(out.transpose(1, 2).reshape(n, k, d))

    def feed_forward(self, x: Tensor) -> Tensor:
        return self.ff2(self.drop(F.relu(self.ff1(x))))

    def forward(self, x: Tensor, attn_mask: Tensor) -> Tensor:
        if self.norm_first:
            x = x + self.drop(self.attention(self.norm1(x), attn_mask))
            return x + self.drop(self.feed_forward(self.norm2(x)))
        x = self.norm1(x + self.drop(self.attention(x, attn_mask)))
        return self.norm2(x + self.drop(self.feed_forward(x)))


def clones(layer: nn.Module, n: int) -> nn.ModuleList:
    """``n`` layers that start as copies of ``layer``, as every original builds a Transformer's
    stack (torch's ``TransformerEncoder``, ``_get_clones``: deep copies of one layer)."""
    return nn.ModuleList(copy.deepcopy(layer) for _ in range(n))


class TransformerEncoder(nn.Module):
    """A stack of :class:`EncoderLayer` with an optional final LayerNorm.

    ``forward(x [N, K, d], mask [N, K] bool, bias [N, Lb, H, K, K] | None)``. How the bias tensor
    maps onto layers is ``bias_mode``: "per_layer" (Lb = layers), "shared" (Lb = 1, every layer)
    or "first" (Lb = 1, first layer only, as SWAT's relational bias).
    """

    BIAS_MODES = ("per_layer", "shared", "first")

    def __init__(
        self,
        d_model: int,
        layers: int,
        heads: int,
        ff: int,
        dropout: float = 0.0,
        norm_first: bool = False,
        final_norm: bool = True,
        bias_mode: str = "per_layer",
    ) -> None:
        super().__init__()
        if bias_mode not in self.BIAS_MODES:
            raise ValueError(f"bias_mode must be one of {self.BIAS_MODES}, got {bias_mode!r}")
        self.bias_mode = bias_mode
        self.heads = heads
        self.layers = clones(EncoderLayer(d_model, heads, ff, dropout, norm_first), layers)
        self.norm = nn.LayerNorm(d_model) if final_norm else None

    def forward(self, x: Tensor, mask: Tensor, bias: Tensor | None = None) -> Tensor:
        base = key_padding_bias(mask, x.dtype)  # [N, 1, 1, K]
        for i, layer in enumerate(self.layers):
            if bias is None:
                m = base
            elif self.bias_mode == "per_layer":
                m = base + bias[:, i]
            elif self.bias_mode == "shared" or i == 0:
                m = base + bias[:, 0]
            else:
                m = base
            x = layer(x, m)
        return self.norm(x) if self.norm is not None else x


class ContextAttentionLayer(EncoderLayer):
    """ModuMorph's "fixed attention" encoder layer (pre-LN).

    Queries and keys come from this layer's own LayerNorm of a static context embedding
    ``ctx`` [N, K, d] (the same for every layer, computed once per robot), values from the
    LayerNorm of the token stream ``x``; the attention pattern therefore depends only on the
    robot, not on its state. Feed-forward and residuals as a pre-LN :class:`EncoderLayer`; the
    projection weights keep ``EncoderLayer``'s shapes (one ``qkv`` Linear, Q/K/V slices of it).
    """

    def __init__(self, d_model: int, heads: int, ff: int, dropout: float = 0.0) -> None:
        super().__init__(d_model, heads, ff, dropout, norm_first=True)
        self.norm_ctx = nn.LayerNorm(d_model)

    def context_attention(self, x: Tensor, ctx: Tensor, attn_mask: Tensor) -> Tensor:
        n, k, d = x.shape
        w, b = self.qkv.weight, self.qkv.bias
        c = self.norm_ctx(ctx)

        def heads(t: Tensor) -> Tensor:
            return t.view(n, k, self.heads, d // self.heads).transpose(1, 2)

        q = heads(F.linear(c, w[:d], b[:d]))
        kk = heads(F.linear(c, w[d : 2 * d], b[d : 2 * d]))
        v = heads(F.linear(x, w[2 * d :], b[2 * d :]))
        out = attention(q, kk, v, attn_mask, self.dropout if self.training else 0.0)
        return self.proj(out.transpose(1, 2).reshape(n, k, d))

    def forward(self, x: Tensor, ctx: Tensor, attn_mask: Tensor) -> Tensor:  # type: ignore[override]
        x = x + self.drop(self.context_attention(self.norm1(x), ctx, attn_mask))
        return x + self.drop(self.feed_forward(self.norm2(x)))


class ContextTransformer(nn.Module):
    """A stack of :class:`ContextAttentionLayer` (no final LayerNorm, as ModuMorph).

    ``forward(x [N, K, d], ctx [N, K, d], mask [N, K] bool)``.
    """

    def __init__(self, d_model: int, layers: int, heads: int, ff: int, dropout: float = 0.0):
        super().__init__()
        self.layers = clones(ContextAttentionLayer(d_model, heads, ff, dropout), layers)

    def forward(self, x: Tensor, ctx: Tensor, mask: Tensor) -> Tensor:
        m = key_padding_bias(mask, x.dtype)
        for layer in self.layers:
            x = layer(x, ctx, m)
        return x


class HyperLinear(nn.Module):
    """A Linear(in → out) per limb whose weight and bias are generated from the limb's context
    embedding ``h`` [*, K, c]: ``W = Linear(c → in·out)(h)``, ``b = Linear(c → out)(h)``.

    Initialisation (ModuMorph): the generators' weights start at 0, so at first every limb gets
    the same map; the weight generator's bias is U(±``weight_bound``) (the initial shared
    weight), the bias generator's bias 0.
    """

    def __init__(self, ctx_dim: int, in_dim: int, out_dim: int, weight_bound: float) -> None:
        super().__init__()
        self.in_dim, self.out_dim = in_dim, out_dim
        self.weight = nn.Linear(ctx_dim, in_dim * out_dim)
        self.bias = nn.Linear(ctx_dim, out_dim)
        nn.init.zeros_(self.weight.weight)
        nn.init.uniform_(self.weight.bias, -weight_bound, weight_bound)
        nn.init.zeros_(self.bias.weight)
        nn.init.zeros_(self.bias.bias)

    def forward(self, x: Tensor, h: Tensor) -> Tensor:
        w = self.weight(h).unflatten(-1, (self.in_dim, self.out_dim))
        return torch.einsum("...i,...io->...o", x, w) + self.bias(h)


def flatten_lead(x: Tensor, keep: int) -> tuple[Tensor, torch.Size]:
    """Merge all but the last ``keep`` dims into one: ``[*L, ...] → [N, ...]``."""
    lead = x.shape[: x.dim() - keep]
    return x.reshape(-1, *x.shape[x.dim() - keep :]), lead


def scaled(x: Tensor, d_model: int, on: bool) -> Tensor:
    return x * math.sqrt(d_model) if on else x
