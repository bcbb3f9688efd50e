"""Robot catalogues, benchmarks (named robot splits) and robot look-up by name, file or benchmark.

A *catalogue* is one set of robots that gcnt can load by name (SMPENV's 32 robots; UNIMAL's
generated robots and their variants; or one of your own). It is a small :class:`Catalogue` record:
its name, the robot names it knows, how to load one, and its benchmark split file. Register your
own without editing gcnt::

    register_catalogue(Catalogue(name="toy", robot_names=lambda: ["toy_1"], load=load_toy,
                                 split_file="/path/to/toy.yaml"))

A split file maps a benchmark name to its splits: ``train`` (required), ``test``, and any
``variants-<kind>`` lists. Names, ``Benchmark:split`` specs, ``.xml`` paths and folders of ``.xml``
files resolve through every catalogue (:func:`resolve_robots`).

The built-in catalogues' robot and split files ship with gcnt (:func:`morphologies_dir`); robot
sets of the user's own (``gcnt import-unimal``) live in the user's folder
(:func:`gcnt.data_folders.user_morphologies`, ``$GCNT_MORPHOLOGIES``) and are added to them.
"""

from __future__ import annotations

import dataclasses
import fnmatch
import functools
import importlib
import logging
import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from gcnt.data_folders import packaged_morphologies, user_morphologies
from gcnt.files import read_yaml
from gcnt.morphology.catalogue_base import (
    IMPORTED_INDEX,
    MAX_SPLIT_FILE_BYTES,
    BenchmarkFileError,
    Catalogue,
    morphologies_dir,
    stale_files,
)
from gcnt.morphology.robot import Robot, load_robot
from gcnt.morphology.smpenv import SMPENV_ROBOTS, build_mjcf, write_all
from gcnt.morphology.unimal.imported_set import DEFAULT_NAME, imported_catalogue
from gcnt.suggest import did_you_mean

#: The SMPENV benchmark split file inside the morphologies folder.
SMPENV_BENCHMARKS_FILE = "smpenv.yaml"
#: The two main splits; ``Benchmark:all`` in :func:`resolve_robots` means train + test.
SPLITS: tuple[str, ...] = ("train", "test")
#: Further split names a split file may declare: ``variants-<kind>``.
VARIANT_SPLIT = re.compile(r"^variants-[a-z0-9_]+$")
DEFAULT_SPLIT = "train"

log = logging.getLogger(__name__)


class UnknownRobotError(ValueError):
    """A robot or benchmark name that is not known; the message lists close matches."""


class DuplicateRobotError(ValueError):
    """The same robot named twice in one robot list."""


# ------------------------------------------------------------------------------ catalogues


_REGISTRY: dict[str, Catalogue] = {}
#: built-in catalogues, imported on first use
_BUILTIN: dict[str, str] = {
    "smpenv": "gcnt.morphology.catalogues:SMPENV_CATALOGUE",
    "unimal": "gcnt.morphology.unimal.catalogue:UNIMAL_CATALOGUE",
    "mjcf3d": "gcnt.morphology.mjcf3d:MJCF3D_CATALOGUE",
}


def _clear_caches() -> None:
    _usable_imports.cache_clear()
    _warn_shadowing.cache_clear()
    _name_index.cache_clear()
    _file_index.cache_clear()
    _load.cache_clear()
    _read_benchmarks.cache_clear()


def register_catalogue(catalogue: Catalogue, *, replace: bool = False) -> Catalogue:
    """Make ``catalogue`` resolvable (``replace`` to redefine one of yours; a built-in one is
    never replaced)."""
    if catalogue.name in _BUILTIN:
        raise ValueError(
            f"catalogue {catalogue.name!r} is built into gcnt and cannot be replaced; register "
            "yours under a name of its own"
        )
    if not replace and (catalogue.name in _REGISTRY or catalogue.name in _BUILTIN):
        raise ValueError(f"catalogue {catalogue.name!r} is already registered")
    _REGISTRY[catalogue.name] = catalogue
    _clear_caches()
    return catalogue


def unregister_catalogue(name: str) -> None:
    """Forget catalogue ``name`` (tests use it to remove a toy catalogue)."""
    _REGISTRY.pop(name, None)
    _clear_caches()


