"""PPO pipeline: training through `gcnt train` on SMPENV and UNIMAL (tiny), the KL early stop,
the learning-rate schedule, observation statistics (frozen at evaluation, restored from a
checkpoint), exact continuation from a checkpointed state, slot envs, and GAE with bootstrapped
timeouts (by hand, float64). The statistics themselves are tested in tests/test_normalize.py,
robot sampling in tests/test_robot_sampler.py, the summary over robots in tests/test_evaluate.py."""

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule

from gcnt.cli import main as gcnt
from gcnt.envs.smpenv import SMPEnv
from gcnt.morphology.catalogues import resolve_robots
from gcnt.recipes import load_recipe, recipe_from_dict
from gcnt.rl.loop import prepare
from gcnt.rl.ppo.config import PPOConfig
from gcnt.rl.ppo.learner import PPO, NormalizedPolicy, lr_factor, make_gae
from gcnt.run.directory import RunDir, plain_state

OBS_KEY = ("limbs", "obs")
TINY_NET = {"d_model": 16, "layers": 1, "ff": 16, "heads": 2}


def tiny_recipe(run_dir, benchmark="smpenv", **ppo):
    robots = ["Hopper++:train"] if benchmark == "smpenv" else ["unimal_0000", "unimal_0001"]
    cfg = {
        "num_envs": 4,
        "steps_per_env": 20,
        "minibatch_size": 40,
        "epochs": 2,
        "uniform_iterations": 1,
        **ppo,
    }
    return recipe_from_dict(
        {
            "algo": "ppo",
            "task": "tiny",
            "run_dir": str(run_dir),
            "env": {
                "benchmark": benchmark,
                "robots": robots,
                "max_episode_steps": 15,
                "num_threads": 1,
                **({"world": "ft"} if benchmark == "unimal" else {}),
            },
            "collector": {"total_frames": 240},
            "network": {"kwargs": TINY_NET},
            "ppo": cfg,
            "logger": {"backend": "none", "progress": False, "log_interval": 80},
            "eval": {"episodes": 1, "deterministic": False},
            "checkpoint_interval": 80,
        }
    )


@torch.no_grad()
def rollout(prep, steps=20, policy=None):
    """One iteration's data [N, T] as the collector gathers it (sampled actions)."""
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    with set_exploration_type(ExplorationType.RANDOM):
        return prep.env.rollout(steps, policy or prep.algo.policy(), break_when_any_done=False)


def yaml_recipe(tmp_path, benchmark):
    import yaml

    path = tmp_path / "r.yaml"
    path.write_text(yaml.safe_dump(tiny_recipe(tmp_path / "run", benchmark).to_dict()))
    return path


@pytest.mark.parametrize("benchmark", ["smpenv", "unimal"])
def test_ppo_trains_through_gcnt_train(benchmark, tmp_path, capsys):
    path = yaml_recipe(tmp_path, benchmark)
    assert gcnt(["train", str(path)]) == 0
    run = RunDir(tmp_path / "run")
    rows = run.read_metrics()
    assert rows[-1]["env_steps"] >= 240 and rows[-1]["updates"] > 0
    for key in (
        "approx_kl",
        "clip_fraction",
        "explained_variance",
        "entropy",
        "lr",
        "loss_critic",
        "loss_policy",
        "robot_p_min",
        "robot_p_max",
        "update_s",
    ):
        assert any(key in r for r in rows), key
    assert any(k.startswith("train_return/") for r in rows for k in r)
    resolved = run.load_recipe().resolved
    assert resolved["frames_per_batch"] == 80 and resolved["iterations"] == 3
    evals = sorted((run.path / "eval").glob("step*.json"))
    assert evals and json.loads(evals[-1].read_text())["deterministic"] is False
    # ModuMorph's protocol on the trained run: sampled actions, frozen statistics, CI over robots
    out_path = tmp_path / "eval.json"
    assert (
        gcnt(
            [
                "eval",
                str(run.path),
                "--robots",
                "train",
                "--stochastic",
                "--episodes",
                "2",
                "--json",
                str(out_path),
            ]
        )
        == 0
    )
    # the interval over robots: a bootstrap CI from 5 robots, below that their range, named so
    printed = capsys.readouterr().out
    assert "95% CI [" in printed or "range [" in printed
    out = json.loads(out_path.read_text())
    assert out["deterministic"] is False
    over = out["over_robots"]  # the fields named for the interval printed
    interval = ("ci95_low", "ci95_high") if "95% CI [" in printed else ("range_low", "range_high")
    assert {"mean", *interval} <= set(over)


