"""The one resolved record of a run: what a recipe means here, resolved and checked once per
command, and what every part of the command (the checks, the env, the evaluations, the run's
``recipe.yaml``) starts from.

:func:`resolve_run` builds it from a recipe: the benchmark and world, the training and test
robots (each spec looked up once; name, family, catalogue and the sha256 of the stored MJCF of
each, :func:`gcnt.run.record.robot_record`), the method and its network sizes as the preset and
overrides resolve them, the algorithm and its settings, the plugins by identity, the device and
the seed. The checks of the recipe that need it resolved are made there, once: the benchmark and
world known, the network's name and sizes, the training robots given, of the benchmark and apart
from the test robots. A run writes it into its ``recipe.yaml`` (:meth:`RunRecord.resolved`: the
``robots`` and ``plugins`` keys of the ``resolved:`` section, as older gcnt reads them, and the
rest under ``run``); :meth:`RunRecord.from_resolved` reads it back.

Nothing here imports ``gcnt.rl`` or ``gcnt.analysis``: both start from it.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from gcnt.recipes import Recipe, RecipeError, run_robot_specs
from gcnt.run.record import PLUGINS_KEY, ROBOTS_KEY

#: the key, in a run's ``resolved:`` section, of the record's fields other than its robots and
#: plugins
RUN_KEY = "run"
#: the fields of :class:`RunRecord` kept under :data:`RUN_KEY`
_RUN_FIELDS = ("benchmark", "world", "method", "network", "algo", "settings", "device", "seed")


def _plain(value: Any) -> Any:
    """``value`` as plain YAML/JSON data (tuples as lists, keys as strings)."""
    return json.loads(json.dumps(value, default=str))


@dataclass(frozen=True)
class RunRecord:
    """A run as resolved here (plain data; the robots themselves ride along, not compared)."""

    benchmark: str
    world: str | None
    method: str
    #: the method's network configuration with its preset and overrides resolved
    network: dict[str, Any]
    algo: str
    #: the algorithm's section, as validated
    settings: dict[str, Any]
    device: str
    seed: int
    #: ``{"train": [names], "test": [names], "index": {name: {"sha256", "family", "catalogue",
    #: "registered"}}}`` (:func:`gcnt.run.record.robot_record`)
    robots: dict[str, Any]
    #: ``[{"name", "sha256"}]`` (:func:`gcnt.plugins.identities`)
    plugins: list[dict[str, Any]]
    train_robots: tuple[Any, ...] = field(default=(), compare=False, repr=False)
    test_robots: tuple[Any, ...] = field(default=(), compare=False, repr=False)
    #: the robot specs this command looked up, each once (more robots of the command reuse them)
    lookups: dict[str, Any] = field(default_factory=dict, compare=False, repr=False)

    def resolved(self) -> dict[str, Any]:
        """The record as a run's ``resolved:`` section holds it."""
        return {
            ROBOTS_KEY: _plain(self.robots),
            PLUGINS_KEY: _plain(self.plugins),
            RUN_KEY: _plain({k: getattr(self, k) for k in _RUN_FIELDS}),
        }

    @classmethod
    def from_resolved(cls, section: Mapping[str, Any]) -> RunRecord | None:
        """The record a run wrote in its ``resolved:`` section; None for a run written before
        the record (its robots or its ``run`` key missing)."""
        run, robots = section.get(RUN_KEY), section.get(ROBOTS_KEY)
        if not isinstance(run, Mapping) or not isinstance(robots, Mapping):
            return None
        if any(k not in run for k in _RUN_FIELDS):
            return None
        plugins = section.get(PLUGINS_KEY)
        return cls(
            **{k: run[k] for k in _RUN_FIELDS},
            robots=dict(robots),
            plugins=list(plugins) if isinstance(plugins, list) else [],
        )

    def robots_of(self, specs: Sequence[str], recipe: Recipe) -> list[Any]:
        """The robots of ``specs`` (each once), named as in this run: a list of the run's own is
        the record's; other specs are looked up once per command."""
        from gcnt.morphology.catalogues import resolve_robots

        own = {
            tuple(recipe.env.robots): self.train_robots,
            tuple(recipe.env.test_robots): self.test_robots,
            (*recipe.env.robots, *recipe.env.test_robots): (
                *self.train_robots,
                *self.test_robots,
            ),
        }
        if specs and tuple(specs) in own:
            return list(own[tuple(specs)])
        return resolve_robots(
            specs, repeats=True, names_from=run_robot_specs(recipe), lookups=self.lookups
        )


def benchmark_of(recipe: Recipe) -> Any:
    """The recipe's benchmark, its world checked (a RecipeError naming either)."""
    from gcnt.envs.benchmark import get_benchmark

    try:
        bench = get_benchmark(recipe.env.benchmark)
        bench.check_world(recipe.env.world)
    except ValueError as e:
        raise RecipeError(f"env: {e}") from None
    return bench