def refresh_catalogues() -> None:
    """Forget the cached robot names, robots and split files (after catalogue files changed)."""
    _clear_caches()


def imported_catalogues(root: Path | None = None) -> dict[str, Path]:
    """Catalogues imported into the morphologies folder ``root`` (default: the ones gcnt reads,
    its own and then the user's, :func:`gcnt.data_folders.user_morphologies`): name -> folder.
    Hidden folders (an import under way) are left out, and so is a folder whose robot or
    benchmark names are already those of a catalogue before it (a backup copy of an imported
    folder, say), with a warning naming both folders."""
    roots = [root] if root is not None else [packaged_morphologies(), user_morphologies()]
    if root is None:
        _warn_shadowing(user_morphologies())
    found = [
        p.parent for r in roots for p in sorted(Path(r).absolute().glob(f"*/{IMPORTED_INDEX}"))
    ]
    return _usable_imports(tuple(p for p in found if not p.name.startswith(".")))


def read_split_file(path: Path) -> Any:
    """The YAML value of a split file, read through :func:`gcnt.files.read_yaml` (a FIFO, a
    device or a file too large or nested too deep is a BenchmarkFileError naming it)."""
    return read_yaml(
        path, MAX_SPLIT_FILE_BYTES, "a benchmark split file is YAML", BenchmarkFileError
    )


def split_keys(path: Path | None) -> list[str]:
    """The benchmark names of a split file, as written (unreadable: none)."""
    try:
        raw = read_split_file(path) if path is not None else None
    except BenchmarkFileError:
        return []
    return [str(k) for k in raw] if isinstance(raw, dict) else []


def _import_damage(folder: Path, robots: Sequence[str]) -> str | None:
    """Why the imported folder cannot be read (its split file unreadable, or naming a robot
    whose file is gone), or None."""
    try:
        raw = read_split_file(folder / IMPORTED_INDEX)
    except BenchmarkFileError as e:
        return str(e)
    if not isinstance(raw, dict) or not raw:
        return f"{folder / IMPORTED_INDEX}: not a mapping of benchmark name -> splits"
    have = set(robots)
    for bench, splits in raw.items():
        for split, names in (splits or {}).items() if isinstance(splits, dict) else ():
            gone = [n for n in names or [] if isinstance(n, str) and n not in have]
            if gone:
                return f"{bench}:{split} names {gone[0]!r}, whose robot file is missing"
    return None


@functools.lru_cache(maxsize=8)
def _usable_imports(folders: tuple[Path, ...]) -> dict[str, Path]:
    owner: dict[str, str] = {}  # robot name -> what defines it
    #: catalogue and benchmark names, case-folded (one name whatever its case) -> what defines it
    named: dict[str, str] = {}
    for name in [*_BUILTIN, *_REGISTRY]:
        cat = get_catalogue(name)
        try:
            split = cat.split_path()
        except FileNotFoundError:
            split = None
        named.setdefault(name.casefold(), f"catalogue {name!r}")
        for key in cat.robot_names():
            owner.setdefault(key, f"catalogue {name!r}")
        for key in split_keys(split):
            named.setdefault(key.casefold(), f"catalogue {name!r}")
    out: dict[str, Path] = {}
    for folder in folders:
        cat = imported_catalogue(folder)
        robots = list(cat.robot_names())
        damage = _import_damage(folder, robots)
        if damage is not None:
            log.warning(
                "%s is left out: %s; import the set again (remove the folder first)",
                folder,
                damage,
            )
            continue
        names = [folder.name, *split_keys(folder / IMPORTED_INDEX)]
        clash = next((k for k in [folder.name, *robots] if k in owner), None)
        if clash is not None:
            by = owner[clash]
        elif (clash := next((k for k in names if k.casefold() in named), None)) is not None:
            by = named[clash.casefold()]
        if clash is not None:
            log.warning(
                "%s is left out: %r is already defined by %s (catalogue and benchmark names "
                "are one whatever their case); remove or rename one of them",
                folder,
                clash,
                by,
            )
            continue
        out[folder.name] = folder
        owner.update((key, str(folder)) for key in robots)
        named.update((key.casefold(), str(folder)) for key in names)
    return out


