"""SR (single-robot reference, SR-fair / SR-top): one plain MLP over one robot's flattened padded
limb inputs, [K·F] → 3×256 (ReLU) → [K·out], reshaped to per-limb outputs for the shared role
outputs. With a height map, its 64-wide embedding is joined to the last hidden layer and the
decoder becomes [256 ‖ 64] → 64 → [K·out]. Padded limb inputs are zero, so they carry no
gradient. The input size is fixed by K: train one network per robot."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule
from torch import Tensor, nn

from gcnt import keys as K
from gcnt.nn.chain import Backbone, NetIO
from gcnt.nn.config import MLPConfig
from gcnt.nn.layers import as_dtype, mlp
from gcnt.nn.stages import DECODER_HIDDEN


class FlatMLP(nn.Module):
    def __init__(
        self, num_limbs: int, in_dim: int, hidden, out_dim: int, hfield_width: int = 0
    ) -> None:
        super().__init__()
        self.num_limbs, self.in_dim, self.out_dim = num_limbs, in_dim, out_dim
        hidden = tuple(hidden)
        self.trunk = mlp(num_limbs * in_dim, hidden[:-1], hidden[-1], final_activation=True)
        dec_hidden = (DECODER_HIDDEN,) if hfield_width else ()
        self.decoder = mlp(hidden[-1] + hfield_width, dec_hidden, num_limbs * out_dim)

    def forward(self, x: Tensor, hfield: Tensor | None = None) -> Tensor:
        if x.shape[-2:] != (self.num_limbs, self.in_dim):
            raise ValueError(
                f"MLP baseline built for {self.num_limbs} limbs × {self.in_dim} inputs, got "
                f"{tuple(x.shape[-2:])}"
            )
        h = self.trunk(x.flatten(-2))
        if hfield is not None:
            h = torch.cat([h, as_dtype(hfield, h.dtype)], -1)
        return self.decoder(h).unflatten(-1, (self.num_limbs, self.out_dim))


def mlp_backbone(cfg: MLPConfig, io: NetIO, table: TensorDictBase) -> Backbone:
    if not cfg.hidden:
        raise ValueError("MLPConfig.hidden needs at least one layer")
    num_limbs = table.get(K.MASK).shape[-1]
    net = FlatMLP(num_limbs, io.in_dim, cfg.hidden, io.out_dim, io.hfield_width)
    in_keys = [K.INPUT] + ([K.HFIELD_EMBED] if io.hfield_width else [])
    return Backbone([("mlp", TensorDictModule(net, in_keys, [K.OUT]))], name="SR (MLP)")
