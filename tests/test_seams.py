"""The seams hold: a benchmark and an algorithm defined here, outside gcnt, train and evaluate
through gcnt's public functions without editing any gcnt file."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import pytest
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from gcnt.envs.benchmark import Benchmark, get_benchmark, register_benchmark
from gcnt.envs.robot_table import robot_table
from gcnt.keys import ACTION, OBS
from gcnt.recipes import RecipeError, recipe_from_dict, register_algorithm_section
from gcnt.rl.algorithm import Algorithm, CollectSettings, get_algorithm, register_algorithm
from gcnt.rl.evaluate import evaluate
from gcnt.rl.factories import make_net
from gcnt.rl.loop import train
from gcnt.run.directory import RunDir

F, A = 3, 2  # toy limb observation width and action slots per limb: neither is SMPENV's


class ToyEnv(EnvBase):
    """Robots as padded limb sets; reward = −mean squared distance of each motor slot's action
    from 0.5 · (its limb's first observation); episodes of ``max_episode_steps``."""

    batch_locked = True

    def __init__(
        self,
        robots,
        *,
        max_limbs=None,
        max_episode_steps=5,
        seed=None,
        num_threads=None,
        robot_ids=None,
        device="cpu",
        world=None,
    ):
        n = len(robots)
        super().__init__(device=device, batch_size=torch.Size([n]))
        self.table = robot_table(robots, max_limbs, num_actions=A)
        k = self.table["limbs", "mask"].shape[1]
        self.morph_ids = torch.as_tensor(robot_ids if robot_ids is not None else range(n))
        self.max_episode_steps, self.k = max_episode_steps, k
        self._t = torch.zeros(n, dtype=torch.long)
        self._obs = torch.zeros(n, k, F)
        self.observation_spec = Composite(
            morph_id=Unbounded(shape=(n,), dtype=torch.int64),
            limbs=Composite(obs=Unbounded(shape=(n, k, F)), shape=(n, k)),
            shape=(n,),
        )
        self.action_spec = Composite(
            limbs=Composite(action=Bounded(-1.0, 1.0, shape=(n, k, A)), shape=(n, k)),
            shape=(n,),
        )
        self.reward_spec = Unbounded(shape=(n, 1))
        self.full_done_spec = Composite(
            done=Categorical(2, shape=(n, 1), dtype=torch.bool),
            terminated=Categorical(2, shape=(n, 1), dtype=torch.bool),
            truncated=Categorical(2, shape=(n, 1), dtype=torch.bool),
            shape=(n,),
        )
        self._gen = torch.Generator().manual_seed(seed or 0)

    def _set_seed(self, seed):
        self._gen = torch.Generator().manual_seed(seed or 0)

    def _draw(self, rows):
        mask = self.table["limbs", "mask"][self.morph_ids[rows]].unsqueeze(-1)
        self._obs[rows] = torch.rand(len(rows), self.k, F, generator=self._gen) * mask

    def _out(self, reward=None):
        n = self.batch_size[0]
        done = self._t >= self.max_episode_steps
        td = TensorDict(
            {
                "morph_id": self.morph_ids.clone(),
                "limbs": TensorDict({"obs": self._obs.clone()}, batch_size=[n, self.k]),
                "done": done.unsqueeze(-1).clone(),
                "terminated": torch.zeros(n, 1, dtype=torch.bool),
                "truncated": done.unsqueeze(-1).clone(),
            },
            batch_size=[n],
        )
        if reward is not None:
            td["reward"] = reward
        return td

    def _reset(self, td=None):
        which = torch.ones(self.batch_size[0], dtype=torch.bool)
        if td is not None and "_reset" in td.keys():
            which = td["_reset"].reshape(-1)
        rows = which.nonzero().flatten()
        self._t[rows] = 0
        self._draw(rows)
        return self._out()

    def _step(self, td):
        amask = self.table["limbs", "action_mask"][self.morph_ids]
        target = 0.5 * self._obs[..., :1].expand(-1, -1, A)
        err = ((td[ACTION] - target) ** 2 * amask).sum((1, 2)) / amask.sum((1, 2)).clamp_min(1)
        self._t += 1
        self._draw(torch.arange(self.batch_size[0]))
        return self._out(reward=-err.unsqueeze(-1))


@dataclass
class ToyConfig:
    lr: float = 1e-2
    steps_per_batch: int = 4

    def check(self):
        if not self.lr > 0:
            raise ValueError(f"lr must be > 0, got {self.lr}")


class ToyAlgorithm(Algorithm):
    """Regresses the deterministic actor onto the toy env's best action (supervised)."""

    name = "toy"

    def __init__(self, recipe, env, robots):
        super().__init__(recipe, env, robots)
        self.actor = make_net(recipe, env, "td3_actor")
        self.opt = torch.optim.Adam(self.actor.parameters(), lr=self.config.lr)

    def collect_settings(self, env_steps):
        n = self.env.batch_size[0]
        return CollectSettings(self.actor, frames_per_batch=n * self.config.steps_per_batch)

    def process(self, data: TensorDictBase, env_steps: int) -> Iterator[dict[str, float]]:
        batch = data.reshape(-1).select("morph_id", OBS)
        out = self.actor(batch.clone())
        target = 0.5 * batch[OBS][..., :1].expand_as(out[ACTION])
        amask = out["limbs", "action_mask"] if ("limbs", "action_mask") in out.keys(True) else None
        err = (out[ACTION] - target) ** 2
        loss = err.mean() if amask is None else (err * amask).sum() / amask.sum()
        self.opt.zero_grad()
        loss.backward()
        self.opt.step()
        self.updates += 1
        yield {"loss_toy": loss.item()}

    def state_dict(self):
        return {
            "actor": self.policy_state()["actor"],
            "opt": self.opt.state_dict(),
            "updates": self.updates,
        }

    def load_state_dict(self, state):
        self.actor.load_state_dict(state["actor"], strict=False)
        self.opt.load_state_dict(state["opt"])
        self.updates = state["updates"]

    def policy_state(self):
        return {"actor": {k: v for k, v in self.actor.state_dict().items() if "table_" not in k}}

    @classmethod
    def eval_policy(cls, recipe, state, env, *, deterministic=True):
        actor = make_net(recipe, env, "td3_actor")
        actor.load_state_dict(state["actor"], strict=False)
        return actor


@pytest.fixture(scope="module", autouse=True)
def toy_seams():
    register_benchmark(
        Benchmark(
            name="toy",
            catalogue="smpenv",
            make_env=ToyEnv,
            preset="smpenv",
            limb_obs_dim=F,
            action_slots=A,
        ),
        replace=True,
    )
    register_algorithm_section("toy", ToyConfig, replace=True)
    register_algorithm("toy", ToyAlgorithm, replace=True)


def toy_recipe(run_dir, **extra):
    return recipe_from_dict(
        {
            "task": "toy-task",
            "algo": "toy",
            "run_dir": str(run_dir),
            "env": {
                "benchmark": "toy",
                "robots": ["hopper_3", "walker_2_main"],
                "max_episode_steps": 5,
            },
            "collector": {"total_frames": 400},
            "network": {"name": "gcnt", "kwargs": {"d_model": 16, "layers": 1, "ff": 16}},
            "logger": {"backend": "none", "progress": False, "log_interval": 80},
            "checkpoint_interval": 200,
            "eval": {"episodes": 2},
            "toy": {"lr": 1e-2},
            **extra,
        }
    )


def test_a_toy_benchmark_and_algorithm_train_and_evaluate_through_gcnt(tmp_path):
    assert get_benchmark("toy").limb_obs_dim == F and get_algorithm("toy") is ToyAlgorithm
    recipe = toy_recipe(tmp_path / "run")
    run = RunDir(recipe.run_dir)
    run.create(recipe)
    train(recipe, run)
    rows = run.read_metrics()
    assert rows[-1]["env_steps"] >= 400 and rows[-1]["updates"] > 0
    # the toy algorithm learns the toy task: its loss falls
    losses = [r["loss_toy"] for r in rows if "loss_toy" in r]
    assert losses[-1] < losses[0]
    state = run.load_checkpoint()
    assert state["algo"] == "toy" and list((run.path / "eval").glob("step*.json"))
    # evaluation on a robot never trained on, through the benchmark and the algorithm
    results = evaluate(recipe, state["policy"], ["cheetah_3_balanced"], episodes=2)
    assert results["cheetah_3_balanced"]["episodes"] == 2


def test_toy_sections_are_validated_only_when_active(tmp_path):
    with pytest.raises(RecipeError, match="lr must be > 0"):
        toy_recipe(tmp_path, toy={"lr": -1.0})
    # the toy section stays as written (td3 explores randomly for fewer than the 400 frames)
    r = toy_recipe(tmp_path, algo="td3", td3={"init_random_frames": 100})
    assert r.sections["toy"] == {"lr": 1e-2}
    with pytest.raises(RecipeError, match="unknown benchmark 'toyy'; did you mean 'toy'"):
        train(
            toy_recipe(tmp_path, env={"benchmark": "toyy", "robots": ["hopper_3"]}),
            RunDir(tmp_path / "x"),
        )
