"""TD3's loss math as pure functions on per-limb Q tensors, shapes in each docstring.

The learner (:mod:`gcnt.rl.td3.learner`) computes the actor's and the critics' per-limb outputs
with plain-tensor chain calls (:mod:`gcnt.rl.td3.tensor_chain`) and hands them to these functions.
A torchrl ``LossModule`` cannot be used directly: it masks whole samples, never limbs, and here
padded limbs must drop out of every mean. The tests check these functions against torchrl's
``TD3Loss`` with a per-robot TD(0) estimator in float64 (``tests/reference_td3.py``).

* the TD target is per robot: ``r + γ (1 - terminated) · mean over real limbs of min(Q1', Q2')``,
  and every real limb's Q is regressed to it;
* losses are averaged over the robot's real limbs with :func:`gcnt.nn.masking.limb_mean` (the
  same limbs the critic's own per-robot Q averages over), then over the batch.
"""

from __future__ import annotations

import torch

from gcnt.nn.masking import limb_mean


def masked_mean(values: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean over robots of the per-robot :func:`limb_mean` of per-limb ``values`` [*B, K]."""
    return limb_mean(values.unsqueeze(-1), mask).mean()


def smoothed_target_action(
    next_action: torch.Tensor, noise: torch.Tensor, low: float = -1.0, high: float = 1.0
) -> torch.Tensor:
    """TD3's target-policy smoothing: the target actor's action plus clipped noise, clamped."""
    return (next_action + noise).clamp(low, high)


def target_noise(action: torch.Tensor, policy_noise: float, noise_clip: float) -> torch.Tensor:
    """N(0, policy_noise²) clipped at ±noise_clip, one draw per action slot (drawn first, as
    torchrl's TD3Loss does, so both paths consume the random stream alike)."""
    return (torch.randn_like(action) * policy_noise).clamp(-noise_clip, noise_clip)


def td_target(
    reward: torch.Tensor,
    terminated: torch.Tensor,
    next_q: tuple[torch.Tensor, ...],
    mask: torch.Tensor,
    gamma: float,
) -> torch.Tensor:
    """``r + γ (1 - terminated) · mean over real limbs of min_i Q_i'`` [*B, 1]; ``next_q`` are
    the target critics' per-limb values [*B, K, 1]."""
    q_min = next_q[0]
    for q in next_q[1:]:
        q_min = torch.minimum(q_min, q)
    v_next = limb_mean(q_min, mask)  # [*B, 1]
    not_term = (~terminated.bool()).to(v_next.dtype)
    return reward.to(v_next.dtype) + gamma * not_term * v_next


def twin_critic_loss(
    q: tuple[torch.Tensor, ...], target: torch.Tensor, mask: torch.Tensor
) -> torch.Tensor:
    """Σ over critics of (Q_i - target)² per real limb, averaged as :func:`masked_mean`."""
    per_limb = sum((qi.squeeze(-1) - target).pow(2) for qi in q)  # [*B, K]
    return masked_mean(per_limb, mask)


def deterministic_actor_loss(q1: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """-Q1 of the actor's action [*B, K, 1], averaged as :func:`masked_mean`."""
    return masked_mean(-q1.squeeze(-1), mask)
