"""MetaMorph (Gupta et al. 2022) and MetaMorph* (Xiong et al. 2023).

::

    limbs/input ─ encoder: Linear(F→d)·√d ─ + position embedding (limb slot = depth-first index)
      → dropout 0.1 → pre-LN encoder layers (no final LayerNorm)
      → head: output (‖ height-map embedding) → (64 →) out, per limb (no raw-input residual)

MetaMorph* drops the position embedding and the embedding dropout. Init (``init="metamorph"``,
:mod:`gcnt.nn.init`): embedding weight U(±0.1); last decoder layer weight U(±0.01), bias 0;
position table N(0, 1). The position table has
``max_limbs`` rows (12, UNIMAL's padding): the chain rejects a robot with more limbs.
"""

from __future__ import annotations

from tensordict import TensorDictBase

from gcnt import keys as K
from gcnt.nn.chain import Backbone, NetIO
from gcnt.nn.config import MetaMorphConfig
from gcnt.nn.init import init_like_original
from gcnt.nn.stages import (
    encoder_of,
    limb_encoder_stage,
    limb_head_stage,
    position_embedding_stage,
    transformer_stage,
)


def metamorph_backbone(cfg: MetaMorphConfig, io: NetIO, table: TensorDictBase) -> Backbone:
    encoder = limb_encoder_stage(io.in_dim, cfg.d_model, (), cfg.input_scale)
    head = limb_head_stage(
        cfg.d_model, io.out_dim, hfield_width=io.hfield_width, hidden=io.decoder_hidden
    )
    init_like_original(cfg.init, embeddings=[encoder.module], decoder=head.module)
    stages = [("encoder", encoder)]
    token_key = K.EMBED
    if cfg.position_embedding:
        stages.append(
            ("position", position_embedding_stage(cfg.max_limbs, cfg.d_model, cfg.embed_dropout))
        )
        token_key = K.HIDDEN
    elif cfg.embed_dropout:
        raise ValueError(
            "MetaMorphConfig.embed_dropout applies with the position embedding only "
            "(MetaMorph* has neither)"
        )
    stages += [
        ("transformer", transformer_stage(encoder_of(cfg), token_key, with_bias=False)),
        ("head", head),
    ]
    name = "MetaMorph" if cfg.position_embedding else "MetaMorph*"
    return Backbone(stages, max_limbs=cfg.max_limbs if cfg.position_embedding else None, name=name)
