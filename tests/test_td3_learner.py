"""Tests for ``gcnt.rl.td3.learner``, the fast TD3 learner, checked in float64 against torchrl's
TD3Loss (tests/reference_td3.py, the reference for ``gcnt.rl.td3.loss``): the critic and actor
losses and their gradients, for every method, on mixed batches and on the paper schedule's
one-robot batches, the soft target update moving the targets by tau, and the twin critics as one
ensemble making the updates of two separate critics.
"""

from pathlib import Path

import pytest
import torch
from reference_td3 import actor_loss, critic_loss, make_td3_loss

from gcnt.recipes import load_recipe
from gcnt.rl.factories import make_env, train_robots
from gcnt.rl.td3 import replay as rb
from gcnt.rl.td3.learner import TD3Learner, stack_pair_adam
from gcnt.rl.td3.twin import AtOnce, InTurn, make_pair_runner

ROOT = Path(__file__).parents[1]
QUICK = ROOT / "recipes/quickstart.yaml"
NET = "network.kwargs={d_model: 16, layers: 1, ff: 16, heads: 2}"


def _double_learner(recipe_overrides=(), net=NET, rule="robot_mean"):
    # torchrl's TD3Loss with the per-robot TD(0) estimator is the robot_mean rule
    recipe = load_recipe(QUICK, [net, f"td3.target={rule}", *recipe_overrides])
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
        [learner.critics.member(i) for i in range(2)],
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
        for name, p in learner.target_critics.net.named_parameters():
            for i in range(2):
                target_q[name][i].copy_(p[i])
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
    # gradients of both critics (the ensemble's stacked parameters), by parameter name
    ref_params = ref.qvalue_network_params.flatten_keys(".")
    g_ref = _grads([(k, v) for k, v in ref_params.items() if "table_" not in k], q_ref)
    g_fast = _grads(list(learner.critics.net.named_parameters()), q_fast)
    assert g_fast.keys() == g_ref.keys()
    for name, g in g_fast.items():
        torch.testing.assert_close(g, g_ref[name], rtol=1e-9, atol=1e-12, msg=name)
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


def _learner_pair(method, overrides=(), threads=False):
    """A float64 ensemble learner (its members in one vmapped call, or with ``threads`` each on
    its own thread) and a two-critic learner (``pair``, the critics in turn) with the same
    weights, and a mixed and a one-robot batch."""
    net = "network.kwargs={}" if method in ("smp", "mlp") else NET
    one = ["env.robots=[hopper_5]"] if method == "mlp" else []
    recipe = load_recipe(QUICK, [net, f"network.name={method}", *one, *overrides])
    robots = train_robots(recipe)
    env = make_env(recipe, robots)
    data = env.rollout(10, break_when_any_done=False)
    learners = []
    for pair in (False, True):
        torch.manual_seed(0)  # the same initial weights: the ensemble stacks what it is given
        learner = TD3Learner(recipe, env, pair=pair, twin_threads=threads and not pair)
        for m in (learner.actor, learner.critics, learner.target_actor, learner.target_critics):
            m.double()
        learners.append(learner)
    env.close()
    replay = rb.RobotReplay(len(robots), capacity=30, batch_size=6)
    replay.extend(data)
    batches = [replay.sample_mixed(), replay.sample_robot(len(robots) - 1)]
    return learners, [
        b.apply(lambda t: t.double() if t.is_floating_point() else t) for b in batches
    ]


def _critic_weights(learner):
    """name -> [2, ...] of either layout."""
    if learner.pair:
        per = [dict(c.named_parameters()) for c in learner.critics]
        return {f"net.{k}": torch.stack([p[k] for p in per]) for k in per[0]}
    return dict(learner.critics.named_parameters())


@pytest.mark.parametrize(
    ("method", "threads"),
    [
        *[
            (m, False)
            for m in ["gcnt", "gcnt_no_gcn", "gcnt_no_wl", "gcnt_no_dist", "amorpheus", "swat"]
        ],
        ("smp", False),
        ("mlp", False),
        ("gcnt", True),
        ("smp", True),
    ],
)
def test_ensemble_updates_equal_two_separate_critics_float64(method, threads):
    """Both schedules' batches (mixed and one robot), gradient clipping on, two actor steps: the
    ensemble's losses, weights and Adam moments are the two separate critics', with its members
    in one vmapped call or each on its own thread (``compile.twin_threads``)."""
    (ens, pair), batches = _learner_pair(
        method, ["td3.max_grad_norm=0.5", "td3.target=limb"], threads
    )
    assert ens.twin.parallel is threads and not pair.twin.parallel
    for step in range(4):
        for batch in batches:
            torch.manual_seed(step)
            losses = ens.update(batch)
            torch.manual_seed(step)
            assert losses == pytest.approx(pair.update(batch), rel=1e-10, abs=1e-12)
    for name in ("actor", "target_actor"):
        mine = dict(getattr(pair, name).named_parameters())
        for key, p in getattr(ens, name).named_parameters():
            torch.testing.assert_close(p, mine[key], rtol=1e-9, atol=1e-12, msg=f"{name}.{key}")
    for online in (True, False):
        a = _critic_weights(ens) if online else dict(ens.target_critics.named_parameters())
        if online:
            b = _critic_weights(pair)
        else:
            per = [dict(c.named_parameters()) for c in pair.target_critics]
            b = {f"net.{k}": torch.stack([p[k] for p in per]) for k in per[0]}
        assert a.keys() == b.keys()
        for key in a:
            torch.testing.assert_close(a[key], b[key], rtol=1e-9, atol=1e-12, msg=key)
    # the ensemble's Adam moments are the two critics' stacked
    converted = stack_pair_adam(pair.critic_opt.state_dict(), len(ens.critic_params))
    mine = ens.critic_opt.state_dict()["state"]
    for j, state in converted["state"].items():
        for k in ("exp_avg", "exp_avg_sq"):
            torch.testing.assert_close(mine[j][k], state[k], rtol=1e-9, atol=1e-15)


