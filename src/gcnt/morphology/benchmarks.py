"""Benchmarks (named train/test robot sets) and robot look-up by name, file or benchmark.

The robot files and split files live in the repository's ``morphologies/`` folder, or wherever the
environment variable ``GCNT_MORPHOLOGIES`` points. ``BENCHMARKS`` (read lazily on first access)
maps a benchmark name to ``{"train": [...], "test": [...]}``.
"""

from __future__ import annotations

import difflib
import functools
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml

from gcnt.morphology.robot import Robot, load_robot
from gcnt.morphology.smpenv import SMPENV_ROBOTS

#: Environment variable that overrides the location of the ``morphologies/`` folder.
MORPHOLOGIES_ENV = "GCNT_MORPHOLOGIES"
#: The benchmark split file inside the morphologies folder.
SMPENV_BENCHMARKS_FILE = "smpenv.yaml"
#: Splits of every benchmark; ``Benchmark:all`` in :func:`resolve_robots` means train + test.
SPLITS: tuple[str, ...] = ("train", "test")
DEFAULT_SPLIT = "train"


class UnknownRobotError(ValueError):
    """A robot or benchmark name that is not known; the message lists close matches."""


class BenchmarkFileError(ValueError):
    """A malformed benchmark split file; the message names the file and the culprit."""


def morphologies_dir() -> Path:
    """``$GCNT_MORPHOLOGIES`` if set, else the repository's ``morphologies/`` folder."""
    env = os.environ.get(MORPHOLOGIES_ENV)
    path = Path(env) if env else Path(__file__).resolve().parents[3] / "morphologies"
    if not path.is_dir():
        where = f"${MORPHOLOGIES_ENV}={env}" if env else "the repository's morphologies/ folder"
        raise FileNotFoundError(
            f"morphologies folder {path} ({where}) does not exist; set {MORPHOLOGIES_ENV} to the "
            "folder that holds smpenv.yaml and smpenv/*.xml (run `gcnt robots --rebuild` to "
            "regenerate the robot files)"
        )
    return path


def _close(name: str, candidates: Sequence[str]) -> str:
    close = difflib.get_close_matches(name, candidates, n=5, cutoff=0.5)
    return f"; did you mean {', '.join(close)}?" if close else ""


def _validate(raw: Any, source: Path) -> dict[str, dict[str, list[str]]]:
    if not isinstance(raw, dict) or not raw:
        raise BenchmarkFileError(f"{source}: expected a mapping of benchmark name -> splits")
    known = set(SMPENV_ROBOTS)
    out: dict[str, dict[str, list[str]]] = {}
    for bench, splits in raw.items():
        if not isinstance(splits, dict):
            raise BenchmarkFileError(f"{source}: benchmark {bench!r} must map train/test to lists")
        extra = set(splits) - set(SPLITS)
        if extra:
            raise BenchmarkFileError(
                f"{source}: benchmark {bench!r} has unknown keys {sorted(extra)}; "
                f"allowed: {', '.join(SPLITS)}"
            )
        if "train" not in splits:
            raise BenchmarkFileError(f"{source}: benchmark {bench!r} has no train split")
        out[str(bench)] = {}
        for split in SPLITS:
            robots = splits.get(split) or []
            if not isinstance(robots, list) or not all(isinstance(r, str) for r in robots):
                raise BenchmarkFileError(f"{source}: {bench}:{split} must be a list of robot names")
            unknown = [r for r in robots if r not in known]
            if unknown:
                hints = "; ".join(f"{r!r}{_close(r, SMPENV_ROBOTS)}" for r in unknown)
                raise BenchmarkFileError(f"{source}: {bench}:{split} names unknown robots: {hints}")
            dupes = sorted({r for r in robots if robots.count(r) > 1})
            if dupes:
                raise BenchmarkFileError(f"{source}: {bench}:{split} lists {dupes} twice")
            out[str(bench)][split] = list(robots)
        both = set(out[str(bench)]["train"]) & set(out[str(bench)]["test"])
        if both:
            raise BenchmarkFileError(
                f"{source}: benchmark {bench!r} has robots in both train and test: {sorted(both)}"
            )
    return out


