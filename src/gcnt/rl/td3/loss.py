"""TD3's loss math as pure functions on per-limb Q tensors, shapes in each docstring.

The learner (:mod:`gcnt.rl.td3.learner`) computes the actor's and the critics' per-limb outputs
with plain-tensor chain calls (:mod:`gcnt.rl.td3.tensor_chain`) and hands them to these functions.
A torchrl ``LossModule`` cannot be used directly: it masks whole samples, never limbs, and here
padded limbs must drop out of every mean. The tests check these functions against torchrl's
``TD3Loss`` with a per-robot TD(0) estimator (the ``robot_mean`` rule) and against hand-written
references of every rule in float64 (``tests/reference_td3.py``, ``tests/test_td3_targets.py``).

* the TD target follows one of three rules (:data:`TARGET_RULES`, recipe key ``td3.target``):
  per limb as the AMORPHEUS/SWAT/SMP code (the default), per robot from the mean over real limbs,
  or per robot from the sum of the limbs' Qs;
* losses are averaged over the robot's real limbs with :func:`gcnt.nn.masking.limb_mean`, then
  over the batch (the summed rule: over the batch).
"""

from __future__ import annotations

import torch

from gcnt.nn.layers import as_dtype
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


#: how a per-limb critic becomes a TD target and a loss (``td3.target``):
#:
#: * ``"limb"``: every limb has its own target ``r + γ (1 - terminated) · min(Q1'ᵢ, Q2'ᵢ)``, the
#:   robot's reward broadcast to its limbs, and each limb is regressed to its own target; the
#:   actor maximises Q1 averaged over limbs. The AMORPHEUS and SWAT code (``yobibyte/amorpheus``
#:   and ``sunghoonhong/SWAT`` ``modular-rl/src/TD3.py`` ``TD3.train_single``) and SMP's as
#:   published (``huangwl18/modular-rl`` ``src/ModularCritic.py`` with torchfold on, its default:
#:   ``CriticGraphPolicy.forward``'s sum runs over a singleton axis and leaves one Q per limb).
#: * ``"robot_mean"``: one target per robot from the mean over real limbs of ``min(Q1', Q2')``
#:   (:func:`gcnt.nn.masking.limb_mean`), every real limb regressed to it.
#: * ``"robot_sum"``: the critic's Q of a robot is the sum of its limbs' Qs; one target per robot
#:   ``r + γ (1 - terminated) · min(ΣQ1', ΣQ2')``, the robot's summed Q regressed to it, the actor
#:   maximising ΣQ1. SMP's code with ``--disable_fold``; for a monolithic MLP whose outputs are
#:   per limb slot it is plain single-robot TD3 (a sum of linear outputs is a linear output).
#:
#: With one robot per mini-batch (the ``paper`` schedule) every loss is the mean over the batch
#: (and its limbs), as in the original code; a mixed batch averages each robot's limbs first.
TARGET_RULES = ("limb", "robot_mean", "robot_sum")


def _robot_sum(values: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Sum over real limbs of per-limb ``values`` [*B, K, 1] -> [*B, 1]."""
    m = mask.unsqueeze(-1)
    return torch.where(m, values, 0.0).sum(-2)


def td_target(
    reward: torch.Tensor,
    terminated: torch.Tensor,
    next_q: tuple[torch.Tensor, ...],
    mask: torch.Tensor,
    gamma: float,
    rule: str = "limb",
) -> torch.Tensor:
    """The TD target of ``rule`` (:data:`TARGET_RULES`) from the target critics' per-limb values
    ``next_q`` [*B, K, 1], ``reward`` and ``terminated`` [*B, 1]: [*B, K] for ``"limb"``
    (padded limbs hold values the losses never read), [*B, 1] for the robot rules. A truncated
    transition bootstraps; a terminated one is the reward alone."""
    if rule == "robot_sum":
        next_q = tuple(_robot_sum(q, mask).unsqueeze(-1) for q in next_q)  # [*B, 1, 1]
    q_min = next_q[0]
    for q in next_q[1:]:
        q_min = torch.minimum(q_min, q)
    if rule == "limb":
        v_next = q_min.squeeze(-1)  # [*B, K]
    elif rule == "robot_mean":
        v_next = limb_mean(q_min, mask)  # [*B, 1]
    elif rule == "robot_sum":
        v_next = q_min.squeeze(-1)  # [*B, 1]
    else:
        raise ValueError(f"unknown TD target rule {rule!r} (known: {', '.join(TARGET_RULES)})")
    not_term = (~terminated.bool()).to(v_next.dtype)
    return as_dtype(reward, v_next.dtype) + gamma * not_term * v_next


def critic_error(
    q: torch.Tensor, target: torch.Tensor, mask: torch.Tensor, rule: str = "limb"
) -> torch.Tensor:
    """One critic's squared error of ``rule``: per real limb against the limb's (``"limb"``,
    target [*B, K]) or the robot's (``"robot_mean"``, [*B, 1]) target, averaged as
    :func:`masked_mean`; or (``"robot_sum"``) of each robot's summed Q [*B, 1] against its
    target, averaged over the batch. ``q``: the critic's per-limb values [*B, K, 1]."""
    if rule == "robot_sum":
        return (_robot_sum(q, mask) - target).pow(2).mean()
    return masked_mean((q.squeeze(-1) - target).pow(2), mask)


def twin_critic_loss(
    q: tuple[torch.Tensor, ...], target: torch.Tensor, mask: torch.Tensor, rule: str = "limb"
) -> torch.Tensor:
    """Σ over critics of :func:`critic_error` (the averages are linear, so this is also the
    error of the summed squares)."""
    return sum(critic_error(qi, target, mask, rule) for qi in q)


def deterministic_actor_loss(
    q1: torch.Tensor, mask: torch.Tensor, rule: str = "limb"
) -> torch.Tensor:
    """-Q1 of the actor's action [*B, K, 1]: averaged as :func:`masked_mean`, or for
    ``"robot_sum"`` the robot's summed Q1 averaged over the batch."""
    if rule == "robot_sum":
        return -_robot_sum(q1, mask).mean()
    return masked_mean(-q1.squeeze(-1), mask)
