"""torch.compile of the TD3 update steps and of PPO's loss forward on a CPU (the ``compile:`` recipe section).

Compiling takes minutes on a small shared CPU, so this runs only when asked:
``GCNT_TEST_COMPILE=1 pytest tests/test_accelerate.py``. The switches themselves (accepted,
CUDA-only ones rejected on a CPU) are tested in tests/test_accelerate_switches.py.
"""

import os
from pathlib import Path

import pytest
import torch

from gcnt.recipes import load_recipe
from gcnt.rl.factories import make_env, train_robots
from gcnt.rl.td3 import replay as rb
from gcnt.rl.td3.learner import TD3Learner

QUICK = Path(__file__).parents[1] / "recipes/quickstart.yaml"

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(
        os.environ.get("GCNT_TEST_COMPILE") != "1",
        reason="compiling takes minutes on a CPU; set GCNT_TEST_COMPILE=1 to run",
    ),
]


def test_compiled_td3_steps_match_eager_on_cpu():
    import torch._inductor.config as inductor

    # compiled code draws random numbers with its own generator unless told to use eager's
    # (inductor's config.patch, not monkeypatch: undoing a monkeypatch removed the setting)
    with inductor.patch(fallback_random=True):
        _compiled_td3_steps_match_eager()


def _compiled_td3_steps_match_eager():
    over = ["network.kwargs={d_model: 16, layers: 1, ff: 16, heads: 2}", "td3.policy_delay=1"]
    recipe = load_recipe(QUICK, over)
    compiled = load_recipe(QUICK, [*over, "compile.compile=true"])
    env = make_env(recipe, train_robots(recipe))
    data = env.rollout(10, break_when_any_done=False)
    replay = rb.RobotReplay(3, capacity=30, batch_size=6)
    replay.extend(data)
    batch = replay.sample_mixed()
    torch.manual_seed(0)
    eager = TD3Learner(recipe, env)
    torch.manual_seed(0)
    fast = TD3Learner(compiled, env)
    env.close()
    for _ in range(3):
        torch.manual_seed(1)
        a = eager.update(batch)
        torch.manual_seed(1)
        b = fast.update(batch)
        assert a.keys() == b.keys()
        for k in a:
            assert abs(a[k] - b[k]) <= 1e-4 * (1 + abs(a[k])), (k, a[k], b[k])


def test_compiled_ppo_loss_matches_eager_on_cpu(tmp_path):
    """compile.compile: PPO's compiled loss forward gives the eager losses and gradients on the
    same mini-batch."""
    from test_ppo import rollout, tiny_recipe

    from gcnt.rl.loop import prepare
    from gcnt.rl.ppo.learner import _BATCH_KEYS

    recipe = tiny_recipe(tmp_path)
    recipe.compile.compile = True
    prep = prepare(recipe)
    learner = prep.algo.learner
    assert learner.loss_forward is not learner.loss
    batch = learner.advantages(learner.normalized(rollout(prep)))
    keys = [k for k in _BATCH_KEYS if k in batch.keys(True)]
    mb = batch.select(*keys).reshape(-1)[:40]
    prep.env.close()
    learner.actor.train()
    learner.critic.train()
    results = []
    for forward in (learner.loss, learner.loss_forward):
        out = forward(mb.clone())
        total = out["loss_objective"] + out["loss_critic"] + out["loss_entropy"]
        learner.opt.zero_grad(set_to_none=True)
        total.backward()
        grads = [p.grad.clone() for p in learner.params if p.grad is not None]
        results.append((total.detach(), float(out["kl_approx"]), grads))
    (ta, ka, ga), (tb, kb, gb) = results
    assert torch.allclose(ta, tb, rtol=1e-4, atol=1e-5), (ta, tb)
    assert abs(ka - kb) <= 1e-4
    assert len(ga) == len(gb) > 0
    for a, b in zip(ga, gb, strict=True):
        assert torch.allclose(a, b, rtol=1e-3, atol=1e-5)
