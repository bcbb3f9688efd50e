"""``compile.compile``: every TD3 method's update compiles without a graph break and makes the
eager update, on the CPU.

The losses are compiled with ``fullgraph=True`` (a graph break is an error). Here the graphs go
through torch's ``aot_eager`` backend: dynamo's capture and AOTAutograd's forward and backward
graphs, the whole of what ``compile.compile`` traces, without inductor's code generation (minutes
on a small CPU); float64, so the compiled update must give eager's numbers to rounding.
Inductor itself is checked by tests/test_accelerate.py. Tracing takes 20-60 s per method on a
2-core CPU (4 minutes for stacked seeds, by load), so ``make test`` runs GCNT's case and the rest
runs when asked: ``GCNT_TEST_COMPILE=1 pytest tests/test_compile_fullgraph.py`` (every method,
both schedules, stacked seeds).
"""

import functools
import logging
import os
from pathlib import Path

import pytest
import torch
from tensordict import TensorDict

from gcnt.keys import ACTION
from gcnt.recipes import load_recipe
from gcnt.rl.accelerate import inductor_cache_dir
from gcnt.rl.factories import make_env, train_robots
from gcnt.rl.td3 import replay as rb
from gcnt.rl.td3.learner import TD3Learner
from gcnt.rl.td3.loss import target_noise
from gcnt.rl.td3.stacked import StackedTD3Learner

QUICK = Path(__file__).parents[1] / "recipes/quickstart.yaml"
NET = "network.kwargs={d_model: 8, layers: 1, ff: 8, heads: 2}"
SMALL = {
    "smp": "network.kwargs={msg_dim: 4, hidden: 8, head_hidden: [8]}",
    "mlp": "network.kwargs={hidden: [8]}",
}


@pytest.fixture
def aot_eager(monkeypatch):
    """torch.compile with the aot_eager backend; dynamo's state reset before and after."""
    monkeypatch.setattr(torch, "compile", functools.partial(torch.compile, backend="aot_eager"))
    torch._dynamo.reset()
    yield
    torch._dynamo.reset()


def _learners(method, schedule, seeds=(0,)):
    """Float64 learners per seed, eager and compiled from the same weights, and a batch."""
    one = ["env.robots=[hopper_5]"] if method == "mlp" else []
    over = [
        SMALL.get(method, NET),
        f"network.name={method}",
        f"td3.schedule={schedule}",
        "td3.policy_delay=1",
        "td3.max_grad_norm=1.0",
        "compile.twin_threads=false",
        *one,
    ]
    recipe = load_recipe(QUICK, over)
    compiled = load_recipe(QUICK, [*over, "compile.compile=true"])
    robots = train_robots(recipe)
    env = make_env(recipe, robots)
    data = env.rollout(6, break_when_any_done=False)
    pairs = []
    for seed in seeds:
        torch.manual_seed(seed)
        eager = TD3Learner(recipe, env)
        torch.manual_seed(seed)
        fast = TD3Learner(compiled, env)
        for learner in (eager, fast):
            for m in (learner.actor, learner.critics, learner.target_actor, learner.target_critics):
                m.double()
        pairs.append((eager, fast))
    env.close()
    replay = rb.RobotReplay(len(robots), capacity=20, batch_size=4)
    replay.extend(data)
    batch = replay.sample_mixed() if schedule == "mixed" else replay.sample_robot(0)
    return pairs, batch.apply(lambda t: t.double() if t.is_floating_point() else t)


def _weights(learner):
    return [p.detach().clone() for p in [*learner._online, *learner._target]]


def _same(a, b):
    for x, y in zip(a, b, strict=True):
        torch.testing.assert_close(x, y, rtol=1e-9, atol=1e-12)


#: the cases only run when asked (GCNT_TEST_COMPILE=1): minutes each on a small CPU
asked = pytest.mark.skipif(
    os.environ.get("GCNT_TEST_COMPILE") != "1",
    reason="tracing every method takes minutes on a CPU; set GCNT_TEST_COMPILE=1 to run",
)
METHODS = [
    ("gcnt", "mixed"),
    pytest.param("gcnt", "paper", marks=asked),
    pytest.param("gcnt_no_gcn", "mixed", marks=asked),
    pytest.param("gcnt_no_wl", "mixed", marks=asked),
    pytest.param("gcnt_no_dist", "mixed", marks=asked),
    pytest.param("gcnt_dist_first", "mixed", marks=asked),
    pytest.param("amorpheus", "mixed", marks=asked),
    pytest.param("swat", "paper", marks=asked),
    pytest.param("smp", "mixed", marks=asked),
    pytest.param("mlp", "paper", marks=asked),
]


