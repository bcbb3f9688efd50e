"""Several seeds in one process: the stacked update equals the seeds' own updates (float64), the
per-seed clip and random streams, `gcnt train --seeds` end to end, and its bad input."""

import copy
import json
from pathlib import Path

import pytest
import torch
from cli_helpers import holding

from gcnt.cli import main as gcnt
from gcnt.keys import ACTION
from gcnt.recipes import load_recipe
from gcnt.rl.factories import make_env, train_robots
from gcnt.rl.td3 import replay as rb
from gcnt.rl.td3.learner import TD3Learner
from gcnt.rl.td3.loss import target_noise
from gcnt.rl.td3.stacked import SeedRNG, StackedTD3Learner, clip_grad_norm_per_seed

ROOT = Path(__file__).parents[1]
QUICK = ROOT / "recipes/quickstart.yaml"
NET = "network.kwargs={d_model: 16, layers: 1, ff: 16, heads: 2}"
TINY = [
    NET,
    "env.max_episode_steps=15",
    "td3.init_random_frames=30",
    "td3.steps_per_batch=5",
    "td3.batch_size=8",
    "td3.updates_per_step=0.5",
    "td3.max_grad_norm=0.1",
    "logger.backend=none",
    "logger.progress=false",
    "logger.log_interval=15",
    "checkpoint_interval=45",
    "eval.episodes=1",
    "collector.total_frames=90",
]


def _double(batch):
    return batch.apply(lambda t: t.double() if t.is_floating_point() else t)


def _learners(seeds, overrides=()):
    """One float64 learner per seed (as each seed's run builds it), and a replay to sample."""
    recipe = load_recipe(QUICK, [NET, *overrides])
    env = make_env(recipe, train_robots(recipe))
    data = env.rollout(10, break_when_any_done=False)
    learners = []
    for seed in seeds:
        torch.manual_seed(seed)
        learner = TD3Learner(recipe, env)
        for m in (learner.actor, learner.critics, learner.target_actor, learner.target_critics):
            m.double()
        learners.append(learner)
    env.close()
    replay = rb.RobotReplay(3, capacity=30, batch_size=6)
    replay.extend(data)
    return recipe, learners, replay


def _state(learner):
    return {
        "params": [p.detach().clone() for p in [*learner._online, *learner._target]],
        "adam": [
            {k: v.clone() for k, v in opt.state[p].items()}
            for opt, params in (
                (learner.actor_opt, learner.actor_params),
                (learner.critic_opt, learner.critic_params),
            )
            for p in params
            if p in opt.state
        ],
        "updates": learner.updates,
    }


#: absolute tolerance of the float64 comparisons. The attention's key bias has an analytically
#: zero gradient (adding a constant to every key's logit of a query leaves the softmax as it is),
#: so its float64 gradient is rounding noise (~1e-17) and Adam moves it by about
#: lr · noise / eps ~ 1e-13 from its zero start, differently in a vmapped and a plain update;
#: every other tensor is O(0.01–1) and is held to the relative tolerance.
ATOL = 1e-11


def _assert_same_state(a, b):
    assert a["updates"] == b["updates"]
    assert len(a["params"]) == len(b["params"]) and len(a["adam"]) == len(b["adam"])
    for x, y in zip(a["params"], b["params"], strict=True):
        torch.testing.assert_close(x, y, rtol=1e-11, atol=ATOL)
    for sx, sy in zip(a["adam"], b["adam"], strict=True):
        for k in sx:
            torch.testing.assert_close(sx[k], sy[k], rtol=1e-11, atol=ATOL, msg=k)