@functools.lru_cache(maxsize=8)
def _warn_shadowing(root: Path) -> None:
    """A warning for each folder of the user's robot-set folder ``root`` named after a built-in
    catalogue (whatever its case): gcnt never reads it as that catalogue."""
    try:
        entries = sorted(p for p in root.iterdir() if p.is_dir())
    except OSError:
        return
    for folder in entries:
        same = next((b for b in _BUILTIN if b.casefold() == folder.name.casefold()), None)
        if same is not None:
            log.warning(
                "%s is not read: %r is gcnt's built-in catalogue, whose robots come with gcnt; "
                "give a robot set of your own a name of its own",
                folder,
                same,
            )


def catalogue_names() -> list[str]:
    return list(dict.fromkeys([*_BUILTIN, *_REGISTRY, *imported_catalogues()]))


def get_catalogue(name: str) -> Catalogue:
    """The catalogue ``name``; a ValueError with close matches otherwise."""
    if name not in _REGISTRY and name in _BUILTIN:
        module, attr = _BUILTIN[name].split(":")
        _REGISTRY.setdefault(name, getattr(importlib.import_module(module), attr))
    if name not in _REGISTRY and (folder := imported_catalogues().get(name)) is not None:
        return imported_catalogue(folder)  # read afresh: the morphologies folder may change
    if name not in _REGISTRY:
        raise ValueError(
            f"unknown catalogue {name!r}{did_you_mean(name, catalogue_names())} "
            f"(known: {', '.join(catalogue_names())})"
        )
    return _REGISTRY[name]


def catalogues() -> list[Catalogue]:
    return [get_catalogue(n) for n in catalogue_names()]


@functools.lru_cache(maxsize=1)
def _name_index() -> dict[str, str]:
    index: dict[str, str] = {}
    for cat in catalogues():
        for name in cat.robot_names():
            if name in index and index[name] != cat.name:
                raise ValueError(
                    f"robot name {name!r} is in both catalogue {index[name]!r} and {cat.name!r}"
                )
            index[name] = cat.name
    return index


@functools.lru_cache(maxsize=1)
def _file_index() -> dict[str, str]:
    """Resolved path -> catalogue robot name, for the files of :attr:`Catalogue.file_names`."""
    return {
        path: name
        for cat in catalogues()
        if cat.file_names
        for path, name in cat.file_names().items()
    }


def _is_pattern(spec: str) -> bool:
    return any(c in spec for c in "*?[") and ":" not in spec and os.sep not in spec


def _matching_names(pattern: str) -> list[str]:
    names = [n for n in _name_index() if fnmatch.fnmatchcase(n, pattern)]
    if not names:
        raise UnknownRobotError(f"no robot name matches the pattern {pattern!r}")
    return names


def robot_catalogue(name: str) -> str | None:
    """The catalogue that knows robot ``name``, or None."""
    return _name_index().get(name)


@functools.lru_cache(maxsize=2048)
def _load(catalogue: str, name: str) -> Robot:
    return get_catalogue(catalogue).load(name)


#: robot spec -> its robots as (name, stored file, family, catalogue): a run's own copies of
#: robots not registered here (:func:`gcnt.run.record.use_stored_robots`), resolved first
_PINNED: dict[str, tuple[tuple[str, Path, str | None, str | None], ...]] = {}


def pin_robots(spec: str, robots: Sequence[tuple[str, Path, str | None, str | None]]) -> None:
    """Resolve ``spec`` to ``robots`` from now on in this process: each a (name, MJCF file,
    family, catalogue), read from that file (a run's stored copy) as that family of that
    catalogue, under that name."""
    _PINNED[spec] = tuple((n, Path(p), f, c) for n, p, f, c in robots)


@functools.lru_cache(maxsize=2048)
def _load_pinned(name: str, path: Path, family: str | None, catalogue: str | None) -> Robot:
    robot = load_robot(path, catalogue=catalogue, family=family)
    return dataclasses.replace(robot, name=name)


def load_named(name: str) -> Robot:
    """The robot ``name`` from whichever catalogue knows it (cached)."""
    cat = robot_catalogue(name)
    if cat is None:
        raise UnknownRobotError(f"unknown robot {name!r}{did_you_mean(name, _name_index())}")
    return _load(cat, name)


