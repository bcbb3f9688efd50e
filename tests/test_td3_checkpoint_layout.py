"""A TD3 run written before the twin critics became one ensemble (``tests/data/td3_run_b52e8ec``:
a tiny run made by the code of commit b52e8ec, whose checkpoint holds the two critics' weights
as ``0.<name>``/``1.<name>`` and one Adam over both critics' 2P tensors) loads into the
ensemble, resumes and evaluates."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import torch

from gcnt.cli import main as gcnt
from gcnt.rl.factories import make_env, train_robots
from gcnt.rl.td3.learner import TD3Learner
from gcnt.run.directory import RunDir

FIXTURE = Path(__file__).parent / "data" / "td3_run_b52e8ec"


def test_the_older_learner_state_loads_into_the_ensemble():
    run = RunDir(FIXTURE)
    recipe = run.load_recipe()
    state = run.load_checkpoint()["learner"]
    assert any(k.startswith("1.") for k in state["critics"])  # the older layout indeed
    env = make_env(recipe, train_robots(recipe))
    learner = TD3Learner(recipe, env)
    env.close()
    learner.load_state_dict(state)
    assert learner.updates == state["updates"] > 0
    for key in ("critics", "target_critics"):
        for name, p in getattr(learner, key).named_parameters():
            inner = name.removeprefix("net.")
            for i in range(2):
                torch.testing.assert_close(p[i], state[key][f"{i}.{inner}"], rtol=0, atol=0)
    # Adam: critic 1's moments of each tensor, then critic 2's, stacked; one step count
    old = state["critic_opt"]
    n = len(learner.critic_params)
    assert len(old["param_groups"][0]["params"]) == 2 * n
    ids = old["param_groups"][0]["params"]
    for j, p in enumerate(learner.critic_params):
        mine = learner.critic_opt.state[p]
        for k in ("exp_avg", "exp_avg_sq"):
            want = torch.stack([old["state"][ids[j]][k], old["state"][ids[n + j]][k]])
            torch.testing.assert_close(mine[k], want, rtol=0, atol=0)
        assert float(mine["step"]) == float(old["state"][ids[j]]["step"])
    # and the new layout round-trips
    again = TD3Learner(recipe, make_env(recipe, train_robots(recipe)))
    again.load_state_dict(learner.state_dict())
    for a, b in zip(again.critic_params, learner.critic_params, strict=True):
        assert torch.equal(a, b)


def test_the_older_run_resumes_and_evaluates(tmp_path):
    run = tmp_path / "run"
    shutil.copytree(FIXTURE, run)
    done = json.loads((run / "metrics.jsonl").read_text().splitlines()[-1])["env_steps"]
    assert gcnt(["train", "--resume", str(run), f"collector.total_frames={done + 15}"]) == 0
    rows = RunDir(run).read_metrics()
    assert rows[-1]["env_steps"] == done + 15 and rows[-1]["updates"] > rows[0]["updates"]
    out = tmp_path / "eval.json"
    assert gcnt(["eval", str(run), "--robots", "train", "--episodes", "1", "--json", str(out)]) == 0
    assert "hopper_3" in out.read_text()
