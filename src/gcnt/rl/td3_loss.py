"""TD3 with per-limb twin critics, built on torchrl's ``TD3Loss``.

Each critic outputs one Q per limb. torchrl's loss does the target-policy smoothing, the twin
minimum and the target networks; two things are added here, because a LossModule masks whole
samples, never limbs:

* the TD target is per robot: ``r + γ (1 - terminated) · mean over real limbs of min(Q1', Q2')``,
  and every real limb's Q is regressed to it (``PerRobotTD0``);
* losses come back unreduced (``reduction="none"``, one value per limb) and are averaged over the
  robot's real limbs with :func:`gcnt.nn.masking.limb_mean` — the same limbs the critic's own
  per-robot Q averages over — then over the batch.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torchrl.objectives import TD3Loss
from torchrl.objectives.value import TD0Estimator

from gcnt.nn.keys import ACTION, LIMB_Q, MASK
from gcnt.nn.masking import limb_mean


def masked_mean(values: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean over robots of the per-robot :func:`limb_mean` of per-limb ``values`` [*B, K]."""
    return limb_mean(values.unsqueeze(-1), mask).mean()


class PerRobotTD0(TD0Estimator):
    """TD(0) target from the per-robot mean over real limbs of the next Q (shape [*B, 1, 1])."""

    def value_estimate(self, tensordict, target_params=None, next_value=None, **kwargs):
        q_next = tensordict.get(("next", self.tensor_keys.value))  # [*B, K, 1]
        v_next = limb_mean(q_next, tensordict.get(MASK))  # [*B, 1]
        target = super().value_estimate(tensordict, next_value=v_next, **kwargs)
        return target.unsqueeze(-1)  # the loss squeezes the last dim and broadcasts over limbs


def make_td3_loss(
    actor: torch.nn.Module,
    critics: torch.nn.Module | list[torch.nn.Module],
    *,
    gamma: float,
    policy_noise: float,
    noise_clip: float,
) -> TD3Loss:
    loss = TD3Loss(
        actor_network=actor,
        qvalue_network=critics,
        bounds=(-1.0, 1.0),  # TD3Loss rejects a nested Composite action spec (KeyError "action")
        num_qvalue_nets=2,
        policy_noise=policy_noise,
        noise_clip=noise_clip,
        loss_function="l2",
        reduction="none",
        deactivate_vmap=True,
    )
    loss.set_keys(action=ACTION, state_action_value=LIMB_Q)
    estimator = PerRobotTD0(gamma=gamma, value_network=None)
    estimator.set_keys(
        value=LIMB_Q,
        reward=loss.tensor_keys.reward,
        done=loss.tensor_keys.done,
        terminated=loss.tensor_keys.terminated,
    )
    loss._value_estimator = estimator  # what make_value_estimator does, with our estimator
    return loss


def critic_loss(loss: TD3Loss, batch: TensorDictBase) -> torch.Tensor:
    """Twin-critic loss averaged over real limbs; ``batch`` must hold the static keys."""
    per_limb, _ = loss.value_loss(batch)  # [*B, K]
    return masked_mean(per_limb, batch.get(MASK))


def actor_loss(loss: TD3Loss, batch: TensorDictBase) -> torch.Tensor:
    """-Q1 of the actor's action, averaged over real limbs."""
    per_limb, _ = loss.actor_loss(batch)  # [*B, K]
    return masked_mean(per_limb, batch.get(MASK))


# ------------------------------------------------------------------ the learner's fast path
# The same quantities as ``critic_loss`` / ``actor_loss`` above, from per-limb Q tensors that the
# learner computes with plain-tensor chain calls (gcnt.rl.tensor_chain); tests check both agree.


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
