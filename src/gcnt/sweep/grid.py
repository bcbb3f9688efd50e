"""The grid of a sweep: recipes x methods x seeds (or x robots, ``--per-robot``) expanded into
:class:`~gcnt.sweep.spec.RunSpec` s, with each run's directory, overrides and W&B names: the
group ``<sweep>/<task>/<algo>-<method>``, the tag ``sweep:<sweep>`` (and ``seed:N``, which every
run gets)."""

from __future__ import annotations

import json
import logging
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from gcnt.sweep.spec import RunSpec
from gcnt.sweep.status import SweepError, slug

log = logging.getLogger(__name__)

if TYPE_CHECKING:
    from gcnt.recipes import Recipe


def _method_override(override: str) -> tuple[str, str] | None:
    """``METHOD:key=value`` -> (METHOD, ``key=value``); a plain override -> None."""
    head, sep, rest = override.partition(":")
    if sep and "=" in rest and "=" not in head and "." not in head:
        return head, rest
    return None


def _split_method_overrides(
    overrides: Sequence[str], methods: Sequence[str]
) -> dict[str, list[str]]:
    """``METHOD:key=value`` applies to that method only; plain ``key=value`` to all."""
    per: dict[str, list[str]] = {m: [] for m in methods}
    for o in overrides:
        if (split := _method_override(o)) is not None:
            head, rest = split
            if head not in per:
                raise SweepError(
                    f"override {o!r} names method {head!r}, which is not in the sweep "
                    f"({', '.join(methods)})"
                )
            per[head].append(rest)
        else:
            for m in methods:
                per[m].append(o)
    return per


def per_robot_runs(split: str | Sequence[str]) -> list[tuple[str, str]]:
    """(robot name, spec to train it alone) for each robot of ``split``: a robot spec as
    ``env.robots`` takes it (``Unimal:train``, ``CWHH++:test``, a robot name, an .xml file or
    folder), or several, comma-separated or as a list."""
    from gcnt.morphology import resolve_robots
    from gcnt.morphology.catalogues import robot_catalogue

    specs = [t.strip() for t in split.split(",")] if isinstance(split, str) else list(split)
    specs = [s for s in specs if s]
    if not specs:
        raise SweepError("--per-robot: give a robot split, e.g. Unimal:train")
    try:
        robots = resolve_robots(specs)
    except (ValueError, OSError) as e:
        raise SweepError(f"--per-robot {','.join(specs)}: {e}") from None
    # a catalogue robot by its name; a robot loaded from a file by that file
    return [(r.name, r.name if robot_catalogue(r.name) else r.source) for r in robots]


def robot_overrides(spec: str) -> list[str]:
    """The overrides that train one robot alone (JSON strings are YAML scalars: paths quoted)."""
    return [f"env.robots=[{json.dumps(spec)}]", "env.test_robots=[]"]


def _sets_robots(override: str) -> bool:
    split = _method_override(override)
    key = (split[1] if split else override).split("=", 1)[0].strip()
    return key in ("env.robots", "env.test_robots", "env")


def expand(
    recipes: Sequence[str | Path],
    sweep_dir: str | Path,
    *,
    methods: Sequence[str] | None = None,
    seeds: Sequence[int] | None = None,
    overrides: Sequence[str] = (),
    evals: Sequence[str] = (),
    eval_episodes: int | None = None,
    eval_deterministic: bool | None = None,
    group: str | None = None,
    per_robot: str | Sequence[str] | None = None,
) -> list[RunSpec]:
    """The runs of recipes x methods x [robots] x seeds (default: each recipe's own method and
    seed). With ``per_robot`` (a robot split, see :func:`per_robot_runs`), one run per robot of
    the split, each trained alone.

    Each combination is loaded and checked now as its run would check it before starting
    (:func:`gcnt.rl.loop.check_recipe`: the method, benchmark, robots, sizes...), and so is each
    robot spec of ``evals``, so that a mistake fails before anything runs (a :class:`SweepError`
    naming it). The plugins of a recipe given here (its ``plugins:`` key) are imported and join
    this command's (``--plugin``, GCNT_PLUGINS), which the runs' processes, here or on a
    cluster, are given by ``--plugin`` (:func:`gcnt.sweep.spec.gcnt_command`); the manifest
    records none, so a sweep continued elsewhere imports only what its command names.
    """
    from gcnt.recipes import (
        RecipeError,
        import_recipe_plugins,
        read_recipe_file,
        recipe_from_dict,
    )

    sweep_dir = Path(sweep_dir).resolve()
    group = group or sweep_dir.name
    robots: list[tuple[str | None, list[str]]] = [(None, [])]
    if per_robot is not None:
        if bad := [o for o in overrides if _sets_robots(o)]:
            raise SweepError(
                f"--per-robot sets env.robots and env.test_robots of every run; drop {bad[0]!r}"
            )
        if "test" in evals:
            raise SweepError("--per-robot runs have no test robots: --eval test evaluates nothing")
        robots = [(name, robot_overrides(spec)) for name, spec in per_robot_runs(per_robot)]
    specs: list[RunSpec] = []
    seen: dict[str, str] = {}
    missing: set[str] = set()  # fine-tunes' sources not made yet, each said once
    lookups: dict = {}  # robot specs looked up for the runs' checks: each spec once per sweep
    for recipe_path in recipes:
        recipe_path = Path(recipe_path)
        if not recipe_path.is_file():
            raise SweepError(f"{recipe_path}: no such recipe file")
        source = str(recipe_path)
        try:
            data = read_recipe_file(recipe_path)  # read once: a per-robot sweep loads it often
            data = import_recipe_plugins(data, source)
            base = recipe_from_dict(data, [*_plain(overrides), *robots[0][1]], source)
        except RecipeError as e:
            raise SweepError(str(e)) from None
        ms = list(methods or [base.network.name])
        per_method = _split_method_overrides(overrides, ms)
        for m in ms:
            for robot, robot_ovr in robots:
                for s in seeds if seeds is not None else [base.seed]:
                    given = [
                        *per_method[m], *robot_ovr, f"network.name={m}", f"seed={s}"
                    ]  # fmt: skip
                    try:
                        r = recipe_from_dict(data, given, source)
                    except RecipeError as e:
                        raise SweepError(str(e)) from None
                    _check_run(r, source, m, evals, lookups)
                    _fine_tune_task(r, missing)
                    spec = _spec(recipe_path, r, m, robot, given, sweep_dir, group, seen)
                    spec.evals, spec.eval_episodes = list(evals), eval_episodes
                    spec.eval_deterministic = eval_deterministic
                    specs.append(spec)
    if not specs:
        raise SweepError("the sweep has no runs (no recipes?)")
    return specs


