"""The ``mjcf3d`` catalogue: general 3-D robots from files other projects ship, and UNIMAL robots
read as general 3-D robots.

Robot names:

* ``dmc_humanoid``: dm_control's suite ``humanoid.xml`` (dm_control is a dependency of gcnt);
* ``gym_ant``, ``gym_humanoid``: gymnasium's MuJoCo ``ant.xml`` and ``humanoid.xml``, when the
  ``gymnasium`` package is installed (it is in the ``dev`` extras);
* ``unimal3d_<seed>``: the checked-in ``morphologies/unimal/unimal_<seed>.xml`` read as a general
  3-D robot (family ``mjcf3d``: 3-D tokens, the ``mjcf3d`` benchmark's world and rules).

The files are read where their packages installed them; none is copied into gcnt. Any other 3-D
robot file (one free-jointed root body) loads by path as an ``mjcf3d`` robot.

``morphologies/mjcf3d.yaml`` holds the benchmark ``MJCF3D``: a few converted UNIMAL training
robots and dm_control's humanoid to train on, converted UNIMAL test robots to evaluate zero-shot
(gymnasium's robots are left out of the splits because gymnasium is optional).
"""

from __future__ import annotations

import importlib.util
import os
from dataclasses import replace
from pathlib import Path

from gcnt.files import write_text
from gcnt.morphology.catalogue_base import Catalogue, morphologies_dir, read_own_file
from gcnt.morphology.robot import Robot, RobotFileError, load_robot

CATALOGUE = "mjcf3d"
FAMILY = "mjcf3d"
SPLIT_FILE = "mjcf3d.yaml"
BENCHMARK = "MJCF3D"
UNIMAL_PREFIX = "unimal3d_"
#: robots of installed packages: name -> (package, path of the file inside the package)
PACKAGE_ROBOTS: dict[str, tuple[str, str]] = {
    "dmc_humanoid": ("dm_control", "suite/humanoid.xml"),
    "gym_ant": ("gymnasium", "envs/mujoco/assets/ant.xml"),
    "gym_humanoid": ("gymnasium", "envs/mujoco/assets/humanoid.xml"),
}
#: the split file's robots: the first UNIMAL training seeds and the first UNIMAL test seeds
TRAIN_SEEDS = (0, 1, 2, 3)
TEST_SEEDS = (103, 104, 105, 108)


def package_file(package: str, rel: str) -> Path | None:
    """``rel`` inside the installed ``package``, or None if the package is not installed."""
    spec = importlib.util.find_spec(package)
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(next(iter(spec.submodule_search_locations))) / rel


def robot_file(name: str) -> Path | None:
    """The file of a package robot ``name`` (None: its package is not installed)."""
    package, rel = PACKAGE_ROBOTS[name]
    return package_file(package, rel)


def file_names() -> dict[str, str]:
    """The package robots' files (resolved) -> their names: dm_control's ``suite/humanoid.xml``
    listed by its path is ``dmc_humanoid`` too."""
    files = {name: robot_file(name) for name in PACKAGE_ROBOTS}
    return {os.path.realpath(f): name for name, f in files.items() if f is not None and f.is_file()}


def _unimal_names() -> list[str]:
    folder = morphologies_dir() / "unimal"
    stems = sorted(p.stem for p in folder.glob("unimal_*.xml")) if folder.is_dir() else []
    return [UNIMAL_PREFIX + s.removeprefix("unimal_") for s in stems]


def robot_names() -> list[str]:
    installed = [n for n in PACKAGE_ROBOTS if robot_file(n) is not None]
    return installed + _unimal_names()


def load(name: str) -> Robot:
    if name in PACKAGE_ROBOTS:
        path = robot_file(name)
        if path is None:
            raise RobotFileError(
                f"robot {name!r} is read from the {PACKAGE_ROBOTS[name][0]!r} package, which is not "
                "installed"
            )
        robot = load_robot(path, CATALOGUE)
    elif name.startswith(UNIMAL_PREFIX):
        path = morphologies_dir() / "unimal" / f"unimal_{name.removeprefix(UNIMAL_PREFIX)}.xml"
        robot = load_robot(path, CATALOGUE, family=FAMILY)
    else:
        raise RobotFileError(f"{name!r} is not a robot of the {CATALOGUE} catalogue")
    if robot.family != FAMILY:
        raise RobotFileError(f"{robot.source}: not a 3-D robot (its family is {robot.family!r})")
    return replace(robot, name=name)


def split_yaml() -> str:
    """The text of ``mjcf3d.yaml``."""
    train = [f"{UNIMAL_PREFIX}{s:04d}" for s in TRAIN_SEEDS] + ["dmc_humanoid"]
    test = [f"{UNIMAL_PREFIX}{s:04d}" for s in TEST_SEEDS]
    lines = [
        f"# The {BENCHMARK} benchmark (env.benchmark: mjcf3d): general 3-D robots",
        "# (gcnt.morphology.mjcf3d). unimal3d_<seed> is morphologies/unimal/unimal_<seed>.xml read",
        "# as a general 3-D robot; dmc_humanoid is dm_control's suite humanoid.xml. Written by",
        "# `gcnt robots --rebuild`.",
        "",
        f"{BENCHMARK}:",
        "  train:",
        *(f"    - {n}" for n in train),
        "  test:",
        *(f"    - {n}" for n in test),
    ]
    return "\n".join(lines) + "\n"


def write_files(root: Path) -> list[Path]:
    path = root / SPLIT_FILE
    write_text(path, split_yaml())
    return [path]


def check_files(root: Path) -> list[str]:
    path = root / SPLIT_FILE
    if not path.is_file():
        return [f"{path}: missing"]
    if read_own_file(path) != split_yaml():
        return [f"{path}: differs from the split writer's output"]
    return []


MJCF3D_CATALOGUE = Catalogue(
    name=CATALOGUE,
    robot_names=robot_names,
    load=load,
    split_file=SPLIT_FILE,
    rebuild=write_files,
    check=check_files,
    file_names=file_names,
    description="general 3-D robots: dm_control's and gymnasium's files, UNIMAL robots read as 3-D",
)
