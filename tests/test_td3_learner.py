"""Tests for ``gcnt.rl.td3.learner``, the fast TD3 learner, checked in float64 against torchrl's
TD3Loss (tests/reference_td3.py, the reference for ``gcnt.rl.td3.loss``): the critic and actor
losses and their gradients, for every method, on mixed batches and on the paper schedule's
one-robot batches, and the soft target update moving the targets by tau.
"""

import copy
from pathlib import Path

import pytest
import torch
from reference_td3 import actor_loss, critic_loss, make_td3_loss

from gcnt.recipes import load_recipe
from gcnt.rl.factories import make_env, train_robots
from gcnt.rl.td3 import replay as rb
from gcnt.rl.td3.learner import TD3Learner

ROOT = Path(__file__).parents[1]
QUICK = ROOT / "recipes/quickstart.yaml"
NET = "network.kwargs={d_model: 16, layers: 1, ff: 16, heads: 2}"


def _double_learner(recipe_overrides=(), net=NET):
    # torchrl's TD3Loss with the per-robot TD(0) estimator is the robot_mean rule
    recipe = load_recipe(QUICK, [net, "td3.target=robot_mean", *recipe_overrides])
    robots = train_robots(recipe)
    env = make_env(recipe, robots)
    data = env.rollout(10, break_when_any_done=False)
    learner = TD3Learner(recipe, env)
    for m in (learner.actor, learner.critics, learner.target_actor, learner.target_critics):
        m.double()
    # targets that differ from the online networks, so the test tells them apart
    with torch.no_grad():
        for p in [*learner.target_actor.parameters(), *learner.target_critics.parameters()]:
            p.add_(0.01 * torch.randn_like(p))
    replay = rb.RobotReplay(len(robots), capacity=30, batch_size=6)
    replay.extend(data)
    batch = replay.sample_mixed().apply(lambda t: t.double() if t.is_floating_point() else t)
    env.close()
    return recipe, learner, batch


def _reference(recipe, learner):
    """torchrl's TD3Loss over the same modules, with the learner's targets."""
    c = recipe.td3
    loss = make_td3_loss(
        learner.actor,
        list(learner.critics),
        gamma=c.gamma,
        policy_noise=c.policy_noise,
        noise_clip=c.noise_clip,
    )
    # torchrl keeps gamma as a float32 buffer (0.99 becomes 0.99000001): use the exact value
    loss._value_estimator.gamma = torch.tensor(c.gamma, dtype=torch.float64)
    with torch.no_grad():
        target_actor = loss.target_actor_network_params.flatten_keys(".")
        for name, p in learner.target_actor.named_parameters():
            target_actor[name].copy_(p)
        target_q = loss.target_qvalue_network_params.flatten_keys(".")
        for i, critic in enumerate(learner.target_critics):
            for name, p in critic.named_parameters():
                target_q[name][i].copy_(p)
    return loss


def _grads(named, loss_value):
    names, params = zip(*named, strict=True)
    return dict(zip(names, torch.autograd.grad(loss_value, params, allow_unused=True), strict=True))


def test_fast_critic_and_actor_losses_equal_torchrl_td3loss_float64():
    recipe, learner, batch = _double_learner()
    ref = _reference(recipe, learner)
    lookup = learner.actor[0]
    torch.manual_seed(0)
    q_ref = critic_loss(ref, lookup(batch.clone()))
    torch.manual_seed(0)
    q_fast = learner.critic_loss(batch)
    assert q_fast.dtype == torch.float64
    torch.testing.assert_close(q_fast, q_ref, rtol=1e-12, atol=1e-12)
    # gradients of both critics, by parameter name
    ref_params = ref.qvalue_network_params.flatten_keys(".")
    g_ref = _grads([(k, v) for k, v in ref_params.items() if "table_" not in k], q_ref)
    for i, critic in enumerate(learner.critics):
        g_fast = _grads(
            list(critic.named_parameters()), q_fast if i == 0 else _again(learner, batch)
        )
        for name, g in g_fast.items():
            torch.testing.assert_close(g, g_ref[name][i], rtol=1e-9, atol=1e-12, msg=name)
    a_ref = actor_loss(ref, lookup(batch.clone()))
    a_fast = learner.actor_loss(batch)
    torch.testing.assert_close(a_fast, a_ref, rtol=1e-12, atol=1e-12)
    ga_ref = _grads(
        [
            (k, v)
            for k, v in ref.actor_network_params.flatten_keys(".").items()
            if "table_" not in k
        ],
        a_ref,
    )
    for name, g in _grads(list(learner.actor.named_parameters()), a_fast).items():
        torch.testing.assert_close(g, ga_ref[name], rtol=1e-9, atol=1e-12, msg=name)


def _again(learner, batch):
    torch.manual_seed(0)
    return learner.critic_loss(batch)


