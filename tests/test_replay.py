"""Tests for ``gcnt.rl.td3.replay``, the TD3 replay with one storage that rings per robot:
``RobotReplay`` keeps a ring per robot (oldest transitions overwritten, the last ones winning
when more arrive than fit), a mixed sample holds every robot and sampling an empty robot fails
clearly, it stores what torchrl's per-robot ReplayBufferEnsemble stores and gives the same critic
loss, its checkpoint round-trips, and buffers checkpointed during training resume exactly.
"""

from pathlib import Path

import pytest
import torch
from tensordict import TensorDict

from gcnt.bench.td3 import ensemble_store, make_ensemble
from gcnt.recipes import load_recipe
from gcnt.rl.factories import make_env, train_robots
from gcnt.rl.loop import train
from gcnt.rl.td3 import replay as rb
from gcnt.rl.td3.learner import TD3Learner
from gcnt.run.directory import RunDir

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
    ensemble = make_ensemble(len(robots), capacity=20, batch_size=8)
    replay.extend(data)
    ensemble_store(ensemble, data)
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
