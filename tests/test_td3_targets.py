"""The three TD target rules of ``gcnt.rl.td3.loss`` (``td3.target``) in float64 against a
hand-written reference that loops over samples and real limbs, on a batch with a terminated, a
truncated (done, not terminated), a running and a padded row; and which rule each method trains
with by default."""

import pytest
import torch

from gcnt.rl.td3.config import TD3Config, target_rule
from gcnt.rl.td3.loss import TARGET_RULES, deterministic_actor_loss, td_target, twin_critic_loss

GAMMA = 0.9


def batch():
    g = torch.Generator().manual_seed(0)
    b, k = 4, 5
    mask = torch.tensor(
        [[1, 1, 1, 0, 0], [1, 1, 1, 1, 1], [1, 1, 0, 0, 0], [1, 1, 1, 1, 0]], dtype=torch.bool
    )

    def q():
        x = torch.randn(b, k, 1, generator=g, dtype=torch.float64)
        return torch.where(mask.unsqueeze(-1), x, torch.full_like(x, 1e6))  # padding: garbage

    reward = torch.randn(b, 1, generator=g, dtype=torch.float64)
    # row 0 terminated, row 1 truncated (done, not terminated), rows 2-3 running
    terminated = torch.tensor([[True], [False], [False], [False]])
    return dict(mask=mask, reward=reward, terminated=terminated, q=(q(), q()), nq=(q(), q()))


def reference(rule, d):
    """Loops over samples and real limbs: (critic loss, actor loss)."""
    mask, r, term = d["mask"], d["reward"], d["terminated"]
    q, nq = d["q"], d["nq"]
    critic, actor = [], []
    for b in range(mask.shape[0]):
        limbs = [i for i in range(mask.shape[1]) if mask[b, i]]
        boot = 0.0 if term[b, 0] else GAMMA
        if rule == "robot_sum":
            s_next = [sum(float(n[b, i, 0]) for i in limbs) for n in nq]
            y = float(r[b, 0]) + boot * min(s_next)
            critic.append(sum((sum(float(c[b, i, 0]) for i in limbs) - y) ** 2 for c in q))
            actor.append(-sum(float(q[0][b, i, 0]) for i in limbs))
            continue
        mins = [min(float(n[b, i, 0]) for n in nq) for i in limbs]
        if rule == "limb":
            ys = [float(r[b, 0]) + boot * m for m in mins]
        else:  # robot_mean
            ys = [float(r[b, 0]) + boot * sum(mins) / len(mins)] * len(limbs)
        errs = [
            sum((float(c[b, i, 0]) - y) ** 2 for c in q) for i, y in zip(limbs, ys, strict=True)
        ]
        critic.append(sum(errs) / len(limbs))
        actor.append(-sum(float(q[0][b, i, 0]) for i in limbs) / len(limbs))
    return sum(critic) / len(critic), sum(actor) / len(actor)


@pytest.mark.parametrize("rule", TARGET_RULES)
def test_each_rule_equals_the_hand_written_reference(rule):
    d = batch()
    target = td_target(d["reward"], d["terminated"], d["nq"], d["mask"], GAMMA, rule)
    assert target.dtype == torch.float64
    assert target.shape == ((4, 5) if rule == "limb" else (4, 1))
    critic = twin_critic_loss(d["q"], target, d["mask"], rule)
    actor = deterministic_actor_loss(d["q"][0], d["mask"], rule)
    ref_critic, ref_actor = reference(rule, d)
    assert critic.item() == pytest.approx(ref_critic, rel=1e-12)
    assert actor.item() == pytest.approx(ref_actor, rel=1e-12)
    assert torch.isfinite(critic)  # the 1e6 on padding never entered


def test_the_rules_differ_where_they_should():
    d = batch()
    t = {
        r: td_target(d["reward"], d["terminated"], d["nq"], d["mask"], GAMMA, r)
        for r in TARGET_RULES
    }
    # a terminated row is the reward alone under every rule
    for rule in TARGET_RULES:
        assert torch.all(t[rule][0] == d["reward"][0, 0])
    # the per-limb target varies over a running robot's limbs; the robot targets do not
    assert t["limb"][2, :2].unique().numel() == 2


def test_each_method_trains_with_its_originals_rule():
    auto = TD3Config()
    for net in ("gcnt", "gcnt_no_gcn", "gcnt_no_wl", "gcnt_no_dist", "amorpheus", "swat", "smp"):
        assert target_rule(auto, net) == "limb"
    for net in ("sr", "mlp"):
        assert target_rule(auto, net) == "robot_sum"
    assert target_rule(TD3Config(target="robot_mean"), "gcnt") == "robot_mean"
    with pytest.raises(ValueError, match="target must be one of"):
        TD3Config(target="per_robot").check()


def test_the_learner_trains_with_the_recipes_rule():
    """Same robots, seeds and batch layout: the learner resolves ``td3.target`` to its rule and
    the three rules give three different critic losses (the rule reaches the loss)."""
    from gcnt.recipes import load_recipe
    from gcnt.rl.factories import make_env, train_robots
    from gcnt.rl.td3 import replay as rb
    from gcnt.rl.td3.learner import TD3Learner

    losses = {}
    for rule in TARGET_RULES:
        recipe = load_recipe(
            "recipes/quickstart.yaml",
            ["network.kwargs={d_model: 16, layers: 1, ff: 16}", f"td3.target={rule}"],
        )
        robots = train_robots(recipe)
        env = make_env(recipe, robots)
        torch.manual_seed(0)
        data = env.rollout(8, break_when_any_done=False)
        learner = TD3Learner(recipe, env)
        env.close()
        assert learner.rule == rule
        replay = rb.RobotReplay(len(robots), capacity=20, batch_size=4)
        replay.extend(data)
        torch.manual_seed(1)
        batch = replay.sample_mixed()
        torch.manual_seed(2)
        losses[rule] = learner.critic_loss(batch).item()
    assert len({round(v, 6) for v in losses.values()}) == 3, losses
