"""The fast TD3 learner: one replay storage, plain-tensor chain calls, the compile switches.

Equalities are checked in float64 against torchrl's TD3Loss (the reference path in
``gcnt.rl.td3_loss``) and against torchrl's per-robot ReplayBufferEnsemble.
"""

from pathlib import Path

import pytest
import torch
from tensordict import TensorDict

from gcnt.nn.keys import ACTION, OBS
from gcnt.recipes import RecipeError, load_recipe
from gcnt.rl import replay as rb
from gcnt.rl.factories import make_env, train_robots
from gcnt.rl.loop import train
from gcnt.rl.run_dir import RunDir
from gcnt.rl.td3 import TD3Learner
from gcnt.rl.td3_loss import actor_loss, critic_loss, make_td3_loss
from gcnt.rl.tensor_chain import TensorChain, TensorChainModule

ROOT = Path(__file__).parents[1]
QUICK = ROOT / "recipes/quickstart.yaml"
NET = "network.kwargs={d_model: 16, layers: 1, ff: 16, heads: 2}"


def fake_batch(n: int, robots: list[int], k: int = 2, start: float = 0.0) -> TensorDict:
    """``n`` transitions with recognisable observations (start, start+1, ...)."""
    obs = (start + torch.arange(float(n))).view(n, 1, 1).expand(n, k, 1).clone()
    return TensorDict(
        {
            "morph_id": torch.tensor(robots),
            "limbs": {"obs": obs, "action": torch.zeros(n, k, 1)},
            "next": {
                "limbs": {"obs": obs + 0.5},
                "reward": torch.ones(n, 1),
                "done": torch.zeros(n, 1, dtype=torch.bool),
                "terminated": torch.zeros(n, 1, dtype=torch.bool),
                "truncated": torch.zeros(n, 1, dtype=torch.bool),
            },
            "graph": {"adj": torch.zeros(n, k, k, dtype=torch.bool)},  # not stored
        },
        batch_size=[n],
    )


# ------------------------------------------------------------------------------- replay


def test_one_storage_rings_per_robot_and_mixed_sample_has_every_robot():
    replay = rb.RobotReplay(3, capacity=4, batch_size=5)
    assert replay.extend(fake_batch(6, [0, 1, 2, 1, 1, 2])) == 6
    assert [replay.robot_len(i) for i in range(3)] == [1, 3, 2]
    assert "graph" not in replay.storage.keys()
    one = replay.sample_robot(1)
    assert one.shape == (5,) and set(one["morph_id"].tolist()) == {1}
    assert set(one["limbs", "obs"][:, 0, 0].tolist()) <= {1.0, 3.0, 4.0}
    mixed = replay.sample_mixed()
    assert mixed.shape == (15,) and mixed["morph_id"].tolist() == [0] * 5 + [1] * 5 + [2] * 5
    # the ring overwrites a robot's oldest transitions, in collection order
    replay.extend(fake_batch(4, [1, 1, 1, 0], start=10))
    assert replay.robot_len(1) == 4
    ring = replay.storage["limbs", "obs"][1, :, 0, 0].tolist()
    assert sorted(ring) == [4.0, 10.0, 11.0, 12.0] and ring[replay.cursor[1] - 1] == 12.0
    # more new transitions than the capacity: the last ones win
    replay.extend(fake_batch(6, [2] * 6, start=20))
    assert sorted(replay.storage["limbs", "obs"][2, :, 0, 0].tolist()) == [22, 23, 24, 25]


def test_sampling_an_empty_robot_fails_clearly():
    replay = rb.RobotReplay(2, capacity=4, batch_size=2)
    replay.extend(fake_batch(2, [0, 0]))
    with pytest.raises(RuntimeError, match=r"robot\(s\) \[1\]"):
        replay.sample_mixed()


def test_one_storage_holds_what_the_ensemble_holds_and_gives_the_same_loss(tmp_path):
    recipe = load_recipe(QUICK, [NET])
    robots = train_robots(recipe)
    env = make_env(recipe, robots)
    data = env.rollout(12, break_when_any_done=False)
    replay = rb.RobotReplay(len(robots), capacity=20, batch_size=8)
    ensemble = rb.make_ensemble(len(robots), capacity=20, batch_size=8)
    replay.extend(data)
    rb.ensemble_store(ensemble, data)
    torch.manual_seed(3)
    mixed = replay.sample_mixed()
    # the same rows from the per-robot buffers
    rows = []
    for r in range(len(robots)):
        stored = ensemble[r].storage[: len(ensemble[r])]
        assert replay.robot_len(r) == len(ensemble[r])
        for key in rb.STORED_KEYS:
            assert torch.equal(replay.storage[r, : len(ensemble[r])].get(key), stored.get(key))
        # find each sampled row of robot r in the ensemble's storage by its observation
        sampled = mixed[mixed["morph_id"] == r]
        match = (sampled["limbs", "obs"][:, None] == stored["limbs", "obs"][None]).flatten(2)
        assert match.all(-1).any(-1).all()  # every sampled row is one the robot stored
        idx = match.all(-1).float().argmax(-1)
        rows.append(stored[idx])
    from_ensemble = torch.cat(rows)
    # the one-storage sample is those per-robot rows, in the same order, on every stored key
    for key in rb.STORED_KEYS:
        assert torch.equal(mixed.get(key), from_ensemble.get(key)), key
    learner = TD3Learner(recipe, env)
    torch.manual_seed(0)
    a = learner.critic_loss(mixed)
    torch.manual_seed(0)
    b = learner.critic_loss(from_ensemble)
    assert torch.equal(a, b)
    env.close()


