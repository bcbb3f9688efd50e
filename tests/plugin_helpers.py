"""A researcher's plugin, written into a temporary folder by the plugin tests: a method
(``plugnet``, shown as PlugNet), a benchmark (``plugbench``: SMPENV's env under a name of its own)
and an algorithm (``plugalgo``: the deterministic actor regressed onto a fixed target action),
registered through gcnt's public seams only."""

from __future__ import annotations

from pathlib import Path

PLUGIN = '''\
"""My own method, benchmark and algorithm for gcnt."""

import dataclasses

import torch

from gcnt.analysis.names import METHOD_NAMES
from gcnt.envs.benchmark import get_benchmark, register_benchmark
from gcnt.keys import ACTION, OBS
from gcnt.nn import register_network
from gcnt.nn.config import GCNTConfig
from gcnt.nn.gcnt import gcnt_backbone
from gcnt.recipes import register_algorithm_section
from gcnt.rl.algorithm import Algorithm, CollectSettings, register_algorithm
from gcnt.rl.factories import make_net


@dataclasses.dataclass
class PlugNetConfig(GCNTConfig):
    """GCNT's sizes; a method of its own."""


def build_plugnet(cfg, io, table):
    return gcnt_backbone(cfg, io, table)


register_network("plugnet", PlugNetConfig, build_plugnet, description="PlugNet")
METHOD_NAMES["plugnet"] = "PlugNet"

register_benchmark(
    dataclasses.replace(get_benchmark("smpenv"), name="plugbench", description="mine")
)


@dataclasses.dataclass
class PlugAlgoConfig:
    lr: float = 1e-2
    steps_per_batch: int = 4


class PlugAlgo(Algorithm):
    """Regresses the deterministic actor's actions onto 0.1 (supervised)."""

    name = "plugalgo"

    def __init__(self, recipe, env, robots):
        super().__init__(recipe, env, robots)
        self.actor = make_net(recipe, env, "td3_actor")
        self.opt = torch.optim.Adam(self.actor.parameters(), lr=self.config.lr)

    def collect_settings(self, env_steps):
        n = self.env.batch_size[0]
        return CollectSettings(self.actor, frames_per_batch=n * self.config.steps_per_batch)

    def process(self, data, env_steps):
        out = self.actor(data.reshape(-1).select("morph_id", OBS).clone())
        loss = ((out[ACTION] - 0.1) ** 2).mean()
        self.opt.zero_grad()
        loss.backward()
        self.opt.step()
        self.updates += 1
        yield {"loss_plug": loss.item()}

    def state_dict(self):
        return {**self.policy_state(), "opt": self.opt.state_dict(), "updates": self.updates}

    def load_state_dict(self, state):
        self.actor.load_state_dict(state["actor"], strict=False)
        self.opt.load_state_dict(state["opt"])
        self.updates = state["updates"]

    def start_from(self, state):
        self.actor.load_state_dict(state["actor"], strict=False)

    def policy_state(self):
        return {"actor": {k: v for k, v in self.actor.state_dict().items() if "table_" not in k}}

    @classmethod
    def eval_policy(cls, recipe, state, env, *, deterministic=True):
        actor = make_net(recipe, env, "td3_actor")
        actor.load_state_dict(state["actor"], strict=False)
        return actor


register_algorithm_section("plugalgo", PlugAlgoConfig)
register_algorithm("plugalgo", PlugAlgo)
'''

#: a recipe of the plugin's method, benchmark and algorithm that trains in seconds (no
#: ``plugins:`` key: the command names the plugin)
RECIPE = """\
task: plugged
algo: plugalgo
env: {benchmark: plugbench, robots: [hopper_3], test_robots: [hopper_4], max_episode_steps: 15,
      num_threads: 1}
collector: {total_frames: 40}
network: {name: plugnet, kwargs: {d_model: 16, layers: 1, ff: 16, heads: 2}}
logger: {backend: none, progress: false, log_interval: 20}
eval: {episodes: 1}
checkpoint_interval: 20
plugalgo: {lr: 0.01, steps_per_batch: 4}
"""


def write_plugin(folder: Path, module: str = "my_methods") -> Path:
    """The plugin as ``<folder>/<module>.py`` and the recipe beside it (``recipe.yaml``)."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "recipe.yaml").write_text(RECIPE)
    path = folder / f"{module}.py"
    path.write_text(PLUGIN)
    return path