# ------------------------------------------------------------------------------ SMPENV


def smpenv_robot(name: str) -> Robot:
    """The checked-in SMPENV robot ``name`` (``morphologies/smpenv/<name>.xml``), cached."""
    if name not in SMPENV_ROBOTS:
        raise UnknownRobotError(f"unknown SMPENV robot {name!r}{did_you_mean(name, SMPENV_ROBOTS)}")
    return _load("smpenv", name)


def _smpenv_check(root: Path) -> list[str]:
    expected = {f"smpenv/{name}.xml": build_mjcf(name) for name in SMPENV_ROBOTS}
    return stale_files(root, expected, "smpenv", "builder", "an SMPENV robot")


SMPENV_CATALOGUE = Catalogue(
    name="smpenv",
    robot_names=lambda: SMPENV_ROBOTS,
    load=lambda name: load_robot(morphologies_dir() / "smpenv" / f"{name}.xml", "smpenv"),
    split_file=SMPENV_BENCHMARKS_FILE,
    rebuild=lambda root: write_all(root / "smpenv"),
    check=_smpenv_check,
    description="the 32 SMPENV robots (walker, cheetah, humanoid_2d, hopper)",
)


# ------------------------------------------------------------------------------ split files


def _validate(raw: Any, source: Path, known: dict[str, str]) -> dict[str, dict[str, list[str]]]:
    if not isinstance(raw, dict) or not raw:
        raise BenchmarkFileError(f"{source}: expected a mapping of benchmark name -> splits")
    out: dict[str, dict[str, list[str]]] = {}
    for bench, splits in raw.items():
        if not isinstance(splits, dict):
            raise BenchmarkFileError(f"{source}: benchmark {bench!r} must map train/test to lists")
        extra = [s for s in splits if s not in SPLITS and not VARIANT_SPLIT.match(str(s))]
        if extra:
            raise BenchmarkFileError(
                f"{source}: benchmark {bench!r} has unknown keys {sorted(extra)}; "
                f"allowed: {', '.join(SPLITS)}, variants-<kind>"
            )
        if "train" not in splits:
            raise BenchmarkFileError(f"{source}: benchmark {bench!r} has no train split")
        out[str(bench)] = {}
        for split in [*SPLITS, *(s for s in splits if s not in SPLITS)]:
            robots = splits.get(split) or []
            if not isinstance(robots, list) or not all(isinstance(r, str) for r in robots):
                raise BenchmarkFileError(f"{source}: {bench}:{split} must be a list of robot names")
            unknown = [r for r in robots if r not in known]
            if unknown:
                hints = "; ".join(f"{r!r}{did_you_mean(r, known)}" for r in unknown[:5])
                raise BenchmarkFileError(f"{source}: {bench}:{split} names unknown robots: {hints}")
            dupes = sorted({r for r in robots if robots.count(r) > 1})
            if dupes:
                raise BenchmarkFileError(f"{source}: {bench}:{split} lists {dupes} twice")
            out[str(bench)][str(split)] = list(robots)
        both = set(out[str(bench)]["train"]) & set(out[str(bench)]["test"])
        if both:
            raise BenchmarkFileError(
                f"{source}: benchmark {bench!r} has robots in both train and test: {sorted(both)}"
            )
    return out


@functools.lru_cache(maxsize=16)
def _read_benchmarks(path: Path) -> dict[str, dict[str, list[str]]]:
    return _validate(read_split_file(path), path, _name_index())


def load_benchmarks(
    path: str | Path | None = None, catalogue: str | None = None
) -> dict[str, dict[str, list[str]]]:
    """Benchmark name -> split name -> robot names (a fresh copy).

    ``path``: read that one split file. Otherwise the split files of every catalogue (or of
    ``catalogue`` only) together.
    """
    if path is not None:
        paths = [Path(path)]
    else:
        cats = [get_catalogue(catalogue)] if catalogue else catalogues()
        paths = [p for c in cats if (p := c.split_path()) is not None]
    out: dict[str, dict[str, list[str]]] = {}
    for p in paths:
        for bench, splits in _read_benchmarks(p).items():
            same = next((b for b in out if b.casefold() == bench.casefold()), None)
            if same is not None:
                also = "" if same == bench else f" (as {same!r}: names are one whatever their case)"
                raise BenchmarkFileError(
                    f"{p}: benchmark {bench!r} is also defined elsewhere{also}"
                )
            out[bench] = {s: list(r) for s, r in splits.items()}
    return out