def network_sizes(recipe: Recipe) -> dict[str, Any]:
    """The recipe's network configuration with its preset and overrides resolved, as the
    network builder reads it, as plain data (a RecipeError naming a bad name or size)."""
    from gcnt.nn.registry import make_config

    net = recipe.network
    preset = net.preset or benchmark_of(recipe).preset
    try:
        config = make_config(net.name, preset, **net.sizes())
    except (ValueError, TypeError) as e:
        raise RecipeError(f"network: {e}") from None
    return _plain(dataclasses.asdict(config))


def check_benchmark(recipe: Recipe, robots: Sequence[Any], where: str) -> list[Any]:
    """``robots`` if the recipe's benchmark can step them all; else a RecipeError naming the
    first robot of another benchmark (``where``: what named them, for the message)."""
    bench = benchmark_of(recipe)
    for robot in robots:
        if robot.catalogue != bench.catalogue:
            raise RecipeError(
                f"{where}: robot {robot.name!r} is a {robot.catalogue} robot, but this is a "
                f"{bench.name} run (env.benchmark={bench.name}); use a recipe of its benchmark"
            )
    return list(robots)


def check_apart(recipe: Recipe, robots: Sequence[Any], tests: Sequence[Any]) -> None:
    """A RecipeError naming the training robots (``robots``) that the test list (``tests``)
    holds too: a zero-shot robot is never trained on. A fine-tune (``init_from``) onto test
    robots is told the test list without them."""
    from gcnt.morphology.catalogues import robot_catalogue, robot_identity

    trained = {robot_identity(r) for r in robots}
    tested = {robot_identity(r) for r in tests}
    both = [r for r in robots if robot_identity(r) in tested]
    if not both:
        return
    names = ", ".join(r.name for r in both)
    if recipe.init_from:
        rest = [r for r in tests if robot_identity(r) not in trained]
        kept = json.dumps([r.name if robot_catalogue(r.name) else r.source for r in rest])
        raise RecipeError(
            f"env.robots: fine-tuning on {names}, which env.test_robots lists (a zero-shot "
            f"robot is never trained on); drop {'it' if len(both) == 1 else 'them'} from the "
            f"test list: 'env.test_robots={kept}'"
        )
    raise RecipeError(
        f"env.robots and env.test_robots both list {names}: a zero-shot (test) robot is never "
        "trained on; drop each from one of the lists"
    )


def _key(recipe: Recipe) -> str:
    """What the record of ``recipe`` depends on (a recipe changed since is resolved again)."""
    net = recipe.network
    return json.dumps(
        [
            recipe.env.benchmark,
            recipe.env.world,
            recipe.env.robots,
            recipe.env.test_robots,
            recipe.eval.robots,
            recipe.init_from,
            net.name,
            net.preset,
            net.kwargs,
            net.method_kwargs,
            recipe.algo,
            recipe.device,
            recipe.seed,
        ],
        default=str,
        sort_keys=True,
    )


#: id(recipe) -> (the recipe, what its record depends on, the record): one record per recipe
#: object of a command
_RECORDS: dict[int, tuple[Recipe, str, RunRecord]] = {}


def resolve_run(recipe: Recipe, *, lookups: dict[str, Any] | None = None) -> RunRecord:
    """The record of the run of ``recipe``, resolved and checked once per recipe object (again
    where the recipe changed since); ``lookups``: robot specs this command looked up already.
    A RecipeError (or a robot error) names what is wrong."""
    key = _key(recipe)
    held = _RECORDS.get(id(recipe))
    if held is not None and held[0] is recipe and held[1] == key:
        return held[2]
    record = _resolve(recipe, {} if lookups is None else lookups)
    if len(_RECORDS) > 64:  # a process that checks many recipes (a sweep's)
        _RECORDS.clear()
    _RECORDS[id(recipe)] = (recipe, key, record)
    return record


def _resolve(recipe: Recipe, lookups: dict[str, Any]) -> RunRecord:
    from gcnt import plugins
    from gcnt.morphology.catalogues import resolve_robots
    from gcnt.run.record import robot_record

    bench = benchmark_of(recipe)
    network = network_sizes(recipe)
    if not recipe.env.robots:
        raise RecipeError("env.robots is empty: name at least one robot to train on")
    names_from = run_robot_specs(recipe)
    train = resolve_robots(recipe.env.robots, names_from=names_from, lookups=lookups)
    tests = (
        resolve_robots(recipe.env.test_robots, names_from=names_from, lookups=lookups)
        if recipe.env.test_robots
        else []
    )
    check_benchmark(recipe, train, "env.robots")
    check_apart(recipe, train, tests)
    settings = recipe.algo_config
    return RunRecord(
        benchmark=bench.name,
        world=bench.check_world(recipe.env.world),
        method=recipe.network.name,
        network=network,
        algo=recipe.algo,
        settings=_plain(dataclasses.asdict(settings) if dataclasses.is_dataclass(settings) else {}),
        device=recipe.device,
        seed=recipe.seed,
        robots=robot_record(train, tests),
        plugins=plugins.identities(),
        train_robots=tuple(train),
        test_robots=tuple(tests),
        lookups=lookups,
    )
