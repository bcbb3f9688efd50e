"""Fine-tuning with ``init_from`` / ``gcnt train RECIPE --init-from RUN_DIR``: a new run on other
robots starts from a trained run's networks (PPO: and its observation statistics) with fresh
optimisers, replay and counters, records where it started, and a run that does not fit is one
line naming both sides."""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import pytest
import torch
import yaml
from cli_helpers import error_line

from gcnt.analysis.runs import Run
from gcnt.cli import main as gcnt
from gcnt.recipes import load_recipe
from gcnt.rl.factories import network_weights
from gcnt.rl.loop import prepare
from gcnt.run.directory import RunDir

ROOT = Path(__file__).parents[1]

#: a tiny GCNT with TD3 on hopper_3 (3 limbs), a few seconds
TD3_TINY = """\
base: {root}/recipes/smpenv/_td3.yaml
task: tiny
env: {{robots: [hopper_3], test_robots: [], max_episode_steps: 15, num_threads: 1}}
collector: {{total_frames: 40}}
td3: {{init_random_frames: 20, steps_per_batch: 5, batch_size: 8, buffer_size_per_robot: 2000,
      updates_per_step: 0.5}}
network: {{kwargs: {{d_model: 16, layers: 1, ff: 16, heads: 2}}}}
logger: {{backend: none, progress: false, log_interval: 20}}
eval: {{episodes: 0}}
checkpoint_interval: 20
"""

#: a tiny GCNT with PPO on hopper_3 and hopper_4 (at most 4 limbs), two iterations
PPO_TINY = """\
algo: ppo
task: tiny
env: {robots: [hopper_3, hopper_4], max_episode_steps: 15, num_threads: 1}
collector: {total_frames: 160}
network: {kwargs: {d_model: 16, layers: 1, ff: 16, heads: 2}}
ppo: {num_envs: 4, steps_per_env: 20, minibatch_size: 40, epochs: 2, uniform_iterations: 1}
logger: {backend: none, progress: false, log_interval: 80}
eval: {episodes: 0}
checkpoint_interval: 80
"""

#: 10 frames, fewer than a TD3 batch: no update, so the run's policy stays the one it started from
NO_UPDATE = [
    "collector.total_frames=10",
    "td3.init_random_frames=5",
    "td3.batch_size=64",
    "checkpoint_interval=10",
]

#: the new robot set: walker_7_main has 7 limbs, more than any source robot
NEW_ROBOTS = "env.robots=[walker_7_main]"


@pytest.fixture(scope="module")
def td3_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("recipes") / "td3.yaml"
    path.write_text(TD3_TINY.format(root=ROOT))
    return path


@pytest.fixture(scope="module")
def ppo_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("recipes") / "ppo.yaml"
    path.write_text(PPO_TINY)
    return path


@pytest.fixture(scope="module")
def td3_source(tmp_path_factory, td3_file) -> Path:
    """A finished tiny TD3 run (copy it before changing it)."""
    run = tmp_path_factory.mktemp("td3") / "source"
    assert gcnt(["train", str(td3_file), f"run_dir={run}"]) == 0
    return run


@pytest.fixture(scope="module")
def ppo_source(tmp_path_factory, ppo_file) -> Path:
    run = tmp_path_factory.mktemp("ppo") / "source"
    assert gcnt(["train", str(ppo_file), f"run_dir={run}"]) == 0
    return run


def _learner(run: Path) -> dict:
    return RunDir(run).load_checkpoint()["learner"]


