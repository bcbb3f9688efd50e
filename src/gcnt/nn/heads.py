"""Role outputs shared by every method: they turn the per-limb head output ``limbs/out`` into
what TD3 and PPO read.

========== ====================================================================================
role       writes
========== ====================================================================================
td3_actor  ``limbs/action`` [*, K, A] = tanh(out), zero where ``limbs/action_mask`` is False
td3_critic ``limbs/state_action_value`` [*, K, 1] (zero on padding) and ``state_action_value``
           [*, 1] = mean over real limbs (:func:`gcnt.nn.masking.limb_mean`)
ppo_actor  ``limbs/loc``, ``limbs/scale`` [*, K, A]; wrapped in a ``ProbabilisticActor`` with
           :class:`MaskedNormal` that samples ``limbs/action`` and writes ``action_log_prob`` [*]
ppo_critic ``limbs/state_value`` [*, K, 1] and ``state_value`` [*, 1] = mean over real limbs
========== ====================================================================================
"""

from __future__ import annotations

import math

import torch
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import Tensor, nn
from torchrl.modules import ProbabilisticActor

from gcnt import keys as K
from gcnt.nn.distributions import MaskedNormal
from gcnt.nn.layers import as_dtype
from gcnt.nn.masking import limb_mean

ROLES = ("td3_actor", "td3_critic", "ppo_actor", "ppo_critic")


class TanhAction(nn.Module):
    """Deterministic TD3 action: tanh of the head, zero on torso/padded slots."""

    def forward(self, out: Tensor, action_mask: Tensor) -> Tensor:
        return torch.where(action_mask, torch.tanh(out), 0.0)


class LimbValue(nn.Module):
    """Per-limb value (zero on padding) and its mean over the robot's real limbs."""

    def forward(self, out: Tensor, mask: Tensor) -> tuple[Tensor, Tensor]:
        per_limb = torch.where(mask.unsqueeze(-1), out, 0.0)
        return per_limb, limb_mean(out, mask)


PPO_STD_MODES = ("fixed", "learned")


def check_ppo_std(std: str, init_std: float) -> None:
    """A ValueError unless ``std`` is "fixed" or "learned" and ``init_std`` > 0."""
    if std not in PPO_STD_MODES:
        raise ValueError(f"ppo_std must be 'fixed' or 'learned', got {std!r}")
    if not (isinstance(init_std, int | float) and init_std > 0):
        raise ValueError(f"ppo_init_std must be > 0, got {init_std!r}")


class GaussianParams(nn.Module):
    """loc = head output (zero on masked slots); scale = a fixed std (``std="fixed"``, MetaMorph:
    0.9, not trained), or exp of a learned state-independent log-std per action slot
    (``std="learned"``, initialised to ``init_std``)."""

    def __init__(self, num_actions: int, std: str = "fixed", init_std: float = 0.9) -> None:
        super().__init__()
        check_ppo_std(std, init_std)
        self.std_mode = std
        if std == "learned":
            self.log_std = nn.Parameter(torch.full((num_actions,), math.log(init_std)))
        else:
            self.register_buffer("std", torch.tensor(float(init_std)), persistent=False)

    def forward(self, out: Tensor, action_mask: Tensor) -> tuple[Tensor, Tensor]:
        loc = torch.where(action_mask, out, 0.0)
        if self.std_mode == "learned":
            scale = self.log_std.exp().to(out.dtype).expand_as(out)
        else:
            scale = as_dtype(self.std, out.dtype).expand_as(out)
        return loc, scale


def role_output(role: str, num_actions: int, std: str = "fixed", init_std: float = 0.9):
    """The TensorDictModule that finishes a chain for ``role`` (ppo_actor: the param module)."""
    if role == "td3_actor":
        return TensorDictModule(TanhAction(), [K.OUT, K.ACTION_MASK], [K.ACTION])
    if role == "td3_critic":
        return TensorDictModule(LimbValue(), [K.OUT, K.MASK], [K.LIMB_Q, K.Q])
    if role == "ppo_critic":
        return TensorDictModule(LimbValue(), [K.OUT, K.MASK], [K.LIMB_VALUE, K.VALUE])
    if role == "ppo_actor":
        return TensorDictModule(
            GaussianParams(num_actions, std, init_std), [K.OUT, K.ACTION_MASK], [K.LOC, K.SCALE]
        )
    raise ValueError(f"unknown role {role!r}")


def final_keys(role: str) -> list:
    return {
        "td3_actor": [K.ACTION],
        "td3_critic": [K.LIMB_Q, K.Q],
        "ppo_critic": [K.LIMB_VALUE, K.VALUE],
        "ppo_actor": [K.LOC, K.SCALE, K.ACTION_MASK],
    }[role]


def probabilistic_actor(params_module: TensorDictSequential) -> ProbabilisticActor:
    """Wrap a chain writing ``limbs/loc``, ``limbs/scale`` (and ``limbs/action_mask``) into a
    ``ProbabilisticActor`` over :class:`MaskedNormal` that samples ``limbs/action`` and writes
    the log-probability at the root key ``action_log_prob``."""
    return ProbabilisticActor(
        params_module,
        in_keys={"loc": K.LOC, "scale": K.SCALE, "mask": K.ACTION_MASK},
        out_keys=[K.ACTION],
        distribution_class=MaskedNormal,
        return_log_prob=True,
        log_prob_key=K.LOG_PROB,
    )