@pytest.mark.parametrize("clip", [0.0, 0.1])
def test_stacked_updates_equal_each_seeds_own_updates_float64(clip, monkeypatch):
    import gcnt.rl.td3.learner as td3_module

    seeds = [0, 1, 2]
    _, learners, replay = _learners(seeds, [f"td3.max_grad_norm={clip}", "td3.policy_delay=2"])
    alone = [copy.deepcopy(lr) for lr in learners]  # the same seeds, updated one by one
    stacked = StackedTD3Learner(learners)
    torch.manual_seed(7)
    for _ in range(6):  # critic, critic+actor+targets, ... with Adam states building up
        batches = [_double(replay.sample_mixed()) for _ in seeds]
        noises = [target_noise(b.get(ACTION), 0.2, 0.5) for b in batches]
        out = stacked.step(stacked.stack_batches(batches, noises))
        for i, learner in enumerate(alone):
            monkeypatch.setattr(td3_module, "target_noise", lambda *a, n=noises[i]: n)
            own = learner.step(batches[i])
            assert sorted(own) == sorted(out)
            for k, v in own.items():
                torch.testing.assert_close(out[k][i], v, rtol=1e-12, atol=1e-13, msg=k)
    assert "loss_actor" in out
    stacked.push()
    for learner, own in zip(learners, alone, strict=True):
        _assert_same_state(_state(learner), _state(own))
        # the seed's modules (collector policy, checkpoints) hold the updated weights
        for p, q in zip(learner.actor.parameters(), own.actor.parameters(), strict=True):
            torch.testing.assert_close(p, q, rtol=1e-11, atol=ATOL)


def test_a_stack_pulled_from_pushed_seeds_continues_alike():
    """What resuming does: seeds' states (here pushed by one stack) pulled into a new stack."""
    _, learners, replay = _learners([3, 4])
    first = StackedTD3Learner(learners)
    batches = [_double(replay.sample_mixed()) for _ in range(2)]
    noises = [torch.zeros_like(b.get(ACTION)) for b in batches]
    batch = first.stack_batches(batches, noises)
    for _ in range(2):
        first.step(batch)
    first.push()
    second = StackedTD3Learner(learners)
    assert second.updates == 2
    for _ in range(2):  # a critic step, then a critic + actor step
        a, b = first.step(batch), second.step(batch)
        assert sorted(a) == sorted(b)
        for k in a:
            torch.testing.assert_close(a[k], b[k], rtol=1e-12, atol=1e-13, msg=k)
    assert "loss_actor" in a
    for x, y in zip(first._online_leaves, second._online_leaves, strict=True):
        torch.testing.assert_close(x, y, rtol=1e-12, atol=1e-13)


def test_gradient_clip_is_per_seed():
    torch.manual_seed(0)
    params = [torch.nn.Parameter(torch.zeros(3, 4, 5)), torch.nn.Parameter(torch.zeros(3, 2))]
    grads = [torch.randn_like(p) for p in params]
    for g in grads:
        g[0] *= 1e-3  # seed 0 below the clip, seeds 1 and 2 above it
        g[2] *= 10
    for p, g in zip(params, grads, strict=True):
        p.grad = g.clone()
    norms = clip_grad_norm_per_seed(params, 0.5)
    for s in range(3):
        own = [torch.nn.Parameter(torch.zeros_like(p[s])) for p in params]
        for p, g in zip(own, grads, strict=True):
            p.grad = g[s].clone()
        norm = torch.nn.utils.clip_grad_norm_(own, 0.5)
        torch.testing.assert_close(norms[s], norm)
        for p, q in zip(params, own, strict=True):
            torch.testing.assert_close(p.grad[s], q.grad)
    assert norms[0] < 0.5 < norms[1] < norms[2]
    torch.testing.assert_close(params[1].grad[0], grads[1][0])  # seed 0 untouched


def test_each_seed_keeps_its_own_random_stream():
    torch.manual_seed(0)
    want0 = torch.rand(4)
    torch.manual_seed(1)
    want1 = torch.rand(4)
    rng = SeedRNG(2)
    torch.manual_seed(0)
    rng.capture(0)
    torch.manual_seed(1)
    rng.capture(1)
    torch.manual_seed(9)
    outside = torch.get_rng_state()
    got = [[], []]
    for _ in range(2):  # interleaved, two draws per turn
        for i in (0, 1):
            with rng.active(i):
                got[i].append(torch.rand(2))
    torch.testing.assert_close(torch.cat(got[0]), want0, rtol=0, atol=0)
    torch.testing.assert_close(torch.cat(got[1]), want1, rtol=0, atol=0)
    assert torch.equal(torch.get_rng_state(), outside)


