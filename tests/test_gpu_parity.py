"""A TD3 step captured in a CUDA graph makes the eager step's updates: the same batches give the
same losses and weights to float32 rounding, for one seed (both schedules' batch layouts) and for
stacked seeds. A captured step replays its kernels only, so Python state read inside it (a
counter, a float, a branch) would be frozen at capture and part ways here. Runs on a GPU, or on
the emulated one (tests/cuda_emulation), whose replay re-executes exactly the captured ops."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from test_gpu import cases

from gcnt.keys import ACTION
from gcnt.recipes import load_recipe
from gcnt.rl.factories import make_env, train_robots
from gcnt.rl.td3 import replay as rb
from gcnt.rl.td3.learner import TD3Learner
from gcnt.rl.td3.loss import target_noise
from gcnt.rl.td3.stacked import StackedTD3Learner

pytestmark = [pytest.mark.gpu]

QUICK = Path(__file__).parents[1] / "recipes/quickstart.yaml"
SIZES = {
    "gcnt": "network.kwargs={d_model: 16, layers: 1, ff: 16, heads: 2}",
    "smp": "network.kwargs={msg_dim: 8, hidden: 12, head_hidden: [16]}",
}
GRAPHED = ["compile.cudagraphs=true", "compile.replay_on_device=true"]
#: updates per comparison: with compile.warmup=2 and td3.policy_delay=2, each step is called
#: eagerly, then captured, then replayed (the critic step 4 times, the actor step once)
UPDATES = 6
#: two robots of other sizes (the paper schedule alternates them)
ROBOTS = "env.robots=[hopper_3, hopper_5]"


def _recipe(method: str, *extra: str):
    # no target noise inside the single-seed step: the eager and graphed runs draw it from the
    # same generator in other orders (the stacked step takes its noise as an input instead)
    over = [f"network.name={method}", SIZES[method], ROBOTS, "device=cuda", "td3.policy_noise=0"]
    return load_recipe(QUICK, [*over, *extra])


def _replay(recipe, env) -> rb.RobotReplay:
    data = env.rollout(12, break_when_any_done=False)
    replay = rb.RobotReplay(env.batch_size[0], capacity=40, batch_size=6)
    replay.extend(data)
    return replay


def _close(a: torch.Tensor, b: torch.Tensor) -> bool:
    """Equal to float64 rounding: both runs make the same arithmetic (below), so anything more
    is the graph replaying something other than the eager step."""
    return torch.allclose(a.detach().cpu(), b.detach().cpu(), rtol=1e-9, atol=1e-12)


def _double(batch):
    return batch.apply(lambda t: t.double() if t.is_floating_point() else t)


def _same_adam(*opts: torch.optim.Optimizer) -> None:
    """The eager run's Adam made capturable, as the graphed run's: the float32 step count and
    bias corrections of capturable Adam would otherwise part the runs by 2e-9 per update, which
    Adam's first steps on a near-zero gradient (a ReLU unit that one run's rounding wakes) turn
    into a whole learning rate."""
    for opt in opts:
        for group in opt.param_groups:
            group.update(capturable=True, foreach=True, fused=False)


def _learners(method: str, env, n: int = 1, graphed: bool = False):
    recipe = _recipe(method, *(GRAPHED if graphed else []))
    out = []
    for seed in range(n):
        torch.manual_seed(seed)
        learner = TD3Learner(recipe, env)
        for m in (learner.actor, learner.critics, learner.target_actor, learner.target_critics):
            m.double()
        _same_adam(learner.actor_opt, learner.critic_opt)
        out.append(learner)
    return out


@pytest.mark.parametrize(
    ("method", "schedule"),
    # make test: GCNT in the mixed schedule; the rest with --gpu-matrix
    cases(["gcnt", "smp"], ["paper", "mixed"], subset=lambda m, s: (m, s) == ("gcnt", "mixed")),
)
def test_graphed_td3_steps_make_the_eager_updates(method, schedule):
    env = make_env(_recipe(method), train_robots(_recipe(method)))
    replay = _replay(_recipe(method), env)
    torch.manual_seed(3)
    n = replay.num_robots
    batches = [
        _double(replay.sample_robot(i % n) if schedule == "paper" else replay.sample_mixed())
        for i in range(UPDATES)
    ]
    (eager,) = _learners(method, env)
    (graphed,) = _learners(method, env, graphed=True)
    env.close()
    for i, batch in enumerate(batches):
        a, b = eager.step(batch), graphed.step(batch)
        assert a.keys() == b.keys()
        for k in a:
            assert _close(a[k], b[k]), (i, k, a[k], b[k])
    for name in ("actor", "critics", "target_actor", "target_critics"):
        ours, theirs = getattr(eager, name), getattr(graphed, name)
        for (key, p), q in zip(ours.named_parameters(), theirs.parameters(), strict=True):
            assert _close(p, q), (name, key, (p - q).abs().max())
    assert eager.updates == graphed.updates == UPDATES


@pytest.mark.parametrize("method", cases(["gcnt", "smp"], subset=lambda m: m == "gcnt"))
def test_graphed_stacked_td3_steps_make_the_eager_updates(method):
    recipe = _recipe(method)
    env = make_env(recipe, train_robots(recipe))
    replay = _replay(recipe, env)
    runs = {g: StackedTD3Learner(_learners(method, env, 2, g)) for g in (False, True)}
    _same_adam(runs[False].actor_opt, runs[False].critic_opt)
    env.close()
    o = runs[False].config
    torch.manual_seed(4)
    for i in range(UPDATES):
        batches = [_double(replay.sample_mixed()) for _ in range(2)]
        noises = [target_noise(b.get(ACTION), 0.2, o.noise_clip) for b in batches]
        out = {g: run.step(run.stack_batches(batches, noises)) for g, run in runs.items()}
        for k in out[False]:
            assert _close(out[False][k], out[True][k]), (i, k, out[False][k], out[True][k])
    for g in runs.values():
        g.push()
    names = [
        f"{role}.{n}"
        for role in ("actor", "critics")
        for n, _ in getattr(runs[False].learners[0], role).named_parameters()
    ]
    for a, b in zip(runs[False].learners, runs[True].learners, strict=True):
        for name, p, q in zip(names, a._online, b._online, strict=True):
            assert _close(p, q), (name, (p - q).abs().max(), p.grad)