def test_kl_stop_is_checked_before_each_step_and_skips_the_rest_of_the_iteration(tmp_path):
    recipe = tiny_recipe(tmp_path, kl_stop={"default": 0.5, "gcnt": 0.05})
    prep = prepare(recipe)
    algo = prep.algo
    assert algo.learner.kl_stop == 0.05  # the method's own threshold
    data = rollout(prep)
    # 2 epochs x 2 mini-batches; the 3rd mini-batch (epoch 1, step 0) reports a KL over 0.05
    kls = iter([0.0, 0.01, 0.2, 0.0])
    real = algo.learner.loss_forward

    def scripted(batch):
        out = real(batch)
        out.set("kl_approx", torch.tensor(next(kls)))
        return out

    algo.learner.loss_forward = scripted
    before = {k: v.clone() for k, v in algo.learner.actor.state_dict().items()}
    losses = list(algo.learner.learn(data))
    assert len(losses) == 2 and algo.learner.updates == 2  # no step on the 3rd, no 4th
    assert algo.learner.stopped_at == (1, 0)
    assert algo.learner.iteration == 1
    after = algo.learner.actor.state_dict()
    assert any(
        not torch.equal(before[k], after[k]) for k in before if before[k].is_floating_point()
    )
    prep.env.close()


def test_compile_switches_for_ppo(tmp_path):
    """compile.compile compiles PPO's loss forward; CUDA graphs are refused with the reason (the
    KL early stop decides between forward and optimiser step)."""
    d = tiny_recipe(tmp_path).to_dict()
    recipe = recipe_from_dict({**d, "compile": {"compile": True}})
    prep = prepare(recipe)
    learner = prep.algo.learner
    assert learner.loss_forward is not learner.loss  # a torch.compile wrapper around it
    prep.env.close()
    eager = prepare(tiny_recipe(tmp_path / "eager"))
    assert eager.algo.learner.loss_forward is eager.algo.learner.loss
    eager.env.close()
    with pytest.raises(ValueError, match=r"compile.cudagraphs=true is for TD3.*ppo.kl_stop"):
        recipe_from_dict({**d, "compile": {"cudagraphs": True}})


def test_lr_schedule_warms_up_then_follows_the_cosine():
    c = PPOConfig()
    total = 100
    assert lr_factor(0, total, c) == pytest.approx(0.1)
    for it in range(1, 5):
        warm = 0.1 + 0.9 * it / 5
        assert lr_factor(it, total, c) == pytest.approx(
            warm * 0.5 * (1 + math.cos(math.pi * it / total))
        )
    for it in (5, 50, 99):
        assert lr_factor(it, total, c) == pytest.approx(0.5 * (1 + math.cos(math.pi * it / total)))
    assert lr_factor(total, total, c) == pytest.approx(0.0)
    assert lr_factor(3, total, PPOConfig(lr_schedule="constant", warmup_iterations=0)) == 1.0


def test_slot_env_changes_robot_at_reset_and_matches_a_fresh_env():
    pool = resolve_robots(["Hopper++:train"]) + resolve_robots(["walker_2_main"])
    k = max(r.num_limbs for r in pool)
    env = SMPEnv([pool[0], pool[1]], max_limbs=k, seed=0, num_threads=1)
    order = iter([[3, 2], [1], [0, 3]])
    env.use_robot_pool(pool, lambda rows: np.array(next(order)[: len(rows)]))
    assert env.table.batch_size[0] == len(pool)
    td = env.reset()
    assert td["morph_id"].tolist() == [3, 2] and [r.name for r in env.robots] == [
        pool[3].name,
        pool[2].name,
    ]
    env.reset(td.clone().set("_reset", torch.tensor([[False], [True]])))
    td = env.observe()
    assert td["morph_id"].tolist() == [3, 1]
    assert torch.equal(td["limbs", "mask"][1], env.table["limbs", "mask"][1])
    # the observation of a reassigned slot is the robot's own
    model, data = env.sim(1)
    ref = SMPEnv([pool[1]], max_limbs=k, seed=0, num_threads=1)
    ref.reset()
    ref.set_state(0, data.qpos.copy(), data.qvel.copy())
    env.set_state(1, data.qpos.copy(), data.qvel.copy())
    assert torch.equal(ref.observe()["limbs", "obs"][0], env.observe()["limbs", "obs"][1])
    out = env.step(td.update(env.full_action_spec.rand()))
    assert out["next", "morph_id"].tolist() == [3, 1]
    with pytest.raises(ValueError, match="pool index"):
        env._reassign(np.array([0]), np.array([9]))