def test_robot_sum_rule_and_the_ensemble_losses_are_the_pairs():
    (ens, pair), batches = _learner_pair("gcnt", ["td3.target=robot_sum"])
    for batch in batches:
        torch.manual_seed(4)
        q_ens = ens.critic_loss(batch)
        torch.manual_seed(4)
        torch.testing.assert_close(q_ens, pair.critic_loss(batch), rtol=1e-12, atol=1e-12)
        torch.testing.assert_close(
            ens.actor_loss(batch), pair.actor_loss(batch), rtol=1e-12, atol=1e-12
        )


def test_torch_threads_apply_to_the_run():
    from gcnt.rl.loop import prepare

    before = torch.get_num_threads()
    try:
        recipe = load_recipe(QUICK, ["compile.torch_threads=1"])
        prepare(recipe).env.close()
        assert torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(before)
    with pytest.raises(ValueError, match="torch_threads must be >= 1"):
        load_recipe(QUICK, ["compile.torch_threads=0"])


def test_the_update_takes_one_thread_on_a_small_cpu_unless_told(monkeypatch):
    from gcnt.rl.td3 import learner as td3_learner

    recipe = load_recipe(QUICK)
    for cores, want in ((1, False), (2, True), (4, True), (8, False)):
        monkeypatch.setattr(td3_learner, "usable_cpus", lambda n=cores: n)
        assert td3_learner.one_update_thread(recipe) is want
    assert not td3_learner.one_update_thread(load_recipe(QUICK, ["compile.torch_threads=2"]))
    monkeypatch.setattr(td3_learner, "usable_cpus", lambda: 2)  # compiled too
    assert td3_learner.one_update_thread(load_recipe(QUICK, ["compile.compile=true"]))


def test_twin_threads_are_refused_where_they_cannot_hold():
    with pytest.raises(ValueError, match="dropout"):
        _double_learner(["compile.twin_threads=true", "network.name=metamorph"])
    with pytest.raises(ValueError, match="twin_threads"):
        load_recipe(QUICK, ["compile.twin_threads=true", "compile.compile=true"])
    with pytest.raises(ValueError, match="torch_threads"):
        load_recipe(QUICK, ["compile.twin_threads=true", "compile.torch_threads=2"])
    cpu = torch.device("cpu")
    assert isinstance(make_pair_runner(None, cpu, False, False, torch_threads=2), InTurn)
    assert isinstance(make_pair_runner(None, cpu, True, False), InTurn)  # compiled
    assert isinstance(make_pair_runner(None, torch.device("cuda"), False, False), InTurn)


def test_twin_threads_work_in_a_forked_child():
    """A process forked after the helper thread started has no helper: it starts its own."""
    import multiprocessing

    runner = AtOnce()
    assert runner.map(abs, (-1, -2)) == [1, 2]
    ctx = multiprocessing.get_context("fork")
    out = ctx.Queue()
    child = ctx.Process(target=lambda: out.put(runner.map(abs, (-3, -4))))
    child.start()
    assert out.get(timeout=60) == [3, 4]
    child.join(timeout=60)
    assert child.exitcode == 0


def test_a_critic_that_vmap_cannot_run_is_one_line_naming_the_method(monkeypatch, tmp_path, capsys):
    """A network that reads a tensor's value in Python works as two networks or on threads, but
    not as the ensemble in one vmapped call (a GPU's path): the first update says so in one
    line, naming the method and the switch, and ``gcnt train`` exits 2."""
    from cli_helpers import error_line, tiny_td3_recipe

    from gcnt.nn import stages
    from gcnt.rl.td3.ensemble import VmapError

    encode = stages.LimbEncoder.forward

    def reading(self, x):
        y = encode(self, x)
        if y.abs().sum().item() < 0:  # a Python branch on a value the weights make
            y = -y
        return y

    monkeypatch.setattr(stages.LimbEncoder, "forward", reading)
    recipe, _, batch = _double_learner()
    env = make_env(recipe, train_robots(recipe))
    threads = TD3Learner(recipe, env, twin_threads=True)
    one_call = TD3Learner(recipe, env, twin_threads=False)
    env.close()
    batch = batch.apply(lambda t: t.float() if t.is_floating_point() else t)
    assert set(threads.update(batch)) == {"loss_critic"}
    with pytest.raises(VmapError, match=r"^gcnt: its forward cannot run under torch\.vmap"):
        one_call.update(batch)

    path = tiny_td3_recipe(tmp_path / "tiny.yaml")
    run = tmp_path / "run"
    line = error_line(capsys, ["train", str(path), "compile.twin_threads=false", f"run_dir={run}"])
    assert "gcnt: its forward cannot run under torch.vmap" in line
    assert "compile.twin_threads=true" in line
    assert not run.exists()  # the run failed before it logged anything: nothing left behind