def test_train_two_seeds_stacked_matches_each_seed_trained_alone(tmp_path, capsys):
    """`gcnt train --seeds 0,1`: two ordinary run directories; seed 1's run matches
    `gcnt train seed=1` (float32: the same numbers up to rounding)."""
    assert gcnt(["train", str(QUICK), *TINY, f"run_dir={tmp_path / 'both'}", "--seeds", "0,1"]) == 0
    out = capsys.readouterr().out
    for seed in (0, 1):
        run = tmp_path / "both" / f"seed{seed}"
        assert f"run directory: {run}" in out
        assert (run / "checkpoints/last.pt").exists() and (run / "eval/step90.json").exists()
        state = torch.load(run / "checkpoints/last.pt", weights_only=True)
        assert state["env_steps"] == 90 and state["learner"]["updates"] == 10
        assert load_recipe(run / "recipe.yaml").seed == seed
    assert gcnt(["train", str(QUICK), *TINY, f"run_dir={tmp_path / 'alone'}", "seed=1"]) == 0

    def rows(path):
        return [json.loads(line) for line in path.read_text().splitlines()]

    stacked, alone = (
        rows(tmp_path / "both/seed1/metrics.jsonl"),
        rows(tmp_path / "alone/metrics.jsonl"),
    )
    assert [r["env_steps"] for r in stacked] == [r["env_steps"] for r in alone]
    assert [r["updates"] for r in stacked] == [r["updates"] for r in alone]
    # float32 runs: the vmapped kernels round differently from the single-seed ones, and returns
    # go through contact physics; exactness is the float64 tests' job, this checks the wiring
    for a, b in zip(stacked, alone, strict=True):
        for k in a:
            if k.startswith(("loss", "train_return")):
                assert a[k] == pytest.approx(b[k], rel=2e-2, abs=1e-3), (a["env_steps"], k)
    seed0 = rows(tmp_path / "both/seed0/metrics.jsonl")
    assert seed0[-1]["loss_critic"] != stacked[-1]["loss_critic"]  # seeds differ


@pytest.mark.parametrize(
    "args, message",
    [
        (["--seeds", "0,1,0"], "--seeds '0,1,0': seed 0 is given twice"),
        (["--seeds", "0,x"], "--seeds '0,x': expected comma-separated integers"),
        (["td3.schedule=paper", "--seeds", "0,1"], "--seeds needs td3.schedule=mixed"),
        (["algo=ppo", "--seeds", "0,1"], "--seeds trains TD3 recipes"),
        (["--resume", "somewhere", "--seeds", "0,1"], "--seeds starts new runs"),
        (["network.name=metamorph", "--seeds", "0,1"], "dropout"),
    ],
)
def test_bad_seed_input_fails_in_one_line(args, message, tmp_path, capsys):
    assert gcnt(["train", str(QUICK), *TINY, f"run_dir={tmp_path}", *args]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and "\n" not in err
    assert not any(tmp_path.iterdir())  # nothing written


def test_a_refused_start_of_seeds_leaves_no_directory(tmp_path, capsys):
    """A seed whose directory is trained by another process, or already holds a run: refused in
    one line, and the other seeds' directories are not left behind holding only a lock."""
    busy = tmp_path / "seed1"
    with holding("gcnt.run.lock:run_lock", busy):
        assert gcnt(["train", str(QUICK), *TINY, f"run_dir={tmp_path}", "--seeds", "0,1"]) == 2
        assert "is being trained by" in capsys.readouterr().err
        assert sorted(p.name for p in tmp_path.iterdir()) == ["seed1"]
    (busy / "recipe.yaml").write_text(QUICK.read_text())  # a run there: refused up front
    assert gcnt(["train", str(QUICK), *TINY, f"run_dir={tmp_path}", "--seeds", "0,1"]) == 2
    assert "already holds a run" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seed1"]
