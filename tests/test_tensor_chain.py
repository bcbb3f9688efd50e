"""Tests for ``gcnt.rl.td3.tensor_chain``, the plain-tensor chain calls: a ``TensorChain`` runs the
robot-only stages (the limb GCN and the distance bias) once per robot, and ``TensorChainModule``
acts like the chain it wraps on an environment's output (float64), for any leading batch dims.
"""

from pathlib import Path

import torch

from gcnt.keys import ACTION, OBS
from gcnt.recipes import load_recipe
from gcnt.rl.factories import make_env, train_robots
from gcnt.rl.td3.learner import TD3Learner
from gcnt.rl.td3.tensor_chain import TensorChain, TensorChainModule

ROOT = Path(__file__).parents[1]
QUICK = ROOT / "recipes/quickstart.yaml"
NET = "network.kwargs={d_model: 16, layers: 1, ff: 16, heads: 2}"


def test_robot_only_stages_run_once_per_robot():
    recipe = load_recipe(QUICK, [NET])
    env = make_env(recipe, train_robots(recipe))
    chain = TensorChain(TD3Learner(recipe, env).critics.net)
    per_robot = {type(st.module.module).__name__ for st in chain.stages if st.per_robot}
    assert per_robot == {"LimbGCN", "DistanceBias"}
    env.close()


def test_policy_module_acts_like_the_chain_on_env_output():
    recipe = load_recipe(QUICK, [NET])
    env = make_env(recipe, train_robots(recipe))
    actor = TD3Learner(recipe, env).actor.double()
    td = env.reset().apply(lambda t: t.double() if t.is_floating_point() else t)
    fast = TensorChainModule(actor, [ACTION])
    assert fast.in_keys == ["morph_id", OBS]
    a = fast(td.clone())[ACTION]
    torch.testing.assert_close(a, actor(td.clone())[ACTION], rtol=1e-12, atol=1e-12)
    # any leading batch dims
    two = torch.stack([td, td]).clone()
    assert fast(two)[ACTION].shape == (2, *a.shape)
    env.close()
