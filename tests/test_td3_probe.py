"""TD3's probe (``td3.probe_interval``) and the episode lengths beside the returns: a short
paper-schedule run logs both, and the probe leaves training exactly as it was (it draws nothing
from torch's global random stream)."""

from pathlib import Path

import pytest
import torch

from gcnt.bench.common import train_quietly
from gcnt.recipes import load_recipe
from gcnt.rl.factories import train_robots
from gcnt.rl.td3.probe import PROBE_SEED, make_probe

ROOT = Path(__file__).parents[1]


def _recipe(*extra):
    return load_recipe(
        ROOT / "recipes/smpenv/hopper.yaml",
        [
            "network.kwargs={d_model: 16, layers: 1, ff: 16, heads: 2}",
            "env.robots=[hopper_3,hopper_4]",
            "td3.init_random_frames=100",
            "td3.random_counted=total",
            "td3.steps_per_batch=10",
            "td3.batch_size=8",
            "td3.buffer_size_per_robot=2000",
            "td3.probe_steps=20",
            "collector.total_frames=400",
            "compile.compile=false",
            *extra,
        ],
    )


@pytest.fixture(scope="module")
def runs():
    torch.manual_seed(0)
    plain = train_quietly(_recipe(), 100)
    torch.manual_seed(0)
    probed = train_quietly(_recipe("td3.probe_interval=200"), 100)
    return plain, probed


@pytest.mark.slow
def test_the_probe_is_logged_and_changes_nothing_of_training(runs):
    plain, probed = runs
    rows = [r for r in probed if "probe/q1_mean" in r]
    assert [r["env_steps"] // 200 for r in rows] == [1, 2]
    for r in rows:
        assert 0.0 <= r["probe/saturated"] <= 1.0 and r["probe/action_std"] >= 0.0
    assert not any("probe/q1_mean" in r for r in plain)
    strip = [
        {k: v for k, v in r.items() if not k.startswith("probe/") and "per_s" not in k}
        for r in probed
    ]
    assert strip == [{k: v for k, v in r.items() if "per_s" not in k} for r in plain]


@pytest.mark.slow
def test_episode_lengths_are_logged_beside_returns(runs):
    plain, _ = runs
    with_returns = [r for r in plain if "train_return/mean" in r]
    assert with_returns
    for r in with_returns:
        robots = [k.split("/", 1)[1] for k in r if k.startswith("train_return/")]
        for name in robots:
            assert r[f"train_length/{name}"] >= 1.0
        assert r["train_length/mean"] >= 1.0


def test_the_probe_is_the_same_transitions_for_every_run():
    recipe = _recipe()
    robots = train_robots(recipe)
    state = torch.get_rng_state()
    a = make_probe(recipe, robots, 15)
    assert torch.equal(torch.get_rng_state(), state)  # the global stream untouched
    torch.manual_seed(PROBE_SEED + 1)
    b = make_probe(recipe, robots, 15)
    assert a.numel() == 30 and torch.equal(a["limbs", "obs"], b["limbs", "obs"])
    assert torch.equal(a["limbs", "action"], b["limbs", "action"])
