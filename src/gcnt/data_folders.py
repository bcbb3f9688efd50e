"""Where gcnt's files live: the robots and recipes that ship with the package, and the user's
own robot sets.

* The packaged files are ``gcnt/data/morphologies`` (robot files and benchmark split files),
  ``gcnt/data/recipes`` and ``gcnt/data/constraints.txt`` (the versions gcnt is tested with)
  inside the installed package. In a checkout these are links to the repository's top-level
  ``morphologies/``, ``recipes/`` and ``constraints.txt``, the files' only copy; a wheel holds
  the files themselves.
* The user's robot sets (``gcnt import-unimal``; any folder ``<name>/catalogue.yaml`` of robot
  files) live in a per-user folder: ``$GCNT_MORPHOLOGIES`` if set, else
  ``$XDG_DATA_HOME/gcnt/morphologies``, else ``~/.local/share/gcnt/morphologies``. They are read
  in addition to the packaged robots, never instead of them. A relative
  ``GCNT_MORPHOLOGIES`` is taken from the current folder, once, as an absolute path.
"""

from __future__ import annotations

import os
from pathlib import Path

#: the package's folder of shipped files
PACKAGE_DATA = Path(__file__).resolve().parent / "data"
#: the variable that names the user's robot-set folder
MORPHOLOGIES_ENV = "GCNT_MORPHOLOGIES"


def packaged_morphologies() -> Path:
    """The folder of the robot files and split files that ship with gcnt (resolved: in a
    checkout, its ``morphologies/``)."""
    return (PACKAGE_DATA / "morphologies").resolve()


def tested_versions_file() -> Path:
    """The exact versions gcnt is tested with (``constraints.txt``, shipped in the package)."""
    return (PACKAGE_DATA / "constraints.txt").resolve()


def packaged_recipes() -> Path:
    """The folder of the recipes that ship with gcnt (in a checkout, its ``recipes/``)."""
    return (PACKAGE_DATA / "recipes").resolve()


def user_data_dir() -> Path:
    """The per-user data folder: ``$XDG_DATA_HOME/gcnt`` (default ``~/.local/share/gcnt``)."""
    xdg = os.environ.get("XDG_DATA_HOME")
    base = Path(xdg) if xdg and Path(xdg).is_absolute() else Path.home() / ".local" / "share"
    return base / "gcnt"


def user_morphologies() -> Path:
    """The folder of the user's robot sets, absolute (it need not exist yet): see the module
    doc."""
    env = os.environ.get(MORPHOLOGIES_ENV)
    path = Path(env).expanduser() if env else user_data_dir() / "morphologies"
    return Path(os.path.abspath(path))
