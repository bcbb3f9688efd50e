"""SMPENV task rules: healthy bounds per robot (unit level) and in the env (exact thresholds)."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
import torch

from gcnt.envs.smpenv import SMPEnv
from gcnt.envs.smpenv.rules import task_rules
from gcnt.morphology.catalogues import smpenv_robot

# robot -> (z_low, z_high) of the healthy test of the original SMPENV task code
Z_BOUNDS = {
    "walker_2_main": (0.8 - 0.26, 2.0 - 0.26),
    "walker_3_main": (0.8 - 0.26, 2.0 - 0.26),
    "walker_4_main": (0.8 - 0.136, 2.0 - 0.136),
    "walker_5_main": (0.8, 2.0),
    "walker_6_main": (0.8, 2.0),
    "walker_7_main": (0.8, 2.0),
    "hopper_3": (0.45, math.inf),
    "hopper_4": (0.6, math.inf),
    "hopper_5": (0.95, math.inf),
    "humanoid_2d_9_full": (0.4, 2.1),
    "humanoid_2d_7_left_leg": (0.4, 2.1),
}
EPS = 1e-6


def _check(rules, z, pitch=0.0, state=None):
    if state is None:
        return rules.healthy(z, pitch)
    return rules.healthy(z, pitch, np.asarray(state, float))


@pytest.mark.parametrize("name", sorted(Z_BOUNDS))
def test_healthy_z_bounds(name):
    lo, hi = Z_BOUNDS[name]
    rules = task_rules(smpenv_robot(name))
    assert _check(rules, lo + EPS)
    assert not _check(rules, lo - EPS)
    assert not _check(rules, lo)  # strict
    if math.isfinite(hi):
        assert _check(rules, hi - EPS)
        assert not _check(rules, hi + EPS)
    else:
        assert _check(rules, 1e6)


@pytest.mark.parametrize("name", ["walker_7_main", "hopper_4", "humanoid_2d_9_full"])
def test_healthy_pitch(name):
    rules = task_rules(smpenv_robot(name))
    z = Z_BOUNDS[name][0] + 0.1
    assert _check(rules, z, 1 - EPS) and _check(rules, z, -1 + EPS)
    assert not _check(rules, z, 1 + EPS) and not _check(rules, z, -1 - EPS)


def test_hopper_state_test():
    rules = task_rules(smpenv_robot("hopper_4"))
    assert _check(rules, 1.0, 0.0, [0.0] * 10)
    assert not _check(rules, 1.0, 0.0, [0.0] * 9 + [100.0 + EPS])
    assert _check(rules, 1.0, 0.0, [0.0] * 9 + [100.0 - EPS])
    assert not _check(rules, 1.0, 0.0, [0.0] * 9 + [np.nan])
    # walkers have no state test
    assert _check(task_rules(smpenv_robot("walker_7_main")), 1.0, 0.0, [1e9] * 10)


def test_cheetah_never_unhealthy():
    rules = task_rules(smpenv_robot("cheetah_7_full"))
    assert not rules.can_terminate
    assert _check(rules, -100.0, 3.1, [np.nan] * 5)


def test_reward_weights_and_noise():
    w, c = task_rules(smpenv_robot("walker_5_main")), task_rules(smpenv_robot("cheetah_4_back"))
    assert (w.healthy_reward, w.ctrl_cost, w.qpos_noise, w.qvel_noise) == (1.0, 1e-3, 0.005, 0.005)
    assert not w.qvel_noise_normal
    assert (c.healthy_reward, c.ctrl_cost, c.qpos_noise, c.qvel_noise) == (0.0, 0.1, 0.1, 0.1)
    assert c.qvel_noise_normal


# --------------------------------------------------------------------------- in the env


def _frozen_env(names):
    """An env whose robots float: no gravity, no contacts or limits, so a state at rest stays put."""
    env = SMPEnv([smpenv_robot(n) for n in names], seed=0, num_threads=1)
    for i in range(len(names)):
        m, _ = env.sim(i)
        m.opt.gravity[:] = 0.0
        m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)
    env.reset()
    return env


def _step_zero(env):
    td = env.observe()
    td["limbs", "action"] = torch.zeros(env.action_spec["limbs", "action"].shape)
    return env.step(td)["next"]


@pytest.mark.parametrize(
    "name,bound,inside",
    [
        # the lower z bounds of walkers, hoppers and humanoids, and their upper bounds
        (n, b, side)
        for n in ["walker_2_main", "walker_3_main", "walker_4_main", "walker_7_main",
                  "hopper_3", "hopper_4", "hopper_5", "humanoid_2d_9_full"]
        for b in (0, 1)
        if math.isfinite(Z_BOUNDS[n][b])
        for side in (True, False)
    ],
)  # fmt: skip
def test_env_terminates_at_exact_bounds(name, bound, inside):
    env = _frozen_env([name])
    m, d = env.sim(0)
    z = Z_BOUNDS[name][bound] + (EPS if (bound == 0) == inside else -EPS)
    qpos = m.qpos0.copy()
    qpos[1] = z  # root slide z (SMPENV root joints: x, z, pitch)
    env.set_state(0, qpos, np.zeros(m.nv))
    out = _step_zero(env)
    assert d.qpos[1] == pytest.approx(z, abs=1e-9)  # it did not move
    assert bool(out["terminated"][0, 0]) is (not inside)
    assert not bool(out["truncated"][0, 0])
    assert bool(out["done"][0, 0]) is (not inside)


def test_env_cheetah_never_terminates():
    env = _frozen_env(["cheetah_7_full"])
    m, _ = env.sim(0)
    qpos = m.qpos0.copy()
    qpos[1], qpos[2] = -5.0, 3.0  # under the floor, upside down
    env.set_state(0, qpos, np.zeros(m.nv))
    out = _step_zero(env)
    assert not bool(out["terminated"][0, 0])


def test_env_hopper_velocity_terminates():
    env = _frozen_env(["hopper_4", "hopper_4"])
    m, _ = env.sim(0)
    for i, v in enumerate((99.0, 101.0)):
        qvel = np.zeros(m.nv)
        qvel[0] = v  # root x velocity: part of s[2:] (s = qpos ++ qvel)
        env.set_state(i, m.qpos0, qvel)
    out = _step_zero(env)
    assert out["terminated"][:, 0].tolist() == [False, True]


@pytest.mark.parametrize(
    "name", ["walker_7_main", "cheetah_7_full", "hopper_3", "humanoid_2d_9_full"]
)
def test_env_reward(name):
    """Reward = Δx/dt + alive − w·Σ clip(a)² over real motors (padding and torso ignored)."""
    env = _frozen_env([name])
    rules = task_rules(smpenv_robot(name))
    m, d = env.sim(0)
    qvel = np.zeros(m.nv)
    qvel[0] = 1.5
    env.set_state(0, m.qpos0, qvel)
    x0 = d.qpos[0]
    td = env.observe()
    a = torch.full(env.action_spec["limbs", "action"].shape, 0.3)
    a[0, 1, 0] = 7.0  # clipped to 1
    a[0, 0, 0] = 5.0  # torso slot: ignored
    td["limbs", "action"] = a
    out = env.step(td)["next"]
    n_motor = smpenv_robot(name).num_motors
    sq = 1.0 + 0.09 * (n_motor - 1)
    dt = m.opt.timestep * 4
    expected = (d.qpos[0] - x0) / dt + rules.healthy_reward - rules.ctrl_cost * sq
    assert float(out["reward"][0, 0]) == pytest.approx(expected, rel=1e-5, abs=1e-5)
    assert d.ctrl[smpenv_robot(name).actuator_ids[1][0]] == 1.0  # clipped, and on limb 1's motor