def test_timeouts_bootstrap_in_the_advantage_by_hand():
    """r + gamma V(s') at a truncation, r alone at a termination, traces cut at both."""
    c = PPOConfig(gamma=0.9, gae_lambda=0.8)
    critic = TensorDictModule(
        lambda x: x.sum(-1, keepdim=True), in_keys=["x"], out_keys=["state_value"]
    )
    t_len = 5
    x = torch.arange(t_len, dtype=torch.float64).reshape(1, t_len, 1) + 1.0
    # next obs = the following obs, except at the episode ends (t = 1 timeout, t = 3 fall),
    # where the env restarted: the next row is a fresh start
    nxt = torch.tensor([2.0, 30.0, 4.0, 50.0, 60.0], dtype=torch.float64).reshape(1, t_len, 1)
    reward = torch.tensor([1.0, 2.0, 3.0, 4.0, 5.0], dtype=torch.float64).reshape(1, t_len, 1)
    trunc = torch.tensor([False, True, False, False, False]).reshape(1, t_len, 1)
    term = torch.tensor([False, False, False, True, False]).reshape(1, t_len, 1)
    td = TensorDict(
        {
            "x": x,
            "next": {
                "x": nxt,
                "reward": reward,
                "terminated": term,
                "truncated": trunc,
                "done": term | trunc,
            },
        },
        [1, t_len],
    )
    make_gae(c, critic)(td)
    v, v1 = x.squeeze().tolist(), nxt.squeeze().tolist()
    r, g, lam = reward.squeeze().tolist(), 0.9, 0.8
    delta = [r[t] + (0.0 if term[0, t, 0] else g * v1[t]) - v[t] for t in range(t_len)]
    adv = [0.0] * t_len
    for t in reversed(range(t_len)):
        cut = bool(term[0, t, 0] or trunc[0, t, 0]) or t == t_len - 1
        adv[t] = delta[t] + (0.0 if cut else g * lam * adv[t + 1])
    got = td["advantage"].squeeze().double()
    assert torch.allclose(got, torch.tensor(adv, dtype=torch.float64), rtol=1e-6)
    assert adv[1] == pytest.approx(2.0 + 0.9 * 30.0 - 2.0)  # the timeout bootstraps with V(s')
    assert adv[3] == 0.0  # the fall does not
    assert torch.allclose(td["value_target"].double(), got.reshape(x.shape) + x, rtol=1e-6)


def test_checkpointed_state_continues_exactly_and_freezes_obs_stats_for_eval(tmp_path):
    recipe = tiny_recipe(tmp_path / "a")
    a = prepare(recipe)
    data1 = rollout(a)
    list(a.algo.process(data1, 80))
    state = a.algo.state_dict()
    path = tmp_path / "state.pt"
    torch.save(plain_state(state), path)  # as a checkpoint stores it: no NumPy objects
    b = prepare(tiny_recipe(tmp_path / "b"))
    b.algo.load_state_dict(torch.load(path, weights_only=True))
    assert b.algo.learner.iteration == 1 and b.algo.learner.lr_now() == a.algo.learner.lr_now()
    # fresh episodes (a rollout starts with a reset), as after a resume, collected by a policy
    # that leaves the statistics alone, so that both learners start the iteration equal
    frozen = NormalizedPolicy(a.algo.learner.obs_norm, a.algo.learner.actor)
    data2 = rollout(a, policy=frozen)
    a.algo.scaler.ret[:] = 0.0  # episode lengths restart with the env (StepCounter)
    for algo in (a.algo, b.algo):
        torch.manual_seed(5)
        list(algo.process(data2.clone(), 160))
    for (k, va), vb in zip(
        a.algo.learner.actor.state_dict().items(),
        b.algo.learner.actor.state_dict().values(),
        strict=True,
    ):
        assert torch.equal(va, vb), k
    assert torch.equal(a.algo.learner.obs_norm.mean, b.algo.learner.obs_norm.mean)
    assert np.array_equal(np.asarray(a.algo.sampler.probs), np.asarray(b.algo.sampler.probs))
    # evaluation rebuilds the normalised policy from policy_state, statistics frozen
    norm = a.algo.learner.obs_norm
    assert not torch.equal(norm.mean, torch.zeros_like(norm.mean))
    pol = PPO.eval_policy(recipe, a.algo.policy_state(), a.env, deterministic=True)
    assert isinstance(pol, NormalizedPolicy) and torch.equal(pol.norm.mean, norm.mean)
    td = a.env.reset()
    mean_before = pol.norm.mean.clone()
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        act = pol(td.clone())["limbs", "action"]
        sub = td.clone()
        sub["limbs", "obs"] = norm(td["limbs", "obs"], td["limbs", "mask"])
        ref = a.algo.learner.actor(sub)["limbs", "action"]
    assert torch.equal(act, ref) and torch.equal(pol.norm.mean, mean_before)
    for p in (a, b):
        p.env.close()


