"""AMORPHEUS (Kurin et al. 2021): a Transformer over limb tokens with no positional information.

Input Linear(F→d)·√d; post-LN encoder layers (ReLU, dropout 0) and a final LayerNorm; decoder
[output ‖ raw limb input (‖ height-map embedding)] → (64 →) out per limb. Init as the AMORPHEUS
code (``init="amorpheus"``, :mod:`gcnt.nn.init`).
"""

from __future__ import annotations

from tensordict import TensorDictBase

from gcnt import keys as K
from gcnt.nn.chain import Backbone, NetIO
from gcnt.nn.config import TransformerConfig
from gcnt.nn.stages import encoder_of, token_ends, transformer_stage


def amorpheus_backbone(cfg: TransformerConfig, io: NetIO, table: TensorDictBase) -> Backbone:
    encoder, head = token_ends(cfg, io)
    return Backbone(
        [
            ("encoder", encoder),
            ("transformer", transformer_stage(encoder_of(cfg), K.EMBED, with_bias=False)),
            ("head", head),
        ],
        name="AMORPHEUS",
    )
