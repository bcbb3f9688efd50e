"""Tests for ``gcnt.rl.ppo.robot_sampler``, PPO's robot sampling: ``RobotSampler`` draws robots
uniformly in the first iterations, then in inverse proportion to an exponential moving average of
each robot's episode length (a robot without episodes takes the mean of the others), and a
``RobotDraw`` pickles as a view of the shared probabilities, so envs in worker processes follow
the trainer's updates.
"""

import numpy as np
import pytest

from gcnt.rl.ppo.robot_sampler import (
    PROBS_PREFIX,
    RobotDraw,
    RobotSampler,
    remove_stale_probs,
    shared_probs,
)


def test_robot_sampler_uniform_then_inverse_episode_length():
    s = RobotSampler(3, uniform_iterations=2, warmup_episodes=10, alpha=0.1)
    draw = s.drawer(seed=0)
    s.add_episodes([0] * 10 + [1] * 10, [100] * 10 + [400] * 10)
    s.end_iteration()
    assert np.allclose(np.asarray(s.probs), 1 / 3)  # still uniform in the first iterations
    s.add_episodes([0, 1], [200, 400])  # past the warm-up: EMA
    s.end_iteration()
    ema = np.array([0.1 * 200 + 0.9 * 100, 400.0, (110 + 400) / 2])  # robot 2: mean of the others
    w = 1000 / ema
    assert np.allclose(np.asarray(s.probs), w / w.sum())
    assert np.allclose(s.ema[:2], ema[:2])
    # the env-side drawer reads the same (shared) probabilities
    picks = draw(np.arange(20000))
    assert np.allclose(np.bincount(picks, minlength=3) / 20000, w / w.sum(), atol=0.015)
    # first episodes: the mean of those seen so far
    t = RobotSampler(1, warmup_episodes=10)
    t.add_episodes([0, 0, 0], [10, 20, 60])
    assert t.ema[0] == pytest.approx(30.0)


def test_robot_draw_pickles_as_a_view_of_the_shared_probabilities():
    """Envs in worker processes (a multi-process collector) follow the trainer's updates."""
    import pickle

    import cloudpickle

    probs = shared_probs(4)
    for dumps in (pickle.dumps, cloudpickle.dumps):
        d = pickle.loads(dumps(RobotDraw(probs, 3)))
        probs[:] = [0.0, 0.0, 1.0, 0.0]
        assert d(np.arange(5)).tolist() == [2] * 5
        probs[:] = 0.25


def test_a_stale_probabilities_name_that_cannot_be_removed_stops_nothing(tmp_path):
    """A folder (or another user's file) under the name of a dead process's probabilities file
    is left where it is; the removal of the others goes on."""
    gone = 999_999_999  # above any pid: no such process
    blocked = tmp_path / f"{PROBS_PREFIX}{gone}-a.f64"
    blocked.mkdir()  # unlink fails on it
    stale = tmp_path / f"{PROBS_PREFIX}{gone}-b.f64"
    stale.write_bytes(b"\0" * 8)
    remove_stale_probs(str(tmp_path))
    assert blocked.is_dir() and not stale.exists()