@pytest.mark.parametrize("method", ["amorpheus", "swat", "smp", "metamorph", "mlp"])
def test_every_method_gives_torchrl_td3loss_losses(method):
    net = "network.kwargs={}" if method in ("smp", "mlp") else NET
    # SR's MLP is one network per robot: it trains one robot (several are refused)
    one = ["env.robots=[hopper_5]"] if method == "mlp" else []
    recipe, learner, batch = _double_learner([f"network.name={method}", *one], net)
    ref = _reference(recipe, learner)
    torch.manual_seed(0)
    q_ref = critic_loss(ref, learner.actor[0](batch.clone()))
    torch.manual_seed(0)
    torch.testing.assert_close(learner.critic_loss(batch), q_ref, rtol=1e-11, atol=1e-12)
    torch.manual_seed(1)  # MetaMorph has dropout: the same draws in both
    a_ref = actor_loss(ref, learner.actor[0](batch.clone()))
    torch.manual_seed(1)
    torch.testing.assert_close(learner.actor_loss(batch), a_ref, rtol=1e-11, atol=1e-12)


def test_paper_schedule_batches_of_one_robot_equal_too():
    recipe, learner, _ = _double_learner()
    # a one-robot batch (the paper schedule) through both paths
    env = make_env(recipe, train_robots(recipe))
    data = env.rollout(10, break_when_any_done=False)
    env.close()
    replay = rb.RobotReplay(3, capacity=30, batch_size=6)
    replay.extend(data)
    batch = replay.sample_robot(2).apply(lambda t: t.double() if t.is_floating_point() else t)
    ref = _reference(recipe, learner)
    torch.manual_seed(5)
    q_ref = critic_loss(ref, learner.actor[0](batch.clone()))
    torch.manual_seed(5)
    torch.testing.assert_close(learner.critic_loss(batch), q_ref, rtol=1e-12, atol=1e-12)


def test_soft_target_update_moves_targets_by_tau():
    recipe, learner, batch = _double_learner(["td3.policy_delay=1"])
    before = [p.clone() for p in learner.target_actor.parameters()]
    learner.update(batch)
    tau = recipe.td3.tau
    for b, t, p in zip(
        before, learner.target_actor.parameters(), learner.actor.parameters(), strict=True
    ):
        torch.testing.assert_close(t, (1 - tau) * b + tau * p)


def test_twin_critics_on_two_threads_make_the_same_updates():
    """compile.twin_threads: the critics and target critics on two threads give the updates of
    the critics in turn (float64, the learner's own steps, with gradient clipping), and the
    switch is refused where it cannot hold."""
    from gcnt.rl.td3.twin import AtOnce, InTurn

    _, learner, batch = _double_learner(["td3.max_grad_norm=0.5"])
    twin = copy.deepcopy(learner)
    learner.twin, twin.twin = InTurn(), AtOnce()
    for _ in range(4):  # two actor steps (policy_delay 2)
        torch.manual_seed(3)
        losses = learner.update(batch)
        torch.manual_seed(3)
        assert twin.update(batch) == pytest.approx(losses, rel=1e-12)
    for name in ("actor", "critics", "target_actor", "target_critics"):
        mine = dict(getattr(twin, name).named_parameters())
        for key, p in getattr(learner, name).named_parameters():
            torch.testing.assert_close(mine[key], p, rtol=1e-12, atol=1e-14, msg=f"{name}.{key}")

    with pytest.raises(ValueError, match="dropout"):
        _double_learner(["compile.twin_threads=true", "network.name=metamorph"])
    with pytest.raises(ValueError, match="twin_threads"):
        load_recipe(QUICK, ["compile.twin_threads=true", "compile.compile=true"])
    with pytest.raises(ValueError, match="torch_threads"):
        load_recipe(QUICK, ["compile.twin_threads=true", "compile.torch_threads=2"])
    with pytest.raises(ValueError, match="torch_threads must be >= 1"):
        load_recipe(QUICK, ["compile.torch_threads=0"])


def test_torch_threads_apply_to_the_run_and_more_than_one_leaves_the_critics_in_turn():
    from gcnt.rl.loop import prepare
    from gcnt.rl.td3.twin import InTurn, make_pair_runner

    before = torch.get_num_threads()
    try:
        recipe = load_recipe(QUICK, ["compile.torch_threads=1"])
        prepare(recipe).env.close()
        assert torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(before)
    cpu = torch.device("cpu")
    assert isinstance(make_pair_runner(None, cpu, False, False, torch_threads=2), InTurn)
    assert isinstance(make_pair_runner(None, cpu, True, False), InTurn)  # compiled
    assert isinstance(make_pair_runner(None, torch.device("cuda"), False, False), InTurn)


def test_twin_threads_work_in_a_forked_child():
    """A process forked after the helper thread started has no helper: it starts its own."""
    import multiprocessing

    from gcnt.rl.td3.twin import AtOnce

    runner = AtOnce()
    assert runner.map(abs, (-1, -2)) == [1, 2]
    ctx = multiprocessing.get_context("fork")
    out = ctx.Queue()
    child = ctx.Process(target=lambda: out.put(runner.map(abs, (-3, -4))))
    child.start()
    assert out.get(timeout=60) == [3, 4]
    child.join(timeout=60)
    assert child.exitcode == 0