ROOT = Path(__file__).parents[1]
PPO_RECIPES = sorted(
    p
    for p in (ROOT / "recipes").rglob("*.yaml")
    if not p.name.startswith("_") and load_recipe(p).algo == "ppo"  # TD3: tests/test_td3.py
)


@pytest.mark.parametrize("path", PPO_RECIPES, ids=lambda p: str(p.relative_to(ROOT / "recipes")))
def test_every_ppo_recipe_trains_a_few_steps(path, tmp_path):
    """Each PPO recipe (its world, height map and method) on two robots (SR: one, since its MLP
    is one network per robot), a few steps."""
    from gcnt.morphology.catalogues import resolve_robots
    from gcnt.morphology.unimal.imported import DEFAULT_NAME
    from gcnt.rl.loop import train

    own = load_recipe(path)
    if any(str(spec).startswith(f"{DEFAULT_NAME}:") for spec in own.env.robots):
        # the paper's robots cannot ship: tests/test_unimal_import.py builds this recipe's env
        # from an imported set it makes
        pytest.skip(f"{path.name} trains the imported {DEFAULT_NAME} robots")
    single = own.network.name == "sr"
    names = [r.name for r in resolve_robots(own.env.robots)][: 1 if single else 2]
    recipe = load_recipe(
        path,
        [
            f"run_dir={tmp_path / 'run'}",
            f"env.robots=[{', '.join(names)}]",
            "env.test_robots=[]",
            "env.max_episode_steps=8",
            "env.num_threads=1",
            "ppo.num_envs=2",
            "ppo.steps_per_env=6",
            "ppo.minibatch_size=6",
            "ppo.epochs=1",
            "collector.total_frames=24",
            "logger.backend=none",
            "logger.progress=false",
            "logger.log_interval=12",
            "eval.episodes=1",
            f"eval.robots=[{names[0]}]",
            "checkpoint_interval=12",
            *([] if single else ["network.kwargs={d_model: 16, layers: 1, ff: 16, heads: 2}"]),
        ],
    )
    run = RunDir(recipe.run_dir)
    run.create(recipe)
    train(recipe, run)
    rows = run.read_metrics()
    assert rows[-1]["env_steps"] >= 24 and rows[-1]["updates"] > 0
    assert list((run.path / "eval").glob("step*.json"))


def test_kl_thresholds_per_method_and_world_follow_table_5():
    expect = {
        "ft": (0.05, 0.05, 0.05),
        "incline": (0.03, 0.05, 0.05),
        "mt": (0.03, 0.03, 0.03),
        "obstacles": (0.03, 0.03, 0.03),
    }
    for world, values in expect.items():
        for method, kl in zip(("metamorph_star", "modumorph", "gcnt"), values, strict=True):
            r = load_recipe(ROOT / f"recipes/unimal/{world}.yaml", [f"network.name={method}"])
            assert r.ppo.kl_threshold(method) == kl, (world, method)
            assert r.env.world == world and r.env.benchmark == "unimal"