@pytest.mark.slow
@pytest.mark.parametrize(("method", "schedule"), METHODS)
def test_each_td3_method_compiles_without_a_graph_break_and_updates_as_eager(
    method, schedule, aot_eager
):
    [(eager, fast)], batch = _learners(method, schedule)
    assert fast.critic_forward is not fast._critic_forward  # compiled (fullgraph)
    for _ in range(2):  # Adam's moments built up: the second step reads them
        torch.manual_seed(3)
        a = eager.step(batch)
        torch.manual_seed(3)
        b = fast.step(batch)
        assert a.keys() == b.keys() == {"loss_critic", "loss_actor"}
        for k in a:
            torch.testing.assert_close(b[k], a[k], rtol=1e-10, atol=1e-12)
    _same(_weights(fast), _weights(eager))
    counters = torch._dynamo.utils.counters
    assert not counters["graph_break"], dict(counters["graph_break"])


@pytest.mark.slow
@asked
def test_stacked_seeds_compile_without_a_graph_break_and_update_as_eager(aot_eager):
    pairs, batch = _learners("gcnt", "mixed", seeds=(0, 1))
    eager = StackedTD3Learner([e for e, _ in pairs])
    fast = StackedTD3Learner([f for _, f in pairs])
    torch.manual_seed(5)
    noises = [target_noise(batch.get(ACTION), 0.2, 0.5) for _ in pairs]
    stacked = eager.stack_batches([batch, batch], noises)
    for _ in range(2):
        a, b = eager.step(stacked.clone()), fast.step(stacked.clone())
        for k in a:
            torch.testing.assert_close(b[k], a[k], rtol=1e-10, atol=1e-12)
    _same(fast._online_leaves + fast._target_leaves, eager._online_leaves + eager._target_leaves)
    assert fast.critic_forward.compile_s is not None  # compiled, and timed


def test_compiled_code_is_cached_in_the_users_cache_folder(monkeypatch, tmp_path, caplog):
    monkeypatch.delenv("TORCHINDUCTOR_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    recipe = load_recipe(QUICK, ["compile.compile=true"])
    assert inductor_cache_dir(recipe.compile) == tmp_path / "xdg/gcnt/inductor"
    named = load_recipe(QUICK, ["compile.compile=true", f"compile.cache_dir={tmp_path / 'c'}"])
    assert inductor_cache_dir(named.compile) == tmp_path / "c"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert inductor_cache_dir(recipe.compile) == tmp_path / "home/.cache/gcnt/inductor"
    # importing torch._dynamo writes inductor's /tmp default into the variable: not the user's
    from torch._inductor.runtime.cache_dir_utils import default_cache_dir

    monkeypatch.setenv("TORCHINDUCTOR_CACHE_DIR", default_cache_dir())
    assert inductor_cache_dir(recipe.compile) == tmp_path / "home/.cache/gcnt/inductor"
    monkeypatch.setenv("TORCHINDUCTOR_CACHE_DIR", str(tmp_path / "mine"))
    assert inductor_cache_dir(recipe.compile) == tmp_path / "mine"

    # compiling sets it for inductor (which would otherwise use /tmp/torchinductor_<user>),
    # and the first call's time is logged
    from gcnt.rl.accelerate import compile_step

    monkeypatch.setattr(torch, "compile", lambda fn, **kw: fn)
    step = compile_step(lambda x: x + 1, named.compile, fullgraph=True, name="toy")
    from torch._inductor.runtime.cache_dir_utils import cache_dir

    assert Path(cache_dir()) == (tmp_path / "c").resolve()
    with caplog.at_level(logging.INFO, logger="gcnt.rl.accelerate"):
        step(torch.zeros(1))
    assert "toy compiled in" in caplog.text


def test_a_table_with_out_of_range_ids_is_refused_when_set_not_in_the_forward():
    """The GCN's limb-type bound and SWAT's traversal bound are read once per robot table (not
    in the compiled forward): a table past them is one ValueError naming the setting."""
    recipe = load_recipe(QUICK, [NET, "compile.twin_threads=false"])
    env = make_env(recipe, train_robots(recipe))
    learner = TD3Learner(recipe, env)
    env.close()
    lookup = learner.actor[0]
    table = TensorDict(
        {k: v.clone() for k, v in lookup.table().items()}, batch_size=[lookup.num_robots]
    )
    table["limbs", "type"][0, 0] = 10_000
    with pytest.raises(ValueError, match="num_limb_types"):
        lookup.set_table(table)
