"""The catalogue seam: a catalogue registered from a test, look-up through every catalogue."""

from __future__ import annotations

import shutil

import pytest

from gcnt.morphology.catalogues import (
    Catalogue,
    DuplicateRobotError,
    UnknownRobotError,
    get_catalogue,
    load_benchmarks,
    morphologies_dir,
    register_catalogue,
    resolve_robots,
    unregister_catalogue,
)
from gcnt.morphology.robot import load_robot


@pytest.fixture
def toy(tmp_path):
    """A toy catalogue of two robots (copies of SMPENV hoppers) with its own split file."""
    folder = tmp_path / "toy"
    folder.mkdir()
    for src, dst in (("hopper_3", "toy_small"), ("hopper_4", "toy_big")):
        shutil.copy(morphologies_dir() / "smpenv" / f"{src}.xml", folder / f"{dst}.xml")
    split = tmp_path / "toy.yaml"
    split.write_text("Toy:\n  train: [toy_big]\n  test: [toy_small]\n")
    cat = Catalogue(
        name="toy",
        robot_names=lambda: ["toy_small", "toy_big"],
        load=lambda name: load_robot(folder / f"{name}.xml", "toy"),
        split_file=split,
    )
    register_catalogue(cat)
    yield cat
    unregister_catalogue("toy")


def test_a_toy_catalogue_resolves_everywhere(toy):
    assert get_catalogue("toy") is toy
    robots = resolve_robots(["toy_small", "Toy:train", "walker_3_main"])
    assert [(r.name, r.catalogue) for r in robots] == [
        ("toy_small", "toy"),
        ("toy_big", "toy"),
        ("walker_3_main", "smpenv"),
    ]
    assert load_benchmarks()["Toy"] == {"train": ["toy_big"], "test": ["toy_small"]}
    assert "Walker++" in load_benchmarks() and "Unimal" in load_benchmarks()
    assert list(load_benchmarks(catalogue="toy")) == ["Toy"]
    with pytest.raises(UnknownRobotError, match="toy_small"):
        resolve_robots(["toy_smal"])
    with pytest.raises(ValueError, match="already registered"):
        register_catalogue(toy)


def test_unknown_catalogue_suggests():
    with pytest.raises(ValueError, match="did you mean 'unimal'"):
        get_catalogue("unimall")


def test_repeated_robots_fail_loudly():
    with pytest.raises(DuplicateRobotError, match="'hopper_3'.*env.copies"):
        resolve_robots(["hopper_3", "hopper_3"])
    with pytest.raises(DuplicateRobotError, match="'hopper_4'.*'Hopper\\+\\+:train'.*'hopper_4'"):
        resolve_robots(["Hopper++:train", "hopper_4"])


def test_folders_and_splits(tmp_path):
    for name in ("walker_2_main", "cheetah_2_back"):
        shutil.copy(morphologies_dir() / "smpenv" / f"{name}.xml", tmp_path / f"my_{name}.xml")
    names = [r.name for r in resolve_robots([str(tmp_path)])]
    assert names == ["my_cheetah_2_back", "my_walker_2_main"]
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(UnknownRobotError, match="no .xml"):
        resolve_robots([str(empty)])
    assert len(resolve_robots(["Unimal:test"])) == 100
    with pytest.raises(UnknownRobotError, match="did you mean 'variants-dynamics'"):
        resolve_robots(["Unimal:variants-dynamic"])
    with pytest.raises(UnknownRobotError, match="did you mean 'Unimal'"):
        resolve_robots(["Unimall:train"])


def test_name_patterns_pick_robots_in_catalogue_order():
    kin = [r.name for r in resolve_robots(["unimal_000?-[lr]*"])]
    assert len(kin) == 40 and kin[:4] == [
        "unimal_0000-length1",
        "unimal_0000-length2",
        "unimal_0000-range1",
        "unimal_0000-range2",
    ]
    dyn = {r.name.split("-")[1] for r in resolve_robots(["unimal_000?-[adg]*"])}
    assert dyn == {"armature1", "damping1", "gear1", "density1"}
    assert [r.name for r in resolve_robots(["walker_?_main"])][:2] == [
        "walker_2_main",
        "walker_3_main",
    ]
    with pytest.raises(UnknownRobotError, match="no robot name matches"):
        resolve_robots(["nothing_like_this_*"])


def test_a_benchmark_spelled_in_another_case_is_that_benchmark():
    from gcnt.morphology.catalogues import resolve_robots

    # MJCF3D was once spelled Mjcf3d: recipes and runs that say so still resolve
    assert resolve_robots(["Mjcf3d:train"]) == resolve_robots(["MJCF3D:train"])
