"""One-robot TD3 batches at the robot's own limb count (``td3.trim_padding``): the same losses and
gradients as the batch padded to the largest robot, in float64, for every method that claims
it (``padding_free`` in the registry); the schedule cuts only where the method allows it."""

from pathlib import Path

import pytest
import torch

from gcnt.envs.robot_table import trim_rows, trim_table
from gcnt.keys import ACTION, ADJ, MASK, OBS, WL
from gcnt.nn.registry import BUILTIN_NETWORKS, NETWORKS
from gcnt.recipes import load_recipe
from gcnt.rl.factories import make_env, train_robots
from gcnt.rl.td3 import replay as rb
from gcnt.rl.td3.learner import TD3, TD3Learner, trims_padding

ROOT = Path(__file__).parents[1]
QUICK = ROOT / "recipes/quickstart.yaml"
NET = "network.kwargs={d_model: 16, layers: 2, ff: 16, heads: 2}"
ROBOTS = "env.robots=[hopper_3,hopper_4,walker_7_main]"  # 3, 4 and 7 limbs: padded to 7
#: every built-in that claims ``padding_free`` (all of them run on SMPENV's robots)
CLAIMS = sorted(name for name in BUILTIN_NETWORKS if NETWORKS[name].padding_free)


def _setup(method: str):
    recipe = load_recipe(QUICK, [NET, f"network.name={method}", ROBOTS, "td3.schedule=paper"])
    robots = train_robots(recipe)
    env = make_env(recipe, robots)
    torch.manual_seed(0)
    data = env.rollout(10, break_when_any_done=False)
    env.close()
    learner = TD3Learner(recipe, env)
    for m in (learner.actor, learner.critics, learner.target_actor, learner.target_critics):
        m.double()
    with torch.no_grad():  # targets apart from the online networks
        for p in [*learner.target_actor.parameters(), *learner.target_critics.parameters()]:
            p.add_(0.01 * torch.randn_like(p))
    replay = rb.RobotReplay(len(robots), capacity=30, batch_size=6)
    replay.extend(data)
    return recipe, robots, learner, replay


def _double(batch):
    return batch.apply(lambda t: t.double() if t.is_floating_point() else t)


def _losses_and_grads(learner, batch, noise):
    params = learner.actor_params + learner.critic_params
    critic = learner.critic_loss(batch, noise)
    actor = learner.actor_loss(batch)
    grads = torch.autograd.grad(critic + actor, params, allow_unused=True)
    return critic.detach(), actor.detach(), grads


@pytest.mark.parametrize("method", CLAIMS)
def test_a_robots_batch_at_its_own_size_gives_the_padded_losses_and_gradients(method):
    _, robots, learner, replay = _setup(method)
    for robot, r in enumerate(robots):
        torch.manual_seed(1)
        padded = _double(replay.sample_robot(robot))
        torch.manual_seed(1)
        cut = _double(replay.sample_robot(robot, limbs=r.num_limbs))
        assert cut.get(OBS).shape[-2] == r.num_limbs and padded.get(OBS).shape[-2] == 7
        torch.testing.assert_close(cut.get(OBS), padded.get(OBS)[:, : r.num_limbs])
        torch.manual_seed(2)
        noise_padded = learner.padded_noise(padded.get(ACTION))
        torch.manual_seed(2)
        noise_cut = learner.padded_noise(cut.get(ACTION))
        # the same draws: the cut noise is the padded noise's real limbs
        assert torch.equal(noise_cut, noise_padded[:, : r.num_limbs])
        a = _losses_and_grads(learner, padded, noise_padded)
        b = _losses_and_grads(learner, cut, noise_cut)
        torch.testing.assert_close(b[0], a[0], rtol=1e-12, atol=0)
        torch.testing.assert_close(b[1], a[1], rtol=1e-12, atol=0)
        for ga, gb in zip(a[2], b[2], strict=True):
            assert (ga is None) == (gb is None)
            if ga is not None:
                torch.testing.assert_close(gb, ga, rtol=1e-10, atol=1e-14)


def test_the_schedule_cuts_batches_only_for_a_method_that_allows_it():
    for method, expected in (("gcnt", True), ("swat", False)):
        recipe = load_recipe(QUICK, [NET, f"network.name={method}", ROBOTS, "td3.schedule=paper"])
        env = make_env(recipe, train_robots(recipe))
        algo = TD3(recipe, env, train_robots(recipe))
        assert trims_padding(recipe, algo.learner) is expected
        assert (algo.schedule.limbs == [3, 4, 7]) if expected else algo.schedule.limbs is None
        off = load_recipe(QUICK, [NET, f"network.name={method}", ROBOTS, "td3.trim_padding=false"])
        assert not trims_padding(off, algo.learner)
        env.close()


def test_a_table_cut_to_fewer_limbs_keeps_whole_robots_only():
    table = {
        MASK: torch.tensor([[1, 1, 0, 0], [1, 1, 1, 1], [1, 1, 1, 0]], dtype=torch.bool),
        ADJ: torch.arange(48).reshape(3, 4, 4),
        WL: torch.arange(6).reshape(3, 2),
    }
    rows = trim_rows([2, 4, 3], limbs=3)
    assert rows == [0, 0, 2]  # robot 1 (4 limbs) does not fit: robot 0's row stands in
    cut = trim_table(table, rows, 3)
    assert cut[MASK].shape == (3, 3) and cut[ADJ].shape == (3, 3, 3) and cut[WL].shape == (3, 2)
    assert torch.equal(cut[ADJ][2], table[ADJ][2, :3, :3])
    assert torch.equal(cut[ADJ][1], table[ADJ][0, :3, :3]) and torch.equal(cut[WL][1], table[WL][0])
    assert trim_rows([4, 5], limbs=3) is None