def __getattr__(name: str) -> Any:
    # BENCHMARKS is read on first access, so that importing this module needs no files.
    if name == "BENCHMARKS":
        return load_benchmarks()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


# ------------------------------------------------------------------------------ resolution


def _benchmark_names(spec: str, benchmarks: dict[str, dict[str, list[str]]]) -> list[str]:
    bench_name, _, split = spec.partition(":")
    if bench_name not in benchmarks:  # another spelling of one benchmark (Mjcf3d for MJCF3D)
        same = [b for b in benchmarks if b.lower() == bench_name.lower()]
        bench_name = same[0] if len(same) == 1 else bench_name
    if bench_name not in benchmarks:
        if bench_name == DEFAULT_NAME:  # the paper's robots, not imported on this machine
            raise UnknownRobotError(
                f"{spec!r}: the benchmark {DEFAULT_NAME} (the paper's UNIMAL-100 robots) is not "
                "imported here; download MetaMorph's unimals_100.zip (the data link of its README) "
                "and run gcnt import-unimal unimals_100.zip"
            )
        raise UnknownRobotError(
            f"unknown benchmark {bench_name!r} in {spec!r}{did_you_mean(bench_name, benchmarks)} "
            f"(known: {', '.join(benchmarks)})"
        )
    splits = benchmarks[bench_name]
    split = split or DEFAULT_SPLIT
    if split == "all":
        return splits["train"] + splits["test"]
    if split not in splits:
        raise UnknownRobotError(
            f"unknown split {split!r} in {spec!r}{did_you_mean(split, [*splits, 'all'])}; "
            f"{bench_name} has splits {', '.join([*splits, 'all'])}"
        )
    return splits[split]


def _folder_robots(folder: Path) -> list[Robot]:
    files = sorted(folder.glob("*.xml"))
    if not files:
        raise UnknownRobotError(f"folder {folder} holds no .xml robot files")
    return [load_robot(f) for f in files]


def robot_identity(robot: Robot) -> tuple[str, ...]:
    """What tells robots apart: a robot read from a file is that file (resolved), read as its
    family with its text; a robot without a file (generated) is its name. A catalogue robot and
    the path of its file are thus one robot, and two files of one model name are two."""
    if Path(robot.source).is_file():
        return (os.path.realpath(robot.source), robot.family, robot.xml)
    return (robot.name,)


#: folder names that say what a folder holds, not whose files they are: never a name's prefix
GENERIC_FOLDERS = frozenset(
    {"xml", "xmls", "mjcf", "assets", "asset", "robots", "robot", "models", "model", "files",
     "data", "morphologies"}
)  # fmt: skip


def _folders(path: Path, generic: bool = False) -> list[str]:
    """The folders of ``path`` (absolute, as given: a link keeps the folder it is listed in),
    nearest first; the generic ones (:data:`GENERIC_FOLDERS`) left out unless ``generic``."""
    parts = Path(os.path.abspath(path)).parent.parts[1:]
    return [p for p in reversed(parts) if generic or p.lower() not in GENERIC_FOLDERS]


def _names_by_folder(paths: Sequence[Path], taken: set[str]) -> list[str]:
    """Distinct names for robot files that share a name, none of them in ``taken``: each file's
    stem after its folder at the nearest depth where the files' folders all differ
    (``suite.hopper``, ``mujoco.hopper``; generic folder names such as ``xml`` or ``assets``
    skipped: they tell nothing apart), else after several of its nearest folders, joined by
    dots; generic folders count only where nothing else tells the files apart."""
    stems = [Path(os.path.abspath(p)).stem for p in paths]

    def apart(names: list[str]) -> bool:
        return len(set(names)) == len(names) and not taken.intersection(names)

    names = stems
    for generic in (False, True):
        folders = [_folders(p, generic) for p in paths]
        depth = max(map(len, folders), default=0)
        pairs = list(zip(folders, stems, strict=True))
        for d in range(depth):
            names = [f"{f[d]}.{s}" if d < len(f) else s for f, s in pairs]
            if apart(names):
                return names
        for k in range(2, depth + 1):
            names = [".".join((*reversed(f[:k]), s)) for f, s in pairs]
            if apart(names):
                return names
    return names


