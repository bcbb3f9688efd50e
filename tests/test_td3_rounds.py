"""The "paper" schedule's rounds as the original main.py files run them
(``td3.round_steps: first_episode``): a sub-env's steps after its first episode of the round are
neither stored nor counted, and every sub-env starts the next round with a new episode."""

from pathlib import Path

import numpy as np
import pytest
import torch
from tensordict import TensorDict

from gcnt.keys import MORPH_ID
from gcnt.recipes import load_recipe
from gcnt.rl.loop import follow_algorithm, prepare, train
from gcnt.rl.td3.config import TD3Config
from gcnt.rl.td3.learner import UpdateSchedule
from gcnt.run.directory import RunDir

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
    config = TD3Config(schedule="paper", round_steps="first_episode")
    schedule = UpdateSchedule(config, num_robots=2, num_envs=2)
    counted, kept = schedule.admit(batch([1, None], 5))
    # sub-env 0: steps 0-1 (its episode ends at 1); sub-env 1: all 5
    assert kept is counted and kept["step"].tolist() == [0, 1, 0, 1, 2, 3, 4]
    schedule.add(kept)
    assert list(schedule.batches(None, warm=False)) == [] and not schedule.reset_due
    counted, kept = schedule.admit(batch([3, 2], 5))  # sub-env 0 waits; sub-env 1 ends at 2
    assert kept[MORPH_ID].tolist() == [1, 1, 1] and kept["step"].tolist() == [0, 1, 2]
    schedule.add(kept)
    list(schedule.batches(None, warm=False))  # both finished: the round ends
    assert schedule.reset_due and not schedule.env_done.any() and not schedule.finished.any()
    assert schedule.admit(batch([None, None], 3))[1].numel() == 6  # a new round keeps everything


def test_the_originals_round_stores_every_step_and_counts_each_first_episode():
    """R1 (SWAT/AMORPHEUS main.py): a sub-env that finished keeps stepping while the others
    finish; its steps are stored, not counted."""
    schedule = UpdateSchedule(TD3Config(schedule="paper"), num_robots=2, num_envs=2)
    assert schedule.store_after_first and schedule.rounds  # the default
    data = batch([1, None], 5)
    counted, stored = schedule.admit(data)
    assert counted["step"].tolist() == [0, 1, 0, 1, 2, 3, 4]
    assert stored.numel() == 10 and stored["step"].tolist() == [*range(5), *range(5)]
    schedule.add(stored, counted)
    assert schedule.pending.tolist() == [5, 5] and schedule.counted.tolist() == [2, 5]
    counted, stored = schedule.admit(batch([3, 2], 5))  # sub-env 0 goes on, uncounted
    assert counted[MORPH_ID].tolist() == [1, 1, 1] and stored.numel() == 10
    schedule.add(stored, counted)
    # robot 0's done at step 3 of the second batch is after its first episode: only robot 1's
    # counted done finishes it
    assert schedule.finished.tolist() == [True, True]
    assert schedule.pending.tolist() == [10, 10] and schedule.counted.tolist() == [2, 8]


class Replay:
    def sample_robot(self, robot, limbs=None):
        return robot


@pytest.mark.parametrize(
    ("rule", "expected"),
    [("mean", {0: 5, 1: 5, 2: 5}), ("own", {0: 2, 1: 9, 2: 5})],
)
def test_a_rounds_updates_are_shared_out_as_the_originals_or_by_own_steps(rule, expected):
    """R2: the originals' TD3.train gives every robot sum(counted) // robots updates."""
    config = TD3Config(schedule="paper", round_updates=rule)
    schedule = UpdateSchedule(config, num_robots=3, num_envs=3)
    steps = {0: 2, 1: 9, 2: 5}  # counted steps (16 in all: 16 // 3 = 5 each)
    done_at = [steps[0] - 1, None, steps[2] - 1]
    data = batch(done_at, 9)
    counted, stored = schedule.admit(data)
    schedule.add(stored, counted)
    # robot 1 ends its episode at the last step of a second batch of 0 counted steps
    schedule.finished[1] = True
    made = list(schedule.batches(Replay(), warm=True))
    assert {r: made.count(r) for r in range(3)} == expected
    assert not schedule.counted.any() and not schedule.pending.any()


def test_every_step_is_kept_with_round_steps_all_or_the_mixed_schedule():
    for config in (TD3Config(round_steps="all"), TD3Config(schedule="mixed")):
        schedule = UpdateSchedule(config, num_robots=2, num_envs=2)
        data = batch([1, None], 5)
        counted, stored = schedule.admit(data)
        assert counted is data and stored is data


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


@pytest.mark.parametrize("rounds", ["first_episode", "store_all_count_first"])
def test_a_paper_run_stores_one_whole_episode_per_robot_and_round(tmp_path, rounds):
    """A humanoid that falls and a cheetah that never does (random actions, then an untrained
    actor):
    each robot's stored
    transitions hold one episode per round, an episode cut by the time limit holds exactly
    ``max_episode_steps`` transitions (it began with the round's reset), and every counted step
    is stored; with ``store_all_count_first`` the robot that fell first also stored the steps
    it took while the other finished, uncounted."""
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
            f"td3.round_steps={rounds}",
        ],
    )
    prepared = prepare(recipe)
    run = RunDir(recipe.run_dir)
    run.create(recipe)
    train(recipe, run, prepared=prepared)
    algo = prepared.algo
    steps = run.read_metrics()[-1]["env_steps"]
    if rounds == "store_all_count_first":
        # every step of every sub-env stored (2 robots in lockstep), more than were counted
        assert algo.stored == len(algo.replay) > steps
        assert algo.replay.robot_len(0) == algo.replay.robot_len(1)
        return
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