@functools.lru_cache(maxsize=8)
def _read_benchmarks(path: Path) -> dict[str, dict[str, list[str]]]:
    try:
        raw = yaml.safe_load(path.read_text())
    except OSError as e:
        raise BenchmarkFileError(f"{path}: cannot read benchmark file ({e.strerror})") from e
    except yaml.YAMLError as e:
        raise BenchmarkFileError(f"{path}: not valid YAML ({e})") from e
    return _validate(raw, path)


def load_benchmarks(path: str | Path | None = None) -> dict[str, dict[str, list[str]]]:
    """Benchmark name -> {"train": [robot names], "test": [robot names]} (a fresh copy).

    ``path`` defaults to ``<morphologies_dir()>/smpenv.yaml``.
    """
    path = Path(path) if path is not None else morphologies_dir() / SMPENV_BENCHMARKS_FILE
    return {b: {s: list(r) for s, r in sp.items()} for b, sp in _read_benchmarks(path).items()}


def __getattr__(name: str) -> Any:
    # BENCHMARKS is read on first access, so that importing this module needs no files.
    if name == "BENCHMARKS":
        return load_benchmarks()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


@functools.lru_cache(maxsize=128)
def smpenv_robot(name: str) -> Robot:
    """The checked-in SMPENV robot ``name`` (``morphologies/smpenv/<name>.xml``), cached."""
    if name not in SMPENV_ROBOTS:
        raise UnknownRobotError(f"unknown SMPENV robot {name!r}{_close(name, SMPENV_ROBOTS)}")
    return load_robot(morphologies_dir() / "smpenv" / f"{name}.xml")


def _benchmark_robots(spec: str) -> list[Robot]:
    bench_name, _, split = spec.partition(":")
    benchmarks = load_benchmarks()
    if bench_name not in benchmarks:
        raise UnknownRobotError(
            f"unknown benchmark {bench_name!r} in {spec!r}{_close(bench_name, list(benchmarks))} "
            f"(known: {', '.join(benchmarks)})"
        )
    split = split or DEFAULT_SPLIT
    if split == "all":
        names = benchmarks[bench_name]["train"] + benchmarks[bench_name]["test"]
    elif split in SPLITS:
        names = benchmarks[bench_name][split]
    else:
        raise UnknownRobotError(
            f"unknown split {split!r} in {spec!r}; use one of {', '.join(SPLITS)}, all"
        )
    return [smpenv_robot(n) for n in names]


def resolve_robots(specs: Sequence[str]) -> list[Robot]:
    """Robots from specs, in order and without repeats. A spec is one of:

    * a robot name, e.g. ``walker_3_main``;
    * a path to an MJCF file, e.g. ``my_robots/walker_long.xml``;
    * ``Benchmark:split``, e.g. ``CWHH++:train`` or ``Walker++:test`` (split defaults to
      ``train``; ``all`` means train then test).
    """
    if isinstance(specs, str):
        specs = [specs]
    robots: list[Robot] = []
    seen: set[str] = set()
    for spec in specs:
        found: list[Robot]
        if spec in SMPENV_ROBOTS:
            found = [smpenv_robot(spec)]
        elif spec.endswith(".xml") or os.sep in spec or Path(spec).is_file():
            found = [load_robot(spec)]
        elif ":" in spec or spec.endswith("++") or spec in load_benchmarks():
            found = _benchmark_robots(spec)
        else:
            benchmarks = list(load_benchmarks())
            raise UnknownRobotError(
                f"unknown robot {spec!r}{_close(spec, list(SMPENV_ROBOTS) + benchmarks)} "
                f"(a spec is a robot name, an .xml path, or one of "
                f"{', '.join(b + ':train|test' for b in benchmarks)})"
            )
        for r in found:
            if r.source not in seen:
                seen.add(r.source)
                robots.append(r)
    return robots