def _is_catalogue_robot(robot: Robot) -> bool:
    """Whether ``robot`` (read from a file) is the catalogue robot of its name (its own file)."""
    if robot_catalogue(robot.name) is None:
        return False
    try:
        return robot_identity(load_named(robot.name)) == robot_identity(robot)
    except (ValueError, OSError):
        return False


def _name_apart(
    robots: list[Robot], from_file: list[bool], fixed: dict[str, Robot] | None = None
) -> list[Robot]:
    """``robots`` (distinct) with the robots read from files that share a name with another
    robot (of ``robots``, of a catalogue, listed or not, or a name of ``fixed``: robots already
    named) renamed after their folders (see :func:`_names_by_folder`); catalogue robots and
    their own files keep their names. Names that still clash are a DuplicateRobotError naming
    both files."""
    fixed = fixed or {}
    groups: dict[str, list[int]] = {}
    for i, r in enumerate(robots):
        groups.setdefault(r.name, []).append(i)
    out, taken = list(robots), set(groups) | set(fixed)
    for name, idx in groups.items():
        files = [i for i in idx if from_file[i] and not _is_catalogue_robot(robots[i])]
        shared = len(idx) > 1 or name in fixed or robot_catalogue(name) is not None
        if not files or not shared:
            continue
        new = _names_by_folder([Path(robots[i].source) for i in files], taken)
        for i, n in zip(files, new, strict=True):
            out[i] = dataclasses.replace(robots[i], name=n)
    seen = dict(fixed)
    for r in out:
        if r.name in seen:
            raise DuplicateRobotError(
                f"robot files {seen[r.name].source} and {r.source} would both be named "
                f"{r.name!r}; rename or move one of them"
            )
        seen[r.name] = r
    return out


#: a robot spec -> its robots as read and whether they came from files: what one command has
#: looked up, each spec once
Lookups = dict[str, tuple[list[Robot], bool]]


def _lookup(spec: str) -> tuple[list[Robot], bool]:
    """The robots ``spec`` names, as read (not yet named apart), and whether from files."""
    path = Path(spec)
    if spec in _PINNED:
        return [_load_pinned(*stored) for stored in _PINNED[spec]], False
    if robot_catalogue(spec) is not None:
        return [load_named(spec)], False
    if _is_pattern(spec) and not path.exists():
        return [load_named(n) for n in _matching_names(spec)], False
    if path.is_dir():
        return _folder_robots(path), True
    if spec.endswith(".xml") or os.sep in spec or path.is_file():
        return [load_robot(spec)], True
    benchmarks = load_benchmarks()
    if ":" in spec or spec in benchmarks:
        return [load_named(n) for n in _benchmark_names(spec, benchmarks)], False
    raise UnknownRobotError(
        f"unknown robot {spec!r}{did_you_mean(spec, [*_name_index(), *benchmarks])} "
        f"(a spec is a robot name, an .xml path or folder, or one of "
        f"{', '.join(b + ':train|test' for b in benchmarks)})"
    )


def _resolve_each(
    specs: Sequence[str], *, repeats: bool, lookups: Lookups | None = None
) -> tuple[list[Robot], list[bool]]:
    """The robots of ``specs`` as read (not yet named apart), and which were read from files;
    ``lookups``: specs this command has looked up already (and where the new ones are kept)."""
    robots: list[Robot] = []
    from_file: list[bool] = []
    origin: dict[tuple[str, ...], tuple[str, str]] = {}  # identity -> (name, spec)
    for spec in specs:
        if lookups is not None and spec in lookups:
            found, is_file = lookups[spec]
        else:
            found, is_file = _lookup(spec)
            if lookups is not None:
                lookups[spec] = (found, is_file)
        if is_file:  # a catalogue's file whose robot has another name: that name
            found = [_as_catalogue_robot(r) for r in found]
        for r in found:
            key = robot_identity(r)
            if key in origin:
                if repeats:
                    continue
                name, first = origin[key]
                where = "" if first == spec else f" (from {first!r} and {spec!r})"
                raise DuplicateRobotError(
                    f"robot {name!r} is listed twice{where}; list each robot once and set "
                    "env.copies to run more copies of every robot"
                )
            origin[key] = (r.name, spec)
            robots.append(r)
            from_file.append(is_file)
    return robots, from_file


