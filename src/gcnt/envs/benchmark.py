"""The benchmark seam: one small record per benchmark (SMPENV, UNIMAL, or one of your own).

A :class:`Benchmark` names the robot catalogue its robots come from, builds its batched env for
any list of robots, and says which network size preset fits it. The run loop, evaluation,
``gcnt params`` and ``gcnt bench-env`` reach a benchmark only through this record, so adding a
benchmark touches no file of the others::

    register_benchmark(Benchmark(name="toy", catalogue="toy", make_env=ToyEnv, preset="smpenv"))

Observation and action widths are read from the built env's specs (``limb_obs_dim`` and
``action_slots`` below are the same numbers, declared for commands that never build an env).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from gcnt.builtin import BENCHMARKS as BUILTIN_BENCHMARKS
from gcnt.suggest import did_you_mean

#: make_env(robots, *, max_limbs, max_episode_steps, seed, num_threads, robot_ids, device,
#:          world) -> a torchrl EnvBase of batch [len(robots)] emitting the TensorDict contract
EnvFactory = Callable[..., Any]


@dataclass(frozen=True)
class Benchmark:
    """What the rest of gcnt needs to know about one benchmark."""

    #: registry name, used in recipes as ``env.benchmark``
    name: str
    #: the morphology catalogue its robot names resolve in (``gcnt.morphology.catalogues``)
    catalogue: str
    #: builds the batched env (see :data:`EnvFactory`)
    make_env: EnvFactory
    #: network size preset of this benchmark ("smpenv" or "unimal", see ``gcnt.nn.config``;
    #: mjcf3d's 3-D robots use "unimal")
    preset: str
    #: per-limb observation width F and action slots per limb A (the env's specs say the same)
    limb_obs_dim: int = 0
    action_slots: int = 1
    #: worlds (terrains) the env offers; empty: one world, and ``env.world`` must stay unset
    worlds: tuple[str, ...] = ()
    default_world: str | None = None
    #: worlds whose observation carries a height map, and its width
    hfield_worlds: tuple[str, ...] = ()
    hfield_dim: int = 0
    #: the limb decoder's hidden widths per world (the originals' ``DECODER_DIMS``); a world not
    #: listed: the networks' default (one hidden layer with a height map, none without)
    decoder_hidden: Mapping[str, tuple[int, ...]] = field(default_factory=dict)
    #: the robots a run of this benchmark trains on, as a robot spec ("Benchmark:split"); the
    #: default robots of ``gcnt bench-env``
    train_split: str = ""
    #: extra documentation shown by ``gcnt robots``
    description: str = ""

    def check_world(self, world: str | None) -> str | None:
        """The world to build (``world`` or the default); a ValueError names an unknown one."""
        if world is None:
            return self.default_world
        if world not in self.worlds:
            if not self.worlds:
                raise ValueError(f"benchmark {self.name!r} has no worlds; leave env.world unset")
            raise ValueError(
                f"unknown world {world!r} for benchmark {self.name!r}{did_you_mean(world, self.worlds)}"
                f" (known: {', '.join(self.worlds)})"
            )
        return world


_REGISTRY: dict[str, Benchmark] = {}
#: built-in benchmarks, imported on first use (keeps ``gcnt --help`` free of torch/mujoco)
_BUILTIN = BUILTIN_BENCHMARKS


def register_benchmark(benchmark: Benchmark, *, replace: bool = False) -> Benchmark:
    """Make ``benchmark`` available under its name (``replace`` to redefine one of yours; a
    built-in benchmark is never replaced)."""
    if benchmark.name in _BUILTIN and get_benchmark(benchmark.name) is not benchmark:
        raise ValueError(
            f"benchmark {benchmark.name!r} is built into gcnt and cannot be replaced; register "
            "yours under a name of its own"
        )
    if benchmark.name in _REGISTRY and not replace:
        raise ValueError(f"benchmark {benchmark.name!r} is already registered")
    _REGISTRY[benchmark.name] = benchmark
    return benchmark


def benchmark_names() -> list[str]:
    return sorted({*_REGISTRY, *_BUILTIN})


def get_benchmark(name: str) -> Benchmark:
    """The registered benchmark ``name``; a ValueError with close matches otherwise."""
    if name not in _REGISTRY and name in _BUILTIN:
        module, attr = _BUILTIN[name].split(":")
        try:
            bench = getattr(importlib.import_module(module), attr)
        except (ImportError, AttributeError) as e:
            raise ValueError(f"benchmark {name!r} is not available: {e}") from e
        _REGISTRY.setdefault(name, bench)
    if name not in _REGISTRY:
        raise ValueError(
            f"unknown benchmark {name!r}{did_you_mean(name, benchmark_names())} "
            f"(known: {', '.join(benchmark_names())})"
        )
    return _REGISTRY[name]