def _check_run(
    r: Recipe, source: str, method: str, evals: Sequence[str], lookups: dict | None = None
) -> None:
    """What the run of ``r`` (method ``method`` of recipe ``source``) would refuse when it
    starts, and the robots its evaluations ``evals`` name: a SweepError naming the recipe
    (``lookups``: the robot specs the sweep looked up already, for every run's check)."""
    from gcnt.rl.evaluate import check_eval_robots
    from gcnt.rl.loop import check_recipe

    try:
        check_recipe(r, lookups=lookups)
        for spec in evals:
            if spec == "test" and not r.env.test_robots:
                raise ValueError("--eval test: the recipe has no test robots (env.test_robots)")
            if spec == "train":
                continue
            check_eval_robots(r, r.env.test_robots if spec == "test" else [spec])
    except (ValueError, OSError) as e:  # RecipeError, the robot errors, a missing file
        raise SweepError(f"{source} (method {method}): {e}") from None


def _fine_tune_task(r: Recipe, missing: set[str]) -> None:
    """A fine-tune's folder is its own task's (``<source task>-ft``), as ``gcnt train`` names
    it; where the source run does not exist yet (a sweep set up before the one it fine-tunes
    from has run) the recipe's task stays, said once per source (``missing``: those said)."""
    from gcnt.recipes import RecipeError
    from gcnt.rl.init_from import own_task

    try:
        own_task(r)
    except (RecipeError, FileNotFoundError):
        if r.init_from not in missing:
            missing.add(r.init_from)
            log.warning(
                "init_from %s does not exist yet: its fine-tunes go under task %s here (gcnt "
                "train records the task <source task>-ft when it runs)",
                r.init_from,
                r.task,
            )


def _spec(
    recipe_path: Path,
    r: Recipe,
    method: str,
    robot: str | None,
    given: list[str],
    sweep_dir: Path,
    group: str,
    seen: dict[str, str],
) -> RunSpec:
    task, algo, seed = str(r.task or "custom"), str(r.algo), int(r.seed)
    shown = slug(r.label) if r.label else method
    run_id = f"{slug(task)}/{algo}-{shown}/{'' if robot is None else slug(robot) + '/'}seed{seed}"
    if run_id in seen:
        raise SweepError(
            f"{recipe_path} and {seen[run_id]} give the same run {run_id}: "
            "give the recipes different task names (task=...) or labels (label=...)"
        )
    seen[run_id] = str(recipe_path)
    run_dir = sweep_dir / run_id
    name = "-".join([task, algo, r.label or method, *([robot] if robot else []), f"seed{seed}"])
    # W&B: one group per task and method (its seeds, and robots of a per-robot sweep, averaged
    # together), every run tagged with the sweep
    group = f"{group}/{slug(task)}/{algo}-{shown}"
    sweep_tag = f"sweep:{sweep_dir.name}"[:64]  # W&B's longest tag
    tags = list(dict.fromkeys([*r.logger.tags, sweep_tag]))
    return RunSpec(
        id=run_id,
        run_dir=str(run_dir),
        recipe=str(recipe_path.resolve()),
        task=task,
        algo=algo,
        method=method,
        seed=seed,
        overrides=[
            *given,
            f"run_dir={run_dir}",
            f"logger.group={json.dumps(group)}",
            f"logger.name={json.dumps(name)}",
            f"logger.tags={json.dumps(tags)}",
        ],
        robot=robot,
    )


def default_dir(
    recipes: Sequence[str | Path],
    overrides: Sequence[str] = (),
    per_robot: str | Sequence[str] | None = None,
) -> Path:
    """``sweeps/<task>`` (the recipes' tasks joined by ``-``)."""
    from gcnt.recipes import RecipeError, load_recipe

    given = _plain(overrides)
    if per_robot is not None:  # a single-robot recipe on its first robot
        given += robot_overrides(per_robot_runs(per_robot)[0][1])
    tasks = []
    for r in recipes:
        try:
            rec = load_recipe(r, given)
        except RecipeError as e:
            raise SweepError(str(e)) from None
        tasks.append(slug(str(rec.task or "x")))
    return Path("sweeps") / "-".join(dict.fromkeys(tasks))


def _plain(overrides: Sequence[str]) -> list[str]:
    """Overrides that apply to every method (``METHOD:key=value`` ones left out)."""
    return [o for o in overrides if _method_override(o) is None]
