"""The torchrl reference for gcnt's TD3 loss functions (:mod:`gcnt.rl.td3.loss`).

Training never uses this module: it computes the same quantities with torchrl's ``TD3Loss`` and a
per-robot TD(0) estimator, so that the tests can check the learner's pure functions against
torchrl in float64.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torchrl.objectives import TD3Loss
from torchrl.objectives.value import TD0Estimator

from gcnt.keys import ACTION, LIMB_Q, MASK
from gcnt.nn import make_network
from gcnt.nn.masking import limb_mean
from gcnt.rl.td3.loss import masked_mean


def make_td3_critics(name: str, *, num: int = 2, **kwargs) -> list:
    """``num`` independently initialised TD3 critics, for ``TD3Loss(actor, critics, ...)``.

    Given a single qvalue network, TD3Loss makes the twins itself by expanding its parameters and
    re-drawing every tensor uniformly between its min and max (LayerNorm weights stay 1, but no
    layer keeps its own init scheme); passing a list uses these modules' own initialisations.
    """
    return [make_network(name, "td3_critic", **kwargs) for _ in range(num)]


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
