"""ModuMorph (Xiong et al. 2023): a Transformer whose limb encoder and decoder weights are
generated per limb by a hypernetwork from the limb's static context, with "fixed attention".

::

    limbs/context ─ hn_context: MLP C → 128 → 128 (ReLU) ─────────────── h (per limb)
    limbs/input, h ─ encoder: HyperLinear(F → d)(x, h) · √d
    limbs/context ─ attn_context: MLP C → 128 → 128 → 128 (ReLU after each) ─ c (once per robot)
    → fixed-attention layers: Q, K from LayerNorm_l(c), V from the pre-LN token stream; no final LN
    → head: HyperLinear layers over [output (‖ height-map embedding)] → (64 →) out, ReLU between

No position embedding, no dropout. The hypernetwork's generators start with zero weights, so every
limb starts with the same maps: embedding weights U(±0.1), decoder weights U(±0.01), biases 0.
The first layer of each context MLP starts with weights U(±0.1), and both MLPs end with a ReLU,
as the original's ``context_embed_HN`` / ``context_encoder_HN`` and ``context_embed_attention`` /
``context_encoder_attention`` (``MasterXiong/ModuMorph`` ``metamorph/algos/ppo/model.py``).
The context ``limbs/context`` [R, K, C] comes from the robot table (C = 35 on UNIMAL, scaled to
[-1, 1]); a table without it is an error naming the key.
"""

from __future__ import annotations

from tensordict import TensorDictBase

from gcnt import keys as K
from gcnt.nn.chain import Backbone, NetIO
from gcnt.nn.config import ModuMorphConfig
from gcnt.nn.layers import ContextTransformer
from gcnt.nn.stages import (
    context_stage,
    context_transformer_stage,
    context_width,
    encoder_of,
    hyper_encoder_stage,
    limb_head_stage,
    transformer_stage,
)


def modumorph_backbone(cfg: ModuMorphConfig, io: NetIO, table: TensorDictBase) -> Backbone:
    ctx = context_width(table, "ModuMorph")
    hn = cfg.hn_width
    stages = [
        ("hn_context", context_stage(ctx, (hn, hn), K.HN_CONTEXT)),
        ("encoder", hyper_encoder_stage(hn, io.in_dim, cfg.d_model, cfg.input_scale)),
    ]
    if cfg.fixed_attention:
        attn_context = context_stage(ctx, cfg.attn_context_widths, K.ATTN_CONTEXT)
        stages.append(("attn_context", attn_context))
        enc = ContextTransformer(cfg.d_model, cfg.layers, cfg.heads, cfg.ff, cfg.dropout)
        stages.append(("transformer", context_transformer_stage(enc)))
    else:
        stages.append(("transformer", transformer_stage(encoder_of(cfg), K.EMBED)))
    head = limb_head_stage(
        cfg.d_model, io.out_dim, hfield_width=io.hfield_width, hyper_dim=hn, hidden=io.decoder_hidden
    )
    stages.append(("head", head))
    return Backbone(stages, static_keys=(K.CONTEXT,), name="ModuMorph")
