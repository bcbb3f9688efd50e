"""GCNT (paper section 3, appendix A) as a chain of stages.

::

    limbs/input ─ encoder (MLP F→d, ·√d) ──────────────────────────┐
    limbs/type, graph/adj ─ gcn (one-hot → width, 4 residual GCN) ─┤ fusion: + Linear([GCN ‖ WL] → d)
    graph/wl ──────────────────────────────────────────────────────┘
    graph/dist ─ dist_bias (Embedding(clamped hop distance) → one bias per head per layer)
    → transformer (post-LN encoder layers, bias added to q·k/√d_h, padded keys masked, final LN)
    → head: Linear(output ‖ limbs/input → out) per limb

Choices the paper leaves open, made here and documented:

* **Limb encoder**: one Linear(F→d) scaled by √d (``encoder_hidden=()``), the AMORPHEUS/SWAT
  encoder of the codebase GCNT was built on; set ``encoder_hidden`` for a deeper MLP.
* **Transformer**: post-LN with a final LayerNorm, as AMORPHEUS/SWAT (appendix A: GCNT was
  implemented on SWAT's code); ``norm_first=True`` gives pre-LN.
* **Distance bias**: one zero-initialised embedding table per layer (``dist_bias="per_layer"``;
  "shared" uses one for all layers), over hop distances clamped to ``max_dist``; zero init means
  training starts from the plain Transformer.
* **WL counts** enter raw (counts, not frequencies), as the paper describes.
"""

from __future__ import annotations

from gcnt.nn import keys as K
from gcnt.nn.chain import Backbone
from gcnt.nn.config import GCNTConfig
from gcnt.nn.layers import TransformerEncoder
from gcnt.nn.stages import (
    distance_bias_stage,
    fusion_stage,
    gcn_stage,
    limb_encoder_stage,
    limb_head_stage,
    transformer_stage,
)


def encoder_of(cfg, bias_mode: str = "per_layer") -> TransformerEncoder:
    """The shared Transformer encoder at a config's sizes."""
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


def gcnt_backbone(cfg: GCNTConfig, in_dim: int, out_dim: int, wl_dim: int) -> Backbone:
    """GCNT's stages from ``limbs/input`` (width ``in_dim``) to ``limbs/out`` (``out_dim``)."""
    stages = [
        ("encoder", limb_encoder_stage(in_dim, cfg.d_model, cfg.encoder_hidden, cfg.input_scale))
    ]
    static = []
    if cfg.use_gcn:
        stages.append(("gcn", gcn_stage(cfg.num_limb_types, cfg.gcn_width, cfg.gcn_layers)))
        static += [K.TYPE, K.ADJ]
    if cfg.use_wl:
        static.append(K.WL)
    hidden_key = K.EMBED
    if cfg.use_gcn or cfg.use_wl:
        gw = cfg.gcn_width if cfg.use_gcn else 0
        stages.append(("fusion", fusion_stage(cfg.d_model, gw, wl_dim if cfg.use_wl else 0)))
        hidden_key = K.HIDDEN
    if cfg.use_dist_bias:
        tables = cfg.layers if cfg.dist_bias == "per_layer" else 1
        stages.append(("dist_bias", distance_bias_stage(cfg.max_dist, cfg.heads, tables)))
        static.append(K.DIST)
    enc = encoder_of(cfg, "per_layer" if cfg.dist_bias == "per_layer" else "shared")
    stages.append(("transformer", transformer_stage(enc, hidden_key, cfg.use_dist_bias)))
    stages.append(("head", limb_head_stage(cfg.d_model, in_dim, out_dim)))
    return Backbone(stages, tuple(static), name="GCNT")
