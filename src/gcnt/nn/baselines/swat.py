"""SWAT (Hong et al. 2022): AMORPHEUS plus structural information.

* Traversal position embeddings: each limb's pre-order index, and its in-order and post-order
  index in the left-child right-sibling binary tree (``graph/traversal``), each through its own
  embedding table (widths 42/42/44, concatenated to d = 128), added to the input embedding.
  The tables have ``max_limbs`` rows: a table with a larger robot raises ``RobotTooLargeError``
  naming it when the chain is built or the robot table is swapped.
* Relational bias: Linear(3 → heads) of [personalised PageRank, normalised Laplacian,
  hop distance / N] per limb pair, added to the attention logits of the first layer only.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule
from torch import Tensor, nn

from gcnt import keys as K
from gcnt.nn.chain import Backbone, NetIO
from gcnt.nn.config import SWATConfig
from gcnt.nn.layers import as_dtype
from gcnt.nn.stages import (
    encoder_of,
    relational_bias_stage,
    token_ends,
    transformer_stage,
)


class TraversalEmbedding(nn.Module):
    """embed + [E_pre(pre) ‖ E_in(in) ‖ E_post(post)]."""

    def __init__(self, widths: tuple[int, int, int], max_limbs: int) -> None:
        super().__init__()
        self.max_limbs = max_limbs
        self.tables = nn.ModuleList(nn.Embedding(max_limbs, w) for w in widths)

    def forward(self, embed: Tensor, traversal: Tensor) -> Tensor:
        # positions past max_limbs are refused once per robot table (Backbone.limits)
        pe = torch.cat([t(traversal[..., i]) for i, t in enumerate(self.tables)], -1)
        return embed + as_dtype(pe, embed.dtype)


def swat_backbone(cfg: SWATConfig, io: NetIO, table: TensorDictBase) -> Backbone:
    encoder, head = token_ends(cfg, io)
    return Backbone(
        [
            ("encoder", encoder),
            (
                "traversal",
                TensorDictModule(
                    TraversalEmbedding(cfg.traversal_widths, cfg.max_limbs),
                    [K.EMBED, K.TRAVERSAL],
                    [K.HIDDEN],
                ),
            ),
            ("relational_bias", relational_bias_stage(cfg.heads)),
            ("transformer", transformer_stage(encoder_of(cfg, "first"), K.HIDDEN, with_bias=True)),
            ("head", head),
        ],
        static_keys=(K.TRAVERSAL, K.PPR, K.LAPLACIAN, K.DIST),
        max_limbs=cfg.max_limbs,
        name="SWAT",
        limits={K.TRAVERSAL: (cfg.max_limbs, "max_limbs")},
    )
