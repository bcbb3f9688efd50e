"""The UNIMAL catalogue: the checked-in generated robots, their variants, and the ``Unimal`` splits.

``morphologies/unimal/unimal_<seed>.xml`` is :func:`generate(seed) <generate>` written as MJCF;
``morphologies/unimal.yaml`` holds the benchmark ``Unimal``: 100 training robots (seeds 0-99) and
100 test robots (the next seeds whose body tree, as an unordered rooted tree, is not the tree of
any training robot), and the zero-shot variant splits ``variants-dynamics`` and
``variants-kinematics`` of the training robots.

These are generated, not the paper's evolved UNIMAL-100; ``gcnt import-unimal`` makes MetaMorph's
published files of those a catalogue of their own (``gcnt.morphology.unimal.imported``).

Variants are not checked in: a variant name ``unimal_<seed>-<suffix>`` says how to make it (the
generator's robot of that seed, changed by the operator of the suffix, drawn from a stream seeded
by the name), so it is built on first use and cached for the process.
"""

from __future__ import annotations

import functools
from pathlib import Path

from gcnt.files import write_text
from gcnt.morphology.catalogue_base import Catalogue, morphologies_dir, stale_files
from gcnt.morphology.robot import Robot, RobotFileError, load_robot, robot_from_xml
from gcnt.morphology.unimal.generate import generate
from gcnt.morphology.unimal.mjcf import build_mjcf
from gcnt.morphology.unimal.mutate import VARIANTS, make_variant, variant_names
from gcnt.morphology.unimal.space import Unimal

FOLDER = "unimal"
SPLIT_FILE = "unimal.yaml"
BENCHMARK = "Unimal"
NUM_TRAIN = 100
NUM_TEST = 100
PREFIX = "unimal_"


def robot_name(seed: int) -> str:
    return f"{PREFIX}{seed:04d}"


def seed_of(name: str) -> int | None:
    """The seed of a generated robot's name (``unimal_0042`` -> 42), or None."""
    digits = name.removeprefix(PREFIX)
    return int(digits) if name.startswith(PREFIX) and digits.isdigit() else None


def topology(u: Unimal) -> str:
    """The body tree as a canonical string (the same for any numbering of the limbs)."""

    def enc(i: int) -> str:
        return "(" + "".join(sorted(enc(c) for c in u.children(i))) + ")"

    return enc(-1)


@functools.lru_cache(maxsize=512)
def _base(seed: int) -> Unimal:
    """``generate(seed)``, cached: the split search and the files need the same few hundred
    robots (seeds 0-364 today), and variants their bases."""
    return generate(seed)


@functools.lru_cache(maxsize=1)
def benchmark_seeds() -> tuple[tuple[int, ...], tuple[int, ...]]:
    """Seeds of the training and test robots (slow: generates a few hundred robots)."""
    train = tuple(range(NUM_TRAIN))
    seen = {topology(_base(s)) for s in train}
    test: list[int] = []
    seed = NUM_TRAIN
    while len(test) < NUM_TEST:
        if topology(_base(seed)) not in seen:
            test.append(seed)
        seed += 1
    return train, tuple(test)


def split_yaml(train: list[str], test: list[str]) -> str:
    """The text of ``unimal.yaml``."""
    lines = [
        "# The UNIMAL benchmark: robots generated from the DERL symmetric design space",
        "# (morphologies/unimal/<name>.xml, written by `gcnt robots --rebuild`; unimal_<seed> is",
        "# the generator's robot of that seed). Test robots have body trees no training robot has.",
        "# variants-* are zero-shot variants of the training robots (same topology, one kind of",
        "# change), built on demand from their names.",
        "",
        f"{BENCHMARK}:",
    ]
    splits = {"train": train, "test": test}
    for kind in VARIANTS:
        splits[f"variants-{kind}"] = [v for name in train for v in variant_names(name, kind)]
    for split, names in splits.items():
        lines.append(f"  {split}:")
        lines += [f"    - {n}" for n in names]
    return "\n".join(lines) + "\n"


def expected_files() -> dict[str, str]:
    """Relative path -> text of every checked-in UNIMAL file."""
    train, test = benchmark_seeds()
    files = {f"{FOLDER}/{robot_name(s)}.xml": build_mjcf(_base(s)) for s in (*train, *test)}
    files[SPLIT_FILE] = split_yaml([robot_name(s) for s in train], [robot_name(s) for s in test])
    return files


def write_files(root: Path) -> list[Path]:
    """Write the UNIMAL robots and split file under the morphologies folder ``root``."""
    (root / FOLDER).mkdir(parents=True, exist_ok=True)
    paths = []
    for rel, text in expected_files().items():
        path = root / rel
        write_text(path, text)
        paths.append(path)
    return paths


def check_files(root: Path) -> list[str]:
    """Problems of the UNIMAL files under ``root`` (empty when they equal a regeneration)."""
    return stale_files(root, expected_files(), FOLDER, "generator", "a generated UNIMAL robot")


def _checked_in() -> list[str]:
    folder = morphologies_dir() / FOLDER
    return sorted(p.stem for p in folder.glob("*.xml")) if folder.is_dir() else []


def robot_names() -> list[str]:
    names = _checked_in()
    return names + [v for n in names for kind in VARIANTS for v in variant_names(n, kind)]


def as_unimal(robot: Robot, source: str | Path) -> Robot:
    """``robot`` if it is a UNIMAL robot; else a RobotFileError naming ``source``."""
    if robot.family != "unimal":
        raise RobotFileError(
            f"{source}: not a UNIMAL robot (its family is {robot.family!r}; a UNIMAL file has a "
            "free-jointed torso body 'torso/0' or model name 'unimal')"
        )
    return robot


def load_unimal(path: str | Path, catalogue: str = "unimal") -> Robot:
    """A UNIMAL robot file (MetaMorph's or gcnt's); RobotFileError if it is another kind."""
    return as_unimal(load_robot(path, catalogue), path)


def variant_robot(name: str) -> Robot:
    """The variant ``unimal_<seed>-<suffix>``, built from the generator."""
    base, _, _ = name.rpartition("-")
    seed = seed_of(base)
    if seed is None:
        raise ValueError(f"{name!r}: variants exist only of generated robots (unimal_<seed>)")
    text = build_mjcf(make_variant(_base(seed), name))
    return robot_from_xml(text, source=f"<generated {name}>", name=name, catalogue="unimal")


def load(name: str) -> Robot:
    path = morphologies_dir() / FOLDER / f"{name}.xml"
    return load_unimal(path) if path.is_file() else variant_robot(name)


UNIMAL_CATALOGUE = Catalogue(
    name="unimal",
    robot_names=robot_names,
    load=load,
    split_file=SPLIT_FILE,
    rebuild=write_files,
    check=check_files,
    description="robots generated from the DERL symmetric UNIMAL design space, and variants",
)
