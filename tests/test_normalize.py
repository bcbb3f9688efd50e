"""Tests for ``gcnt.rl.ppo.normalize``, PPO's running statistics: ``ObsNormalizer`` keeps per-slot
statistics over real limbs only (padding slots stay at zero mean and unit variance, two merges
equal one pass), clips and zeroes padding when normalising, and widens to more limbs as a copy;
``RewardScaler`` divides rewards by the standard deviation of the discounted return, carrying the
return to the next batch and restarting it at episode ends.
"""

import math

import numpy as np
import pytest
import torch

from gcnt.rl.ppo.normalize import ObsNormalizer, RewardScaler


def test_obs_normalizer_per_slot_over_real_limbs_and_frozen_copy():
    torch.manual_seed(0)
    norm = ObsNormalizer(3, 2, clip=10.0)
    obs = torch.randn(50, 3, 2, dtype=torch.float64) * torch.tensor([1.0, 5.0]) + 3.0
    mask = torch.ones(50, 3, dtype=torch.bool)
    mask[:, 2] = False  # nobody has a third limb
    mask[25:, 1] = False
    norm.update(obs[:20], mask[:20])
    norm.update(obs[20:], mask[20:])  # two merges equal one pass over everything
    ref0 = obs[:, 0]
    assert torch.allclose(norm.mean[0], ref0.mean(0), atol=1e-3)
    assert torch.allclose(norm.var[0], ref0.var(0, correction=0), rtol=1e-3)
    assert torch.allclose(norm.mean[1], obs[:25, 1].mean(0), atol=1e-3)
    assert torch.equal(norm.mean[2], torch.zeros(2)) and torch.equal(norm.var[2], torch.ones(2))
    y = norm(obs.float(), mask)
    assert (y[~mask] == 0).all() and y.abs().max() <= 10
    wide = norm.for_limbs(5)
    assert torch.equal(wide.mean[:3], norm.mean) and torch.equal(wide.var[3:], torch.ones(2, 2))


def test_reward_scaling_divides_by_the_std_of_the_discounted_return():
    s = RewardScaler(2, gamma=0.5, clip=10.0)
    r = torch.tensor([[1.0, 1.0, 1.0], [2.0, 0.0, 2.0]])
    done = torch.tensor([[False, True, False], [False, False, False]])
    out = s(r, done)
    rets = np.array([[1.0, 1.5, 1.0], [2.0, 1.0, 2.5]])
    n0 = 1e-4
    mean = rets.mean() * 6 / (6 + n0)
    var = (1.0 * n0 + rets.var() * 6 + rets.mean() ** 2 * n0 * 6 / (6 + n0)) / (6 + n0)
    assert s.mean == pytest.approx(mean) and s.var == pytest.approx(var)
    assert torch.allclose(out, (r / math.sqrt(var + 1e-8)).float())
    assert s.ret.tolist() == [1.0, 2.5]  # carried to the next batch (robot 0 restarted)
