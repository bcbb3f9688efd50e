"""What a run records of what it was trained with, so that it can be handed to anyone: its robots
(stored in the run directory, content-addressed) and the identity of its plugins (never imported
from the record).

The record is the ``resolved:`` section of the run's ``recipe.yaml`` (written by the run):

* ``resolved.robots``: ``{"train": [names], "test": [names], "index": {name: {"sha256",
  "family", "catalogue", "registered"}}}``: the training and test robots as the run resolved
  them, and for each the sha256 of its stored MJCF (:func:`stored_form`), kept in
  ``robots/<sha256>.xml`` with the asset files it references in ``robots/assets/``;
  ``registered``: the robot came from a catalogue by name (a robot file given by path: false).
* ``resolved.plugins``: ``[{"name", "sha256"}]`` (:func:`gcnt.plugins.identities`).

Reading a run back (:func:`use_stored_robots`): a catalogue robot whose name is registered here
is used as registered (a warning names both hashes where its MJCF differs from the stored one);
any other robot is read from the run's own copy. A run written before robots were stored is
resolved by name, as it recorded them, with one line saying so.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import re
import sys
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from gcnt.files import MiB, read_regular, write_bytes
from gcnt.recipes import (
    Recipe,
    RecipeError,
    algorithm_names,
    read_recipe_file,
    recorded_recipe,
)

log = logging.getLogger(__name__)

#: the run directory's folder of stored robots
ROBOTS_DIR = "robots"
#: the folder (inside :data:`ROBOTS_DIR`) of the asset files stored robots reference
ASSETS_DIR = "assets"
#: the largest asset file (a mesh, a texture) a run stores with its robot
MAX_ASSET_BYTES = 256 * MiB
#: the keys of the record in a recipe's ``resolved:`` section
ROBOTS_KEY, PLUGINS_KEY = "robots", "plugins"
#: ``<compiler>`` attributes that prefix asset file names (dropped: stored names are complete)
_ASSET_PREFIXES = ("meshdir", "texturedir", "assetdir")


def stored_form(robot: Any) -> tuple[str, dict[str, bytes]]:
    """The MJCF text a run stores for ``robot`` and the asset files it references (name inside
    :data:`ROBOTS_DIR` -> content): each asset named by the sha256 of its content, so that the
    text's hash covers the assets too. A robot without asset files is stored as its text."""
    root = ET.fromstring(robot.xml)
    files = [el for el in root.iter() if el.get("file")]
    if not files:
        return robot.xml, {}
    assets: dict[str, bytes] = {}
    for el in files:
        # absolute: the robot loader made it so
        data = read_regular(el.get("file"), MAX_ASSET_BYTES, "a robot's asset file", OSError)
        name = f"{ASSETS_DIR}/{hashlib.sha256(data).hexdigest()}{Path(el.get('file')).suffix}"
        assets[name] = data
        el.set("file", name)
    compiler = root.find("compiler")
    if compiler is not None:
        for key in _ASSET_PREFIXES:
            compiler.attrib.pop(key, None)
    return ET.tostring(root, encoding="unicode"), assets


def robot_sha256(robot: Any) -> str:
    """The sha256 of the MJCF a run stores for ``robot`` (:func:`stored_form`)."""
    return hashlib.sha256(stored_form(robot)[0].encode("utf-8")).hexdigest()