def test_the_python_api_shows_progress_and_keeps_torchrl_info_out(tmp_path):
    """``train()`` called from Python with no logging set up (a notebook, a script) shows its
    progress and final evaluation on stderr; torchrl's info lines (a storage initialised) do
    not reach stdout or stderr."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        f"sys.path.insert(0, {str(Path(__file__).parent)!r})\n"
        "import gcnt\n"
        "from test_ppo import tiny_recipe\n"
        "from gcnt.rl.loop import train\n"
        "from gcnt.run.directory import RunDir\n"
        f"recipe = tiny_recipe({str(tmp_path / 'run')!r})\n"
        "run = RunDir(recipe.run_dir)\n"
        "run.create(recipe)\n"
        "train(recipe, run)\n"
    )
    env = {k: v for k, v in __import__("os").environ.items() if k != "RL_LOGGING_LEVEL"}
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert "[torchrl]" not in done.stdout + done.stderr
    assert "env_steps 80" in done.stderr and "finished" in done.stderr
    assert "final evaluation hopper_3 (training robot):" in done.stderr
    assert "nan" not in done.stderr  # no spread of one episode


@pytest.mark.parametrize("world", ["ft", "incline", "mt", "obstacles"])
def test_metamorph_runs_as_its_authors_ran_it(world):
    """MetaMorph's code stops at KL_TARGET_COEF 20 x 0.01 and never leaves training mode (its
    embedding dropout is on while collecting); the other methods keep the paper's table 5."""
    root = Path(__file__).parents[1] / "recipes" / "unimal"
    ppo = load_recipe(root / f"{world}.yaml", ["network.name=metamorph"]).algo_config
    assert ppo.kl_threshold("metamorph") == 0.2 and ppo.dropout_while_collecting("metamorph")
    for other in ("gcnt", "gcnt_hn", "modumorph", "metamorph_star"):
        assert ppo.kl_threshold(other) in (0.05, 0.03)
        assert not ppo.dropout_while_collecting(other)


def test_collect_dropout_keeps_the_network_in_training_mode(tmp_path):
    net = {"name": "metamorph", "kwargs": TINY_NET}
    for on in (True, False):
        d = tiny_recipe(tmp_path / str(on), benchmark="unimal").to_dict()
        recipe = recipe_from_dict({**d, "network": net, "ppo": {**d["ppo"], "collect_dropout": on}})
        prep = prepare(recipe)
        learner = prep.algo.learner
        assert learner.actor.training is on and learner.critic.training is on
        list(learner.learn(rollout(prep)))
        assert learner.actor.training is on and learner.critic.training is on
        prep.env.close()
    with pytest.raises(ValueError, match="collect_dropout.metamorph: expected true or false"):
        recipe_from_dict(
            {**d, "ppo": {**d["ppo"], "collect_dropout": {"default": False, "metamorph": 1}}}
        )


def test_observations_are_normalised_from_the_reset_on(tmp_path):
    """As ``VecNormalize`` does: every observation the collector gives the policy, from the
    reset on, joins the statistics before it is normalised, so iteration 0 is normalised too;
    the update reuses what the policy acted on."""
    from gcnt.rl.loop import make_collector
    from gcnt.rl.ppo.learner import SEEN_OBS
    from gcnt.rl.ppo.normalize import merge_moments

    recipe = tiny_recipe(tmp_path, benchmark="unimal")
    prep = prepare(recipe)
    algo = prep.algo
    norm = algo.learner.obs_norm
    collector = make_collector(recipe, prep.env, algo.collect_settings(0))
    data = next(iter(collector)).reshape(4, -1)
    collector.shutdown()
    obs, mask = data.get(("limbs", "obs")), data.get(("limbs", "mask"))
    m = mask.unsqueeze(-1).double()
    assert torch.equal(norm.count, 1e-4 + m.sum((0, 1)))  # every step, nothing else
    # step 0: the reset observations alone make the statistics that normalise them
    x0, m0 = obs[:, 0].double(), m[:, 0]
    n0 = m0.sum(0)
    b_mean = (x0 * m0).sum(0) / n0
    b_var = ((x0 - b_mean) ** 2 * m0).sum(0) / n0
    mean0, var0, _ = merge_moments(0.0, 1.0, 1e-4, b_mean, b_var, n0)  # the prior count 1e-4
    seen = data.get(SEEN_OBS).double()
    ref0 = ((x0 - mean0) / (var0 + 1e-8).sqrt()).clamp(-10, 10) * m0
    np.testing.assert_allclose(seen[:, 0], ref0, atol=1e-5)
    # the update's observations are those the policy acted on; a next observation is the
    # following step's unless the episode ended there
    batch = algo.learner.normalized(data)
    assert torch.equal(batch.get(OBS_KEY), data.get(SEEN_OBS))
    done = data.get(("next", "done")).squeeze(-1)
    nxt = batch.get(("next", *OBS_KEY))
    for n, t in zip(*torch.nonzero(~done[:, :-1], as_tuple=True), strict=True):
        assert torch.equal(nxt[n, t], seen[n, t + 1])
    prep.env.close()