def _as_catalogue_robot(robot: Robot) -> Robot:
    """``robot`` (read from a file) as its catalogue's robot, where a catalogue names its file
    otherwise (:attr:`Catalogue.file_names`: dm_control's ``suite/humanoid.xml`` is
    ``dmc_humanoid``)."""
    name = _file_index().get(os.path.realpath(robot.source))
    if name is None or name == robot.name:
        return robot
    known = load_named(name)
    return known if robot_identity(known) == robot_identity(robot) else robot


def _names_of(specs: Sequence[str], lookups: Lookups | None = None) -> dict[tuple[str, ...], Robot]:
    """Robot identity -> robot, named apart, for the robots of ``specs`` taken together; a spec
    that no longer resolves (a robot file since moved) is left out."""
    robots: list[Robot] = []
    from_file: list[bool] = []
    keys: set[tuple[str, ...]] = set()
    for spec in specs:
        try:
            found, files = _resolve_each([spec], repeats=True, lookups=lookups)
        except (ValueError, OSError):
            continue
        for r, f in zip(found, files, strict=True):
            if robot_identity(r) not in keys:
                keys.add(robot_identity(r))
                robots.append(r)
                from_file.append(f)
    return {robot_identity(r): r for r in _name_apart(robots, from_file)}


def resolve_robots(
    specs: Sequence[str],
    *,
    repeats: bool = False,
    names_from: Sequence[str] = (),
    lookups: Lookups | None = None,
) -> list[Robot]:
    """Robots from specs, in order. A spec is one of:

    * a robot name of any catalogue, e.g. ``walker_3_main`` or ``unimal_0042``;
    * a path to an MJCF file, e.g. ``my_robots/walker_long.xml``, or a folder of them;
    * ``Benchmark:split``, e.g. ``CWHH++:train``, ``Walker++:test``, ``Unimal:variants-dynamics``
      (split defaults to ``train``; ``all`` means train then test);
    * a shell-style pattern over the catalogues' robot names (``*``, ``?``, ``[...]``), e.g.
      ``unimal_000?-length*``: every matching robot in catalogue order (none matching is an error).

    A robot listed twice (directly or through two specs; a catalogue robot and its own file are
    one robot, see :func:`robot_identity`) is an error: a robot list names each robot once, and
    ``env.copies`` runs more copies of every robot. With ``repeats``, a robot listed again is
    kept once instead (an evaluation's robots). Robot files are told apart by their file: two
    files of one name (gymnasium's and dm_control's ``hopper.xml``) are two robots, named after
    the folders that tell them apart (``assets.hopper``, ``suite.hopper``).

    ``names_from``: more specs whose robots the names are chosen among (a run's robot lists,
    :func:`gcnt.recipes.run_robot_specs`), so that a robot file keeps one name in every
    list of a run; a robot of ``specs`` that is not among them is named apart from them.

    ``lookups``: what this command looked up already, spec by spec (a run's record,
    :func:`gcnt.run.resolved.resolve_run`): a spec given there is not looked up again, and the
    specs looked up here are added (one lookup of each spec per command).
    """
    if isinstance(specs, str):
        specs = [specs]
    robots, from_file = _resolve_each(specs, repeats=repeats, lookups=lookups)
    if not names_from:
        return _name_apart(robots, from_file)
    named = _names_of(names_from, lookups)
    out = [
        dataclasses.replace(r, name=named[key].name) if (key := robot_identity(r)) in named else r
        for r in robots
    ]
    new = [i for i, r in enumerate(robots) if robot_identity(r) not in named]
    fixed = {r.name: r for r in named.values()}
    renamed = _name_apart([robots[i] for i in new], [from_file[i] for i in new], fixed)
    for i, r in zip(new, renamed, strict=True):
        out[i] = r
    return out
