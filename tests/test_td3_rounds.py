"""The "paper" schedule's rounds as the original main.py files run them
(``td3.round_steps: first_episode``): a sub-env's steps after its first episode of the round are
neither stored nor counted, and every sub-env starts the next round with a new episode."""

from pathlib import Path

import numpy as np
import torch
from tensordict import TensorDict

from gcnt.keys import MORPH_ID
from gcnt.recipes import load_recipe
from gcnt.rl.loop import follow_algorithm, prepare, train
from gcnt.rl.run_dir import RunDir
from gcnt.rl.td3.config import TD3Config
from gcnt.rl.td3.learner import UpdateSchedule

ROOT = Path(__file__).parents[1]


def batch(done_at: list[int | None], steps: int) -> TensorDict:
    """Two sub-envs (robots 0 and 1) for ``steps`` steps; sub-env i ends an episode at step
    ``done_at[i]`` (None: not in this batch)."""
    done = torch.zeros(len(done_at), steps, 1, dtype=torch.bool)
    for i, t in enumerate(done_at):
        if t is not None:
            done[i, t] = True
    step = torch.arange(steps).expand(len(done_at), steps)
    morph = torch.arange(len(done_at))[:, None].expand(len(done_at), steps)
    return TensorDict(
        {"step": step, MORPH_ID: morph, "next": {"done": done}}, batch_size=[len(done_at), steps]
    )


def test_a_round_keeps_each_sub_envs_first_episode_then_asks_for_a_reset():
    schedule = UpdateSchedule(TD3Config(schedule="paper"), num_robots=2, num_envs=2)
    kept = schedule.admit(batch([1, None], 5))
    # sub-env 0: steps 0-1 (its episode ends at 1); sub-env 1: all 5
    assert kept["step"].tolist() == [0, 1, 0, 1, 2, 3, 4]
    schedule.add(kept)
    assert list(schedule.batches(None, warm=False)) == [] and not schedule.reset_due
    kept = schedule.admit(batch([3, 2], 5))  # sub-env 0 waits; sub-env 1 ends at 2
    assert kept[MORPH_ID].tolist() == [1, 1, 1] and kept["step"].tolist() == [0, 1, 2]
    schedule.add(kept)
    list(schedule.batches(None, warm=False))  # both finished: the round ends
    assert schedule.reset_due and not schedule.env_done.any() and not schedule.finished.any()
    assert schedule.admit(batch([None, None], 3)).numel() == 6  # a new round keeps everything


def test_every_step_is_kept_with_round_steps_all_or_the_mixed_schedule():
    for config in (TD3Config(round_steps="all"), TD3Config(schedule="mixed")):
        schedule = UpdateSchedule(config, num_robots=2, num_envs=2)
        data = batch([1, None], 5)
        assert schedule.admit(data) is data


class Collector:
    def __init__(self):
        self.init_random_frames, self.resets = 10**9, 0

    def reset(self):
        self.resets += 1


def test_the_loop_ends_the_random_phase_on_counted_steps_and_resets_when_asked():
    from gcnt.rl.algorithm import CollectSettings

    class Algo:
        due = False

        def reset_due(self):
            return self.due

    collector, algo = Collector(), Algo()
    settings = CollectSettings(None, 10, 10**9, random_steps=40)
    follow_algorithm(collector, settings, algo, 30)
    assert (collector.init_random_frames, collector.resets) == (10**9, 0)
    algo.due = True
    follow_algorithm(collector, settings, algo, 40)
    assert (collector.init_random_frames, collector.resets) == (0, 1)


def test_a_paper_run_stores_one_whole_episode_per_robot_and_round(tmp_path):
    """A humanoid that falls and a cheetah that never does (random actions, then an untrained
    actor):
    each robot's stored
    transitions hold one episode per round, an episode cut by the time limit holds exactly
    ``max_episode_steps`` transitions (it began with the round's reset), and every counted step
    is stored."""
    limit = 120
    recipe = load_recipe(
        ROOT / "recipes/smpenv/cwhh.yaml",
        [
            "network.kwargs={d_model: 16, layers: 1, ff: 16, heads: 2}",
            "env.robots=[humanoid_2d_9_full,cheetah_2_back]",
            f"env.max_episode_steps={limit}",
            "td3.init_random_frames=100",
            "td3.random_counted=total",
            "td3.steps_per_batch=5",
            "td3.batch_size=8",
            "td3.buffer_size_per_robot=2000",
            "collector.total_frames=720",
            "td3.updates_per_step=0.05",
            "logger.backend=none",
            "logger.progress=false",
            "eval.episodes=0",
            f"run_dir={tmp_path / 'run'}",
        ],
    )
    prepared = prepare(recipe)
    run = RunDir(recipe.run_dir)
    run.create(recipe)
    train(recipe, run, prepared=prepared)
    algo = prepared.algo
    steps = run.read_metrics()[-1]["env_steps"]
    assert algo.stored == steps == len(algo.replay)
    lengths = []
    for robot in range(2):
        n = algo.replay.robot_len(robot)
        stored = algo.replay.storage[robot, :n]
        done = stored["next", "done"].reshape(n).numpy()
        truncated = (stored["next", "truncated"] & ~stored["next", "terminated"]).reshape(n)
        ends = np.flatnonzero(done)
        starts = np.concatenate([[0], ends[:-1] + 1])
        lengths.append(ends - starts + 1)
        for start, end in zip(starts, ends, strict=True):
            if truncated[end]:
                assert end - start + 1 == limit
    rounds = min(len(x) for x in lengths)
    assert rounds >= 3 and max(len(x) for x in lengths) <= rounds + 1
    # the robots' first episodes differed in length in some round: someone waited
    assert any(lengths[0][i] != lengths[1][i] for i in range(rounds)), lengths
