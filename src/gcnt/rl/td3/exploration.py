"""TD3's exploration: the actor's action plus constant Gaussian noise, clipped to the action
bounds.

torchrl's ``AdditiveGaussianModule`` computes the same values, but projects through
``Bounded.project``, which first asks on the host whether the action is already in bounds: a
device synchronisation per step on a GPU, and a host read that a CUDA graph of the collector's
policy (``compile.policy_cudagraphs``) cannot capture. Here the clip is always applied, as one
kernel on the action's device (a clip leaves an in-bounds action unchanged)."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.data import Bounded
from torchrl.envs.utils import ExplorationType, exploration_type

from gcnt.keys import ACTION


class GaussianExploration(TensorDictModuleBase):
    """Adds ``sigma`` x standard normal noise to ``action_key`` while the exploration type is
    random (collection; also when none is set, as torchrl's modules do) and clips the result to
    ``spec``'s bounds; leaves the action as it is under a deterministic exploration type."""

    def __init__(self, spec: Bounded, sigma: float, action_key=ACTION) -> None:
        super().__init__()
        self.action_key = action_key
        self.in_keys = [action_key]
        self.out_keys = [action_key]
        self.sigma = float(sigma)
        self.register_buffer("low", spec.space.low.clone())
        self.register_buffer("high", spec.space.high.clone())

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        if exploration_type() in (ExplorationType.RANDOM, None):
            action = tensordict.get(self.action_key)
            noisy = action + torch.randn_like(action) * self.sigma
            low, high = self.low.expand_as(noisy), self.high.expand_as(noisy)
            tensordict.set(self.action_key, torch.clamp(noisy, low, high))
        return tensordict
