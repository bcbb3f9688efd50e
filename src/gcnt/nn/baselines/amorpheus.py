"""AMORPHEUS (Kurin et al. 2021): a Transformer over limb tokens with no positional information.

Input Linear(F→d)·√d; post-LN encoder layers (ReLU, dropout 0) and a final LayerNorm; decoder
Linear(output ‖ raw limb input → out) per limb. Same encoder layer and head as GCNT.
"""

from __future__ import annotations

from gcnt.nn import keys as K
from gcnt.nn.chain import Backbone
from gcnt.nn.config import TransformerConfig
from gcnt.nn.gcnt import encoder_of
from gcnt.nn.stages import limb_encoder_stage, limb_head_stage, transformer_stage


def amorpheus_backbone(cfg: TransformerConfig, in_dim: int, out_dim: int) -> Backbone:
    return Backbone(
        [
            ("encoder", limb_encoder_stage(in_dim, cfg.d_model, (), cfg.input_scale)),
            ("transformer", transformer_stage(encoder_of(cfg), K.EMBED, with_bias=False)),
            ("head", limb_head_stage(cfg.d_model, in_dim, out_dim)),
        ],
        name="AMORPHEUS",
    )