def test_replay_checkpoint_round_trip(tmp_path):
    replay = rb.RobotReplay(2, capacity=3, batch_size=2)
    replay.extend(fake_batch(5, [0, 1, 1, 1, 1]))
    path = replay.save(tmp_path / "replay.pt")
    again = rb.RobotReplay(2, capacity=3, batch_size=2)
    again.load(path)
    assert torch.equal(again.cursor, replay.cursor) and torch.equal(again.sizes, replay.sizes)
    assert (again.storage == replay.storage).all()
    torch.manual_seed(1)
    x = replay.sample_mixed()
    torch.manual_seed(1)
    assert (again.sample_mixed() == x).all()
    with pytest.raises(ValueError, match="2 robots x 3"):
        rb.RobotReplay(3, capacity=3, batch_size=2).load(path)


# ------------------------------------------------------------------------ learner vs TD3Loss


def _double_learner(recipe_overrides=(), net=NET):
    recipe = load_recipe(QUICK, [net, *recipe_overrides])
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
    recipe, learner, batch = _double_learner([f"network.name={method}"], net)
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


def test_robot_only_stages_run_once_per_robot():
    recipe = load_recipe(QUICK, [NET])
    env = make_env(recipe, train_robots(recipe))
    chain = TensorChain(TD3Learner(recipe, env).critics[0])
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


def test_soft_target_update_moves_targets_by_tau():
    recipe, learner, batch = _double_learner(["td3.policy_delay=1"])
    before = [p.clone() for p in learner.target_actor.parameters()]
    learner.update(batch)
    tau = recipe.td3.tau
    for b, t, p in zip(
        before, learner.target_actor.parameters(), learner.actor.parameters(), strict=True
    ):
        torch.testing.assert_close(t, (1 - tau) * b + tau * p)


# ------------------------------------------------------------------------ compile switches


def test_compile_switches_are_accepted_and_cuda_only_ones_rejected_on_cpu():
    r = load_recipe(
        QUICK, ["compile.compile=true", "compile.policy_compile=true", "compile.mode=default"]
    )
    assert r.compile.compile and r.compile.policy_compile
    assert not load_recipe(QUICK).compile.compile  # off by default
    for key in ("cudagraphs", "amp", "replay_on_device", "policy_cudagraphs"):
        with pytest.raises(RecipeError) as e:
            load_recipe(QUICK, [f"compile.{key}=true"])
        msg = str(e.value)
        assert f"compile.{key}=true needs a CUDA device" in msg and "\n" not in msg
    with pytest.raises(RecipeError, match="compile: mode must be one of"):
        load_recipe(QUICK, ["compile.mode=fast"])


def test_collector_and_optimizer_switches():
    from gcnt.recipes import CompileConfig
    from gcnt.rl.accelerate import accelerate, collector_kwargs, optimizer_kwargs

    assert collector_kwargs(CompileConfig()) == {}
    assert collector_kwargs(CompileConfig(policy_compile=True)) == {"compile_policy": True}
    assert optimizer_kwargs(CompileConfig(), "cpu") == {"fused": True}
    f = lambda x: x + 1  # noqa: E731
    assert accelerate(f, CompileConfig(), "cpu") is f


def test_checkpointed_buffers_resume_exactly(tmp_path):
    run_dir = tmp_path / "run"
    over = [
        NET,
        "env.max_episode_steps=15",
        "td3.init_random_frames=30",
        "td3.steps_per_batch=5",
        "td3.batch_size=8",
        "td3.updates_per_step=0.25",
        "td3.checkpoint_buffers=true",
        "logger.backend=none",
        "logger.progress=false",
        "logger.log_interval=30",
        "checkpoint_interval=30",
        "eval.episodes=0",
        f"run_dir={run_dir}",
        "collector.total_frames=60",
    ]
    recipe = load_recipe(QUICK, over)
    run = RunDir(run_dir)
    run.create(recipe)
    train(recipe, run)
    state = run.load_checkpoint()
    assert state["has_buffers"] and state["learner"]["stored"] == 60
    files = sorted(p.name for p in run.buffers_dir.iterdir())
    assert files == ["replay-30.pt", "replay-60.pt"] or files == ["replay-60.pt"]
    saved = torch.load(run.buffers_dir / state["learner"]["buffer_file"], weights_only=True)
    # resume: the replay comes back exactly as checkpointed
    from gcnt.rl.loop import prepare

    resumed = load_recipe(run.recipe_path, ["collector.total_frames=90"])
    prepared = prepare(resumed)
    prepared.algo.load_state_dict(state["learner"])
    prepared.algo.load_buffers(run.buffers_dir)
    again = prepared.algo.replay.state_dict()
    assert torch.equal(again["sizes"], saved["sizes"]) and again["sizes"].sum() == 60
    for k, v in saved["data"].items():
        assert torch.equal(again["data"][k], v), k
    prepared.env.close()
    from gcnt.cli import main as gcnt

    assert gcnt(["train", "--resume", str(run_dir), "collector.total_frames=90"]) == 0
    assert run.load_checkpoint()["learner"]["stored"] == 90
    assert sorted(p.name for p in run.buffers_dir.iterdir()) == ["replay-60.pt", "replay-90.pt"]
