"""Which limbs count when a per-limb quantity becomes one number per robot, said once.

Every per-robot reduction over limbs in gcnt (the critic's per-robot Q, the PPO value, the TD
target, the TD3 losses) averages over the robot's **real limbs** (``limbs/mask``: the torso
included, padding excluded), the convention of MetaMorph's value head and of the paper ("the
critic outputs one value per limb, averaged over real limbs"). Use :func:`limb_mean` for all of
them, so that value, target and loss can never disagree.
"""

from __future__ import annotations

import torch

from gcnt.nn.layers import as_dtype


def limb_mean(values: torch.Tensor, mask: torch.Tensor, dim: int = -2) -> torch.Tensor:
    """Mean of ``values`` over the True limbs of ``mask`` along the limb dimension ``dim``.

    ``values`` is [*B, K, ...] (limb dim at ``dim``), ``mask`` is [*B, K] bool. Padded entries may
    hold anything finite or not: they are replaced by zero before summing. A robot without any
    real limb gives 0.
    """
    m = mask
    while m.dim() < values.dim():
        m = m.unsqueeze(-1)
    m = m.expand_as(values)
    total = torch.where(m, values, 0.0).sum(dim)
    return total / as_dtype(m, values.dtype).sum(dim).clamp_min(1.0)