def _write_once(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` unless it is there (content-addressed: the same bytes), through
    the guarded atomic write (a killed write leaves no partial file; a link there is refused)."""
    if path.is_file() and not path.is_symlink():
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    write_bytes(path, data)


def robot_record(train: Sequence[Any], test: Sequence[Any]) -> dict[str, Any]:
    """The ``resolved.robots`` record of a run's training and test robots (nothing written)."""
    from gcnt.morphology.catalogues import load_named, robot_catalogue, robot_identity

    index: dict[str, dict[str, Any]] = {}
    for robot in [*train, *test]:
        if robot.name in index:
            continue
        registered = False
        if robot_catalogue(robot.name) is not None:
            with contextlib.suppress(ValueError, OSError):
                registered = robot_identity(load_named(robot.name)) == robot_identity(robot)
        index[robot.name] = {
            "sha256": robot_sha256(robot),
            "family": robot.family,
            "catalogue": robot.catalogue,
            "registered": registered,
        }
    return {
        "train": [r.name for r in train],
        "test": [r.name for r in test],
        "index": index,
    }


def store_robots(run_dir: str | Path, robots: Iterable[Any]) -> None:
    """Store the MJCF of ``robots`` (and their assets) in ``run_dir/robots/``, each once."""
    folder = Path(run_dir) / ROBOTS_DIR
    for robot in robots:
        text, assets = stored_form(robot)
        data = text.encode("utf-8")
        for name, content in assets.items():
            _write_once(folder / name, content)
        _write_once(folder / f"{hashlib.sha256(data).hexdigest()}.xml", data)


def use_stored_robots(
    recipe: Any, run_dir: str | Path, recorded: Mapping[str, Any] | None = None
) -> None:
    """Resolve ``recipe``'s robot lists to the robots the run recorded (``recorded``: the recipe
    as its run wrote it, read again if not given; a list an override changed is resolved as
    given). A catalogue robot
    registered here is used as registered (a warning names both hashes where its MJCF differs
    from the stored one); any other robot (a robot file given by path, a robot of an imported
    set since gone) is read from the run's own copy
    (:func:`gcnt.morphology.catalogues.pin_robots`): a list of one spec keeps its spec, pinned
    to the stored robots; a longer one lists the robots by name."""
    record = (recipe.resolved or {}).get(ROBOTS_KEY)
    if not isinstance(record, Mapping) or not isinstance(record.get("index"), Mapping):
        _predates(run_dir)
        return
    from gcnt.morphology.catalogues import pin_robots

    if recorded is None:
        recorded = read_recipe_file(Path(run_dir) / "recipe.yaml")
    env = recorded.get("env") if isinstance(recorded.get("env"), Mapping) else {}
    folder = Path(run_dir) / ROBOTS_DIR
    index = record["index"]
    for key, attr in (("train", "robots"), ("test", "test_robots")):
        names = record.get(key)
        specs = list(getattr(recipe.env, attr))
        if not isinstance(names, list) or not names or specs != env.get(attr):
            continue
        entries = [(n, index.get(n)) for n in names]
        if not all(isinstance(e, Mapping) and isinstance(e.get("sha256"), str) for _, e in entries):
            continue
        stored = [
            (n, folder / f"{_sha256(n, e, run_dir)}.xml", e.get("family"), e.get("catalogue"))
            for n, e in entries
        ]
        own = [s for (n, e), s in zip(entries, stored, strict=True) if not _registered(n, e, s)]
        if not own:
            continue
        for name, path, *_ in own:
            check_stored_copy(name, path, run_dir)
        if len(specs) == 1:
            pin_robots(specs[0], stored)
            continue
        for entry in own:
            pin_robots(entry[0], [entry])
        setattr(recipe.env, attr, list(names))


#: the largest stored robot file read back (an MJCF of a robot: kilobytes)
MAX_STORED_ROBOT_BYTES = 64 * MiB


def _sha256(name: str, entry: Mapping[str, Any], run_dir: str | Path) -> str:
    """The recorded sha256 of robot ``name``: 64 lower-case hex digits (it names a file in the
    run's ``robots/``; anything else could name a file elsewhere), else a RecipeError."""
    sha = entry["sha256"]
    if not re.fullmatch(r"[0-9a-f]{64}", sha):
        raise RecipeError(
            f"{Path(run_dir) / 'recipe.yaml'}: robot {name!r} records sha256 {sha[:80]!r}, not "
            "64 hex digits: its stored copy cannot be named"
        )
    return sha


def check_stored_copy(name: str, path: Path, run_dir: str | Path) -> None:
    """A run's stored copy of robot ``name`` is read only if it is a regular file (not a link)
    inside the run's own ``robots/`` folder (itself no link) and its bytes hash to the sha256
    the run recorded (the file's name): a swapped or planted copy is refused in one line, never
    evaluated under the recorded robot's name."""
    run = Path(run_dir)
    folder = path.parent
    inside = not folder.is_symlink() and folder.resolve().parent == run.resolve()
    if not inside or path.is_symlink() or not path.resolve().parent == folder.resolve():
        raise RecipeError(
            f"{path}: robot {name!r}'s stored copy is not a file of the run's own "
            f"{ROBOTS_DIR}/ folder (a link?)"
        )
    data = read_regular(path, MAX_STORED_ROBOT_BYTES, f"robot {name!r}'s stored copy", RecipeError)
    if hashlib.sha256(data).hexdigest() != path.stem:
        raise RecipeError(
            f"{path}: robot {name!r}'s stored copy does not hash to the sha256 the run recorded "
            "for it (the file was changed or swapped): refused"
        )


def _registered(name: str, entry: Mapping[str, Any], stored: tuple) -> bool:
    """Whether the run's robot ``name`` came from a catalogue that still registers it here (then
    it is used as registered, with a warning if its MJCF differs from the stored copy)."""
    from gcnt.morphology.catalogues import load_named, robot_catalogue

    if not entry.get("registered") or robot_catalogue(name) is None:
        return False
    try:
        here = robot_sha256(load_named(name))
    except (ValueError, OSError):
        return False
    if here != entry["sha256"]:
        log.warning(
            "robot %r: the run was trained on sha256 %s (its copy: %s); the robot registered "
            "here under that name is sha256 %s, and is used",
            name,
            entry["sha256"][:16],
            stored[1],
            here[:16],
        )
    return True


_told: set[str] = set()


def _predates(run_dir: str | Path) -> None:
    key = str(Path(run_dir).resolve())
    if key not in _told:
        _told.add(key)
        log.info(
            "%s predates stored robots: its robots are resolved by name, as it recorded them",
            run_dir,
        )


def recorded_plugins(recipe: Mapping[str, Any]) -> list[Any]:
    """The plugins a recorded recipe names: the identities of ``resolved.plugins``, else (a run
    written before identities were recorded) its ``plugins:`` key."""
    resolved = recipe.get("resolved")
    if isinstance(resolved, Mapping) and isinstance(resolved.get(PLUGINS_KEY), list):
        return list(resolved[PLUGINS_KEY])
    listed = recipe.get("plugins")
    return list(listed) if isinstance(listed, list) else []


def unregistered_names(recipe: Mapping[str, Any]) -> list[str]:
    """What a recorded recipe names that nothing imported here registers: its algorithm,
    method (``network.name``) and benchmark. Read without loading torch: a method or benchmark
    is built in, or was registered by code that has loaded its registry already."""
    from gcnt import builtin

    networks = {*builtin.METHODS, *getattr(sys.modules.get("gcnt.nn.registry"), "NETWORKS", ())}
    registry = sys.modules.get("gcnt.envs.benchmark")
    benchmarks = {*builtin.BENCHMARKS, *(registry.benchmark_names() if registry else ())}

    env = recipe.get("env") if isinstance(recipe.get("env"), Mapping) else {}
    net = recipe.get("network") if isinstance(recipe.get("network"), Mapping) else {}
    wanted = (
        ("algo", recipe.get("algo", "td3"), algorithm_names()),
        ("network.name", net.get("name", "gcnt"), networks),
        ("env.benchmark", env.get("benchmark", "smpenv"), benchmarks),
    )
    return [f"{key}={value}" for key, value, known in wanted if str(value) not in known]


def check_plugins(run_dir: str | Path, recipe: Mapping[str, Any]) -> None:
    """The recorded plugins of the run against this command's (:func:`gcnt.plugins.
    check_recorded`); nothing recorded: nothing to check (and nothing heavy imported)."""
    from gcnt import plugins

    recorded = recorded_plugins(recipe)
    if not recorded:
        return
    plugins.check_recorded(recorded, run_dir, unregistered_names(recipe))


def load_run_recipe(
    path: str | Path,
    overrides: list[str] | None = None,
    *,
    anywhere: bool = False,
    stored_robots: bool = True,
) -> Recipe:
    """The recipe a run recorded (its ``recipe.yaml``), to go on with here, with ``overrides``.

    A run moves between machines: the switches that need CUDA (:attr:`gcnt.recipes.CompileConfig.CUDA_ONLY`)
    are dropped, in one warning line, when the run goes on without CUDA (e.g. a GPU run resumed
    with ``device=cpu``), unless an override sets them (then refused as in any recipe). With
    ``anywhere`` (a run read rather than trained on: evaluation, analysis, a fine-tune's source),
    a run recorded on a CUDA device that this machine lacks is read on the CPU, in one info line;
    a resumed run instead names the ``device=cpu`` override that moves it.

    Nothing the run names is imported: its recorded plugins are checked against this command's
    (:func:`check_plugins`: one that the run needs and the command did not name
    is an error naming it), and the recipe's ``plugins`` are this command's own. Its robots are
    the ones it recorded, read from its own copies where not registered here
    (:func:`use_stored_robots`; ``stored_robots=False``: not yet, so that a
    command can check what it was asked before the robot catalogues are loaded)."""
    from gcnt import plugins

    recorded = read_recipe_file(path)
    check_plugins(Path(path).parent, recorded)
    recipe = recorded_recipe(recorded, path, overrides, anywhere)
    recipe.plugins = plugins.session()
    if stored_robots:
        use_stored_robots(recipe, Path(path).parent, recorded)
    return recipe
