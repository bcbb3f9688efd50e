"""The catalogue of a folder of UNIMAL robots imported from MetaMorph's files (written by
``gcnt import-unimal``: :mod:`gcnt.morphology.unimal.imported`): ``<set>/xml/<robot>.xml`` for
each of MetaMorph's sets, and the folder's split file."""

from __future__ import annotations

import os
from pathlib import Path

from gcnt.morphology.catalogue_base import IMPORTED_INDEX, Catalogue
from gcnt.morphology.robot import Robot, RobotFileError
from gcnt.morphology.unimal.catalogue import load_unimal

#: MetaMorph's set folders, in order, and the split each becomes
SETS: dict[str, str] = {
    "train": "train",
    "test": "test",
    "dynamics": "variants-dynamics",
    "kinematics": "variants-kinematics",
}
#: the catalogue and benchmark name of an import unless ``--name`` says otherwise
DEFAULT_NAME = "Unimal100"


def imported_catalogue(folder: Path) -> Catalogue:
    """The catalogue of an imported folder (see the module doc); a relative ``folder`` is taken
    from the current folder, as an absolute path."""
    folder = Path(os.path.abspath(folder))

    def robot_names() -> list[str]:
        return [p.stem for s in SETS for p in sorted((folder / s / "xml").glob("*.xml"))]

    def load(name: str) -> Robot:
        for s in SETS:
            path = folder / s / "xml" / f"{name}.xml"
            if path.is_file():
                return load_unimal(path)
        raise RobotFileError(f"{folder}: no robot {name!r} in {', '.join(SETS)}")

    return Catalogue(
        name=folder.name,
        robot_names=robot_names,
        load=load,
        split_file=folder / IMPORTED_INDEX,
        description=f"MetaMorph's UNIMAL robots, imported into {folder}",
    )
