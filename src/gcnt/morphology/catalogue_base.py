"""The catalogue record (:class:`Catalogue`: a set of robots gcnt can load by name) and the files
a catalogue ships: its robot folder, split files and the check that they are current. The
registry of catalogues and robot look-up by name are :mod:`gcnt.morphology.catalogues`."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from gcnt.data_folders import packaged_morphologies
from gcnt.files import MiB, read_text
from gcnt.morphology.robot import Robot

#: the largest benchmark split file read
MAX_SPLIT_FILE_BYTES = 16 * MiB

#: A folder ``<name>/`` of the morphologies folder that holds this file is the catalogue
#: ``<name>`` of UNIMAL robots imported from MetaMorph's files (``gcnt import-unimal``,
#: ``gcnt.morphology.unimal.imported``); the file is its split file.
IMPORTED_INDEX = "catalogue.yaml"


class BenchmarkFileError(ValueError):
    """A malformed benchmark split file; the message names the file and the culprit."""


def morphologies_dir() -> Path:
    """The folder of the robot files and split files that ship with gcnt (in a checkout, its
    ``morphologies/``)."""
    path = packaged_morphologies()
    if not path.is_dir():
        raise FileNotFoundError(
            f"gcnt's robot folder {path} does not exist: this installation of gcnt is incomplete "
            "(reinstall it; in a checkout, `gcnt robots --rebuild` regenerates the robot files)"
        )
    return path


@dataclass(frozen=True)
class Catalogue:
    """One set of robots gcnt can load by name."""

    #: registry name, also ``Robot.catalogue`` of its robots
    name: str
    #: every robot name ``load`` accepts (called when names are resolved; keep it cheap)
    robot_names: Callable[[], Sequence[str]]
    #: the robot of a name (the registry caches the result)
    load: Callable[[str], Robot]
    #: its benchmark split file; a relative path is inside :func:`morphologies_dir`
    split_file: str | Path | None = None
    #: write the catalogue's files under a morphologies folder; returns the paths written
    rebuild: Callable[[Path], list[Path]] | None = None
    #: problems of the catalogue's files under a morphologies folder (empty: all current)
    check: Callable[[Path], list[str]] | None = None
    description: str = ""
    #: the catalogue's robot files whose robot name is not the file's name: resolved path ->
    #: robot name (such a file listed by its path is named as the catalogue names it)
    file_names: Callable[[], dict[str, str]] | None = None

    def split_path(self) -> Path | None:
        if self.split_file is None:
            return None
        path = Path(self.split_file)
        return path if path.is_absolute() else morphologies_dir() / path


def stale_files(
    root: Path, expected: dict[str, str], folder: str, maker: str, kind: str
) -> list[str]:
    """Problems of a catalogue's files under the morphologies folder ``root``: each of
    ``expected`` (relative path -> text) missing or different from what its ``maker`` writes,
    and ``.xml`` files in ``root/folder`` that are not expected (not ``kind``)."""
    problems: list[str] = []
    for rel, text in expected.items():
        path = root / rel
        if not path.is_file():
            problems.append(f"{path}: missing")
        elif read_own_file(path) != text:
            problems.append(f"{path}: differs from the {maker}'s output")
    extra = sorted(p for p in (root / folder).glob("*.xml") if f"{folder}/{p.name}" not in expected)
    return problems + [f"{p}: not {kind}" for p in extra]


def read_own_file(path: Path) -> str | None:
    """The text of a file gcnt writes into the morphologies folder (None: unreadable, as
    :func:`gcnt.files.read_text` refuses it), to compare with what it would write."""
    try:
        return read_text(path, MAX_SPLIT_FILE_BYTES, "gcnt writes it", BenchmarkFileError)
    except BenchmarkFileError:
        return None
