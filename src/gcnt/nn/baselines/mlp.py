"""A plain MLP over one robot's flattened padded limb inputs (the SR-fair/SR-top references):
[K·F] → 3×256 (ReLU) → [K·out], reshaped to per-limb outputs for the shared role outputs.
Padded limb inputs are zero, so they carry no gradient. The input size is fixed by K."""

from __future__ import annotations

from tensordict.nn import TensorDictModule
from torch import Tensor, nn

from gcnt.nn import keys as K
from gcnt.nn.chain import Backbone
from gcnt.nn.config import MLPConfig
from gcnt.nn.layers import mlp


class FlatMLP(nn.Module):
    def __init__(self, num_limbs: int, in_dim: int, hidden, out_dim: int) -> None:
        super().__init__()
        self.num_limbs, self.in_dim, self.out_dim = num_limbs, in_dim, out_dim
        self.net = mlp(num_limbs * in_dim, hidden, num_limbs * out_dim)

    def forward(self, x: Tensor) -> Tensor:
        if x.shape[-2:] != (self.num_limbs, self.in_dim):
            raise ValueError(
                f"MLP baseline built for {self.num_limbs} limbs × {self.in_dim} inputs, got "
                f"{tuple(x.shape[-2:])}"
            )
        y = self.net(x.flatten(-2))
        return y.unflatten(-1, (self.num_limbs, self.out_dim))


def mlp_backbone(cfg: MLPConfig, in_dim: int, out_dim: int, num_limbs: int) -> Backbone:
    return Backbone(
        [
            (
                "mlp",
                TensorDictModule(
                    FlatMLP(num_limbs, in_dim, cfg.hidden, out_dim), [K.INPUT], [K.OUT]
                ),
            )
        ],
        name="MLP",
    )