def _same(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def _record(source: Path) -> dict:
    path = source / "checkpoints" / "last.pt"
    return {
        "run": str(source.resolve()),
        "task": "tiny",
        "fingerprint": Run(source).fingerprint,
        "env_steps": RunDir(source).load_checkpoint()["env_steps"],
        "checkpoint_sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
    }


# ------------------------------------------------------------------ TD3


def test_td3_starts_from_the_trained_networks_with_fresh_optimisers(td3_source, td3_file, tmp_path):
    recipe = load_recipe(td3_file, [f"init_from={td3_source}", NEW_ROBOTS, f"run_dir={tmp_path}"])
    prep = prepare(recipe)
    try:
        learner, trained = prep.algo.learner, _learner(td3_source)
        assert trained["updates"] > 0  # the source learnt: its weights are not an initialisation
        for key in ("actor", "critics", "target_actor", "target_critics"):
            assert _same(network_weights(getattr(learner, key)), trained[key]), key
        assert learner.actor_opt.state_dict()["state"] == {}
        assert learner.critic_opt.state_dict()["state"] == {}
        assert learner.updates == 0 and prep.algo.stored == 0
        assert int(prep.algo.replay.sizes.sum()) == 0
        assert recipe.resolved["init_from"] == _record(td3_source)
        assert "num_envs" in recipe.resolved  # the derived sizes stay beside the record
    finally:
        prep.env.close()


def test_the_command_fine_tunes_records_the_source_and_resumes_without_it(
    td3_source, td3_file, tmp_path
):
    source = tmp_path / "source"
    shutil.copytree(td3_source, source)
    run = tmp_path / "ft"
    argv = ["train", str(td3_file), "--init-from", str(source), NEW_ROBOTS, f"run_dir={run}"]
    assert gcnt([*argv, *NO_UPDATE]) == 0
    written = yaml.safe_load((run / "recipe.yaml").read_text())
    assert written["init_from"] == str(source)
    assert written["resolved"]["init_from"] == _record(source)
    state = _learner(run)
    assert _same(state["actor"], _learner(source)["actor"]) and state["updates"] == 0
    assert state["actor_opt"]["state"] == {}
    # a resumed run continues its own checkpoint: the source is no longer read
    shutil.rmtree(source)
    assert gcnt(["train", "--resume", str(run), "collector.total_frames=20"]) == 0
    written_again = yaml.safe_load((run / "recipe.yaml").read_text())
    assert written_again["resolved"]["init_from"] == written["resolved"]["init_from"]
    assert RunDir(run).load_checkpoint()["env_steps"] == 20


def test_stacked_seeds_all_start_from_the_source(td3_source, td3_file, tmp_path):
    argv = ["train", str(td3_file), "--seeds", "0,1", "--init-from", str(td3_source)]
    overrides = [NEW_ROBOTS, f"run_dir={tmp_path}", "td3.schedule=mixed"]
    assert gcnt([*argv, *overrides, *NO_UPDATE]) == 0
    trained = _learner(td3_source)["actor"]
    for seed in (0, 1):
        run = tmp_path / f"seed{seed}"
        assert _same(_learner(run)["actor"], trained)
        written = yaml.safe_load((run / "recipe.yaml").read_text())
        assert written["resolved"]["init_from"] == _record(td3_source)


# ------------------------------------------------------------------ PPO


def test_ppo_starts_from_the_trained_networks_and_observation_statistics(
    ppo_source, ppo_file, tmp_path
):
    recipe = load_recipe(ppo_file, [f"init_from={ppo_source}", NEW_ROBOTS, f"run_dir={tmp_path}"])
    prep = prepare(recipe)
    try:
        learner, trained = prep.algo.learner, _learner(ppo_source)["learner"]
        assert trained["updates"] > 0
        assert _same(network_weights(learner.actor), trained["actor"])
        assert _same(network_weights(learner.critic), trained["critic"])
        assert learner.opt.state_dict()["state"] == {}
        assert learner.iteration == 0 and learner.updates == 0
        # statistics of the 4 trained limb slots carried over; walker_7_main's 3 other slots
        # start unnormalised with the prior count, so their first batch sets them
        norm, src = learner.obs_norm, trained["obs_norm"]
        assert norm.mean.shape[0] == 7 and src["mean"].shape[0] == 4
        for key in ("mean", "var", "count"):
            assert torch.equal(norm.state_dict()[key][:4], src[key]), key
        assert torch.equal(norm.mean[4:], torch.zeros_like(norm.mean[4:]))
        assert torch.equal(norm.var[4:], torch.ones_like(norm.var[4:]))
        assert bool((norm.count[4:] < 1).all()) and bool((src["count"] > 1).all())
        assert recipe.resolved["init_from"] == _record(ppo_source)
    finally:
        prep.env.close()


def test_ppo_observation_normalisation_must_match(ppo_source, ppo_file, capsys, tmp_path):
    line = error_line(
        capsys,
        ["train", str(ppo_file), "--init-from", str(ppo_source), "ppo.obs_norm=false",
         f"run_dir={tmp_path / 'x'}"],
    )  # fmt: skip
    assert "ppo.obs_norm=True" in line and "ppo.obs_norm=False" in line
    assert not (tmp_path / "x").exists()


# ------------------------------------------------------------------ what does not fit


@pytest.mark.parametrize(
    ("overrides", "sides"),
    [
        (["network.kwargs.d_model=8"], ("d_model=16", "d_model=8")),
        (["network.name=swat"], ("network.name=gcnt", "network.name=swat")),
        (["algo=ppo"], ("algo=td3", "algo=ppo")),
        (
            ["env.benchmark=unimal", "env.robots=[unimal_0000]", "env.world=ft"],
            ("env.benchmark=smpenv", "env.benchmark=unimal"),
        ),
    ],
    ids=["network-size", "network", "algorithm", "benchmark"],
)
def test_a_run_that_does_not_fit_is_one_line_naming_both_sides(
    td3_source, td3_file, capsys, tmp_path, overrides, sides
):
    run = tmp_path / "x"
    argv = ["train", str(td3_file), "--init-from", str(td3_source), f"run_dir={run}", *overrides]
    line = error_line(capsys, argv)
    assert f"init_from {td3_source}" in line
    assert all(side in line for side in sides), line
    assert not run.exists()  # refused before the run directory is made


def test_a_token_width_that_does_not_fit_names_the_tensor_and_both_shapes(
    td3_source, td3_file, capsys, tmp_path
):
    source = tmp_path / "source"
    shutil.copytree(td3_source, source)
    path = source / "checkpoints" / "last.pt"
    state = torch.load(path, weights_only=False)
    actor = state["learner"]["actor"]
    # the first matrix of the actor: one more input feature, as a wider per-limb token gives
    key = next(k for k, v in actor.items() if v.dim() == 2)
    rows, cols = actor[key].shape
    actor[key] = torch.zeros(rows, cols + 1)
    torch.save(state, path)
    argv = ["train", str(td3_file), "--init-from", str(source), f"run_dir={tmp_path / 'x'}"]
    line = error_line(capsys, argv)
    assert "TD3 actor" in line and key in line
    assert f"[{rows}, {cols + 1}] in the checkpoint" in line
    assert f"[{rows}, {cols}] in the network" in line


def test_init_from_is_refused_with_resume_and_a_missing_run_is_named(
    td3_source, td3_file, capsys, tmp_path
):
    line = error_line(
        capsys, ["train", "--resume", str(td3_source), "--init-from", str(td3_source)]
    )
    assert "--init-from" in line and "--resume" in line
    missing = str(td3_source) + "x"
    line = error_line(capsys, ["train", str(td3_file), "--init-from", missing])
    assert missing in line and "does not exist" in line and repr(str(td3_source)) in line


def test_a_fine_tune_onto_test_robots_says_how_to_drop_them_from_the_test_list(
    td3_source, td3_file, capsys, tmp_path
):
    tests = "env.test_robots=[walker_7_main, hopper_5, walker_2_main]"
    argv = ["train", str(td3_file), "--init-from", str(td3_source), NEW_ROBOTS, tests]
    line = error_line(capsys, [*argv, f"run_dir={tmp_path / 'ft'}"])
    assert "fine-tuning on walker_7_main, which env.test_robots lists" in line
    assert """'env.test_robots=["hopper_5", "walker_2_main"]'""" in line
    assert not (tmp_path / "ft").exists()
    # as the line says: the run starts
    argv[-1] = 'env.test_robots=["hopper_5", "walker_2_main"]'
    assert gcnt([*argv, *NO_UPDATE, "eval.episodes=0", f"run_dir={tmp_path / 'ft'}"]) == 0
