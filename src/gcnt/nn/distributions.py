"""A Gaussian over per-limb actions that counts only real action slots.

:class:`MaskedNormal` is an independent Normal over the event [K, A] (batch = the leading dims),
whose ``log_prob`` and ``entropy`` sum only where ``mask`` (the ``limbs/action_mask``) is True, so a
robot's log-probability does not depend on how much padding it carries. Samples are zero on
masked slots. ``sample_and_log_prob`` and ``rsample_and_log_prob`` are overridden too: TorchRL's
probabilistic modules and collectors sample through those fused paths.
"""

from __future__ import annotations

import torch
from torch import Tensor
from torch import distributions as D


class MaskedNormal(D.Independent):
    """Independent Normal(loc, scale) over [..., K, A], restricted to ``mask`` [..., K, A].

    ``batch_shape`` is ``loc.shape[:-2]``; ``log_prob`` and ``entropy`` return that shape.
    """

    arg_constraints = {}  # loc/scale are checked by the base Normal
    has_rsample = True

    def __init__(self, loc: Tensor, scale: Tensor, mask: Tensor, validate_args=None) -> None:
        if loc.dim() < 2:
            raise ValueError(f"MaskedNormal needs loc of shape [..., K, A], got {tuple(loc.shape)}")
        scale = scale.expand_as(loc)
        self.mask = mask.expand_as(loc).bool()
        super().__init__(D.Normal(loc, scale, validate_args=False), 2, validate_args=False)

    # the per-slot quantities, masked
    def _masked(self, x: Tensor) -> Tensor:
        return torch.where(self.mask, x, 0.0)

    def log_prob(self, value: Tensor) -> Tensor:
        return self._masked(self.base_dist.log_prob(value)).sum((-2, -1))

    def entropy(self) -> Tensor:
        return self._masked(self.base_dist.entropy()).sum((-2, -1))

    def rsample(self, sample_shape: torch.Size | tuple[int, ...] = ()) -> Tensor:
        return self._masked(self.base_dist.rsample(sample_shape))

    def sample(self, sample_shape: torch.Size | tuple[int, ...] = ()) -> Tensor:
        with torch.no_grad():
            return self.rsample(sample_shape)

    def sample_and_log_prob(
        self, sample_shape: torch.Size | tuple[int, ...] = ()
    ) -> tuple[Tensor, Tensor]:
        x = self.sample(sample_shape)
        return x, self.log_prob(x)

    def rsample_and_log_prob(
        self, sample_shape: torch.Size | tuple[int, ...] = ()
    ) -> tuple[Tensor, Tensor]:
        x = self.rsample(sample_shape)
        return x, self.log_prob(x)

    @property
    def mean(self) -> Tensor:
        return self._masked(self.base_dist.loc)

    @property
    def mode(self) -> Tensor:
        return self.mean

    @property
    def deterministic_sample(self) -> Tensor:
        return self.mean

    @property
    def variance(self) -> Tensor:
        return self._masked(self.base_dist.variance)

    def expand(self, batch_shape, _instance=None):
        shape = torch.Size(batch_shape) + self.event_shape
        return MaskedNormal(
            self.base_dist.loc.expand(shape),
            self.base_dist.scale.expand(shape),
            self.mask.expand(shape),
        )
