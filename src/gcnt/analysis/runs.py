"""Find run directories and read what they hold, defensively (the recipe is read as a plain dict).

A run directory, as ``gcnt train`` writes it::

    recipe.yaml            the resolved recipe
    metrics.jsonl          one JSON row per log step: env_steps, train_return/mean, ...
                           (a non-finite value is ``null``; read back as NaN)
    checkpoints/last.pt    the latest checkpoint
    eval/*.json            evaluations: {"env_steps": N, "robots": {name: {"mean", ...}}, ...}

The run-reading core (:class:`Run`, :class:`EvalRecord`, what makes runs seeds of one
experiment) is :mod:`gcnt.run.data`, below :mod:`gcnt.rl` and this package; this module adds
finding runs and ordering and naming methods.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from pathlib import Path

from gcnt.run.data import (  # noqa: F401 (the analysis modules read them from here)
    CHECKPOINT,
    METRICS_FILE,
    NOT_THE_EXPERIMENT,
    RECIPE_FILE,
    AnalysisError,
    EvalRecord,
    InitFromCycleError,
    Run,
    check_run_recipe,
    protocol_text,
    protocols_text,
    recipe_defaults,
    score,
)
from gcnt.suggest import existing_path

#: the order methods are listed and coloured in (others follow, sorted)
METHOD_ORDER = (
    "gcnt",
    "gcnt_no_gcn",
    "gcnt_no_wl",
    "gcnt_no_dist",
    "gcnt_dist_first",
    "gcnt_gcn_context",
    "swat",
    "amorpheus",
    "smp",
    "mlp",
)
#: single-robot references, listed after every other method (paper figure 7's SR lines)
REFERENCE_ORDER = ("sr", "SR-fair", "SR-top")


def find_runs(paths: Iterable[str | Path]) -> list[Run]:
    """Every run directory in ``paths`` (run directories, or folders searched recursively)."""
    runs: dict[Path, Run] = {}
    paths = list(paths)
    for p in map(Path, paths):
        if not p.exists():
            try:
                existing_path(str(p), "run or sweep directory")
            except FileNotFoundError as e:
                raise AnalysisError(str(e)) from None
        if (p / RECIPE_FILE).is_file():
            runs[p.resolve()] = Run(p)
            continue
        for recipe in sorted(p.rglob(RECIPE_FILE)):
            if "wandb" in recipe.parts:
                continue
            runs.setdefault(recipe.parent.resolve(), Run(recipe.parent))
    if not runs:
        raise AnalysisError(
            f"no run directories (with {RECIPE_FILE}) under {', '.join(map(str, paths))}"
        )
    return sorted(runs.values(), key=lambda r: (r.task, method_key(r.method), r.seed, str(r.path)))


def first_seed_per_method(runs: Sequence[Run]) -> list[Run]:
    """One run per (task, algorithm, method): the first one listed."""
    first: dict[tuple[str, str, str], Run] = {}
    for r in runs:
        first.setdefault((r.task, r.algo, r.method), r)
    return list(first.values())


def method_key(method: str) -> tuple[int, str]:
    """The place of ``method`` in :data:`METHOD_ORDER` (a method's experiments told apart,
    ``gcnt [collector.total_frames=24000]``, at the method's place)."""
    base = method.split(" [", 1)[0]
    if base in REFERENCE_ORDER:
        return (len(METHOD_ORDER) + 1 + REFERENCE_ORDER.index(base), method)
    return (METHOD_ORDER.index(base) if base in METHOD_ORDER else len(METHOD_ORDER), method)


def method_labels(runs: Sequence[Run]) -> dict[Path, str]:
    """The name a run's method is shown under: the recipe's ``label`` if it has one (SR-fair),
    else the method; prefixed by the algorithm when the runs mix algorithms (``ppo:gcnt``)."""
    mixed = len({r.algo for r in runs}) > 1
    return {r.path: f"{r.algo}:{r.label}" if mixed else r.label for r in runs}


def mean_stderr(values: Sequence[float]) -> tuple[float, float]:
    """Mean and standard error (n-1); the error is nan for one value."""
    xs = [float(v) for v in values]
    n = len(xs)
    if n == 0:
        return math.nan, math.nan
    mean = sum(xs) / n
    if n == 1:
        return mean, math.nan
    var = sum((x - mean) ** 2 for x in xs) / (n - 1)
    return mean, math.sqrt(var / n)


def default_out(paths: Sequence[str | Path]) -> Path:
    """Where figures go by default: for one run directory given, ``<run>-figures`` beside it (a
    run received from someone is read, never written into); for one other directory (a
    sweep's), ``<dir>/figures``; else ``figures``."""
    if len(paths) == 1 and (Path(paths[0]) / RECIPE_FILE).is_file():
        run = Path(paths[0])
        run = run.resolve() if run.name in ("", ".", "..") else run
        return run.with_name(f"{run.name}-figures") if run.name else Path("figures")
    if len(paths) == 1 and Path(paths[0]).is_dir():
        out = Path(paths[0]) / "figures"
        if out.is_symlink() or (
            out.exists() and not out.resolve().is_relative_to(Path(paths[0]).resolve())
        ):
            raise AnalysisError(
                f"{out}: a link out of {paths[0]}; figures are written there only when it is "
                "inside (remove the link, or give --out)"
            )
        return out
    return Path("figures")
