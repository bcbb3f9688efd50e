"""Running statistics for PPO: observation normalisation and reward scaling.

* :class:`ObsNormalizer`: running mean and variance per limb slot x feature, over real limbs only
  (a slot's statistics come from the robots that have that limb); observations become
  ``clip((x - mean) / sqrt(var + eps), ±clip)``, zero on padded limbs. A module, so its
  statistics travel in ``state_dict``; it changes only when :meth:`ObsNormalizer.update` is called:
  PPO's collecting policy adds each new observation before normalising it (the single collector,
  as a ``VecNormalize`` wrapper does), or the iteration's batch joins after the update (the
  ``multi`` collector's workers normalise with a copy of the statistics); the update reuses the
  normalised observations the policy acted on. At evaluation it is frozen.
* :class:`RewardScaler`: rewards divided by the running std of each env's discounted return,
  clipped.

Both merge batch moments exactly (Chan et al.'s parallel algorithm) in float64.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor, nn

EPS = 1e-8


def merge_moments(mean, var, count, b_mean, b_var, b_count):
    """Mean, variance and count of two samples given as (mean, variance, count) each."""
    total = count + b_count
    delta = b_mean - mean
    new_mean = mean + delta * b_count / total
    m2 = var * count + b_var * b_count + delta**2 * count * b_count / total
    return new_mean, m2 / total, total


class ObsNormalizer(nn.Module):
    """Running mean / std of ``limbs/obs`` per limb slot x feature (real limbs only).

    Args:
        max_limbs: K, limb slots; obs_dim: F, features per limb.
        clip: normalised values are clipped to ±clip.
    """

    def __init__(self, max_limbs: int, obs_dim: int, clip: float = 10.0):
        super().__init__()
        self.clip = float(clip)
        self.register_buffer("mean", torch.zeros(max_limbs, obs_dim, dtype=torch.float64))
        self.register_buffer("var", torch.ones(max_limbs, obs_dim, dtype=torch.float64))
        # a tiny prior count, so that the first batch sets the statistics
        self.register_buffer("count", torch.full((max_limbs, 1), 1e-4, dtype=torch.float64))

    @torch.no_grad()
    def update(self, obs: Tensor, mask: Tensor) -> None:
        """Merge a batch ``obs`` [..., K, F] with its limb ``mask`` [..., K] into the stats."""
        k, f = self.mean.shape
        # the batch comes from the env (CPU); the statistics live with the policy
        x = obs.reshape(-1, k, f).to(self.mean.device, torch.float64)
        m = mask.reshape(-1, k, 1).to(self.mean.device, torch.float64)
        n = m.sum(0)  # [K, 1]
        seen = n > 0
        b_mean = (x * m).sum(0) / n.clamp(min=1)
        b_var = (((x - b_mean) ** 2) * m).sum(0) / n.clamp(min=1)
        mean, var, count = merge_moments(self.mean, self.var, self.count, b_mean, b_var, n)
        self.mean.copy_(torch.where(seen, mean, self.mean))
        self.var.copy_(torch.where(seen, var, self.var))
        self.count.copy_(torch.where(seen, count, self.count))

    def forward(self, obs: Tensor, mask: Tensor) -> Tensor:
        """Normalised ``obs`` [..., K, F] (same dtype), zero where ``mask`` [..., K] is False."""
        k = obs.shape[-2]
        if k != self.mean.shape[0]:
            raise ValueError(
                f"ObsNormalizer has statistics for {self.mean.shape[0]} limb slots, the "
                f"observation has {k} (use for_limbs)"
            )
        std = (self.var + EPS).sqrt()
        y = ((obs.to(torch.float64) - self.mean) / std).clamp(-self.clip, self.clip)
        return torch.where(mask.unsqueeze(-1), y, 0.0).to(obs.dtype)

    def for_limbs(self, max_limbs: int) -> ObsNormalizer:
        """A frozen copy for ``max_limbs`` slots: slots beyond the trained ones are unnormalised
        (mean 0, variance 1); extra trained slots are dropped."""
        k, f = self.mean.shape
        out = ObsNormalizer(max_limbs, f, self.clip).to(self.mean.device)
        keep = min(k, max_limbs)
        out.mean[:keep] = self.mean[:keep]
        out.var[:keep] = self.var[:keep]
        out.count[:keep] = self.count[:keep]
        return out.eval()


class RewardScaler:
    """Rewards divided by the running std of the discounted return, clipped to ±clip.

    Each env's discounted return ``ret = gamma * ret + r`` restarts at 0 after its episode ends;
    the statistics merge every return of a batch, then the batch's rewards are scaled.
    """

    def __init__(self, num_envs: int, gamma: float, clip: float = 10.0):
        self.gamma, self.clip = float(gamma), float(clip)
        self.ret = np.zeros(num_envs)
        self.mean, self.var, self.count = 0.0, 1.0, 1e-4

    @property
    def std(self) -> float:
        return float(np.sqrt(self.var + EPS))

    def __call__(self, reward: Tensor, done: Tensor) -> Tensor:
        """Scaled rewards for a batch ``reward``, ``done`` [N, T(, 1)], time last (or before the
        trailing 1); updates the statistics and the returns carried to the next batch."""
        r = (
            reward.detach()
            .reshape(reward.shape[0], reward.shape[1])
            .cpu()
            .numpy()
            .astype(np.float64)
        )
        d = done.reshape(r.shape).cpu().numpy()
        rets = np.empty_like(r)
        ret = self.ret
        for t in range(r.shape[1]):
            ret = self.gamma * ret + r[:, t]
            rets[:, t] = ret
            ret = np.where(d[:, t], 0.0, ret)
        self.ret = ret
        self.mean, self.var, self.count = merge_moments(
            self.mean, self.var, self.count, rets.mean(), rets.var(), rets.size
        )
        scaled = np.clip(r / self.std, -self.clip, self.clip)
        return torch.as_tensor(scaled, dtype=reward.dtype).reshape(reward.shape)

    def state_dict(self) -> dict:
        return {"mean": self.mean, "var": self.var, "count": self.count}

    def load_state_dict(self, state: dict) -> None:
        self.mean, self.var, self.count = state["mean"], state["var"], state["count"]
        self.ret[:] = 0.0  # episodes restart after a resume
