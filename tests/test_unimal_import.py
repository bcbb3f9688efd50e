"""``gcnt import-unimal``: MetaMorph's published UNIMAL-100 layout (a folder, or the zip as
downloaded) becomes a catalogue with its splits that recipes, commands and envs take; bad sets
are refused in one line naming the culprit, leaving nothing behind. The sets here are tiny fakes
in MetaMorph's layout, made from gcnt's own UNIMAL generator."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch
from cli_helpers import ROOT, error_line, holding
from tensordict import TensorDict

from gcnt.cli import main as gcnt
from gcnt.morphology.catalogues import (
    load_benchmarks,
    morphologies_dir,
    refresh_catalogues,
    resolve_robots,
)
from gcnt.morphology.unimal import build_mjcf, generate, make_variant
from gcnt.morphology.unimal.catalogue import seed_of
from gcnt.morphology.unimal.imported import import_unimals

#: the fake set: MetaMorph's folder -> {robot name (named as MetaMorph names them): the robot of
#: gcnt's generator (or its variant) written under that name}
MADE_AS = {
    "train": {
        "floor-1409-0-3-01-15-56-55": "unimal_0900",
        "floor-5506-10-6-01-15-48-35": "unimal_0901",
    },
    "test": {"mvt-5506-12-6-17-12-20-06": "unimal_0902"},
    "dynamics": {"floor-1409-0-3-01-15-56-55_damping_3": "unimal_0900-damping1"},
    "kinematics": {"floor-1409-0-3-01-15-56-55_limb_params_1": "unimal_0900-length1"},
}
FAKE = {folder: list(robots) for folder, robots in MADE_AS.items()}
#: the variable naming the user's robot-set folder (gcnt.data_folders)
MORPHOLOGIES_ENV = "GCNT_MORPHOLOGIES"
SPLITS = {
    "train": FAKE["train"],
    "test": FAKE["test"],
    "variants-dynamics": FAKE["dynamics"],
    "variants-kinematics": FAKE["kinematics"],
}


def _robot_xml(made_as: str) -> str:
    """The MJCF of gcnt's ``unimal_<seed>`` or of its variant ``unimal_<seed>-<suffix>``."""
    base, _, suffix = made_as.partition("-")
    robot = generate(seed_of(base))
    return build_mjcf(make_variant(robot, made_as) if suffix else robot)


@pytest.fixture(scope="module")
def unimals(tmp_path_factory) -> Path:
    """``<tmp>/unimals_100/`` in MetaMorph's layout (metadata and pickles too)."""
    root = tmp_path_factory.mktemp("download") / "unimals_100"
    for folder, names in MADE_AS.items():
        for sub in ("xml", "metadata", "unimal_init"):
            (root / folder / sub).mkdir(parents=True)
        for name, made_as in names.items():
            (root / folder / "xml" / f"{name}.xml").write_text(_robot_xml(made_as))
            (root / folder / "metadata" / f"{name}.json").write_text("{}")
            (root / folder / "unimal_init" / f"{name}.pkl").write_bytes(b"not read")
    return root


def _zip(folder: Path, path: Path, skip: str | None = None, extra=()) -> Path:
    """``folder`` zipped as MetaMorph's archive is (its name as the top folder)."""
    with zipfile.ZipFile(path, "w") as z:
        for f in sorted(folder.rglob("*")):
            rel = f.relative_to(folder.parent).as_posix()
            if f.is_file() and (skip is None or f"/{skip}/" not in rel):
                z.write(f, rel)
        for name, data in extra:
            z.writestr(name, data)
    return path


@pytest.fixture
def morph(tmp_path, monkeypatch) -> Path:
    """A robot-set folder of its own, read by gcnt beside its own robots."""
    folder = tmp_path / "morphologies"
    folder.mkdir()
    monkeypatch.setenv(MORPHOLOGIES_ENV, str(folder))
    refresh_catalogues()
    yield folder
    refresh_catalogues()


def test_the_zip_as_downloaded_becomes_a_benchmark(unimals, morph, tmp_path, capsys):
    archive = _zip(unimals, tmp_path / "unimals_100.zip")
    assert gcnt(["import-unimal", str(archive)]) == 0
    out = capsys.readouterr().out
    assert "imported 5 UNIMAL robots" in out and "Unimal100:variants-dynamics" in out
    folder = morph / "Unimal100"
    assert load_benchmarks()["Unimal100"] == SPLITS
    for split, names in FAKE.items():  # MetaMorph's files, byte for byte, in its layout
        for name in names:
            copied = folder / split / "xml" / f"{name}.xml"
            assert copied.read_bytes() == (unimals / split / "xml" / f"{name}.xml").read_bytes()
    assert not list(folder.rglob("*.pkl")) and not list(folder.rglob("*.json"))
    assert (folder / ".gitignore").read_text().splitlines()[-1] == "*"
    robots = resolve_robots(["Unimal100:test", "floor-5506-10-6-01-15-48-35"])
    assert [r.name for r in robots] == [*FAKE["test"], FAKE["train"][1]]
    assert {(r.catalogue, r.family) for r in robots} == {("unimal", "unimal")}

    assert gcnt(["robots"]) == 0  # listed with its splits and next to gcnt's generated set
    listing = capsys.readouterr().out
    assert "Unimal100:variants-kinematics" in listing and "Unimal100:train (2)" in listing


def test_a_folder_feeds_a_unimal_recipe_and_its_env(unimals, morph):
    from gcnt.envs.benchmark import get_benchmark
    from gcnt.recipes import load_recipe
    from gcnt.rl.factories import train_robots

    imported = import_unimals(unimals.parent)  # the folder the archive was unpacked in
    assert imported.folder == morph / "Unimal100" and imported.splits == SPLITS
    recipe = load_recipe(ROOT / "recipes/unimal/ft_unimal100.yaml")
    robots = train_robots(recipe)
    assert [r.name for r in robots] == FAKE["train"]
    env = get_benchmark(recipe.env.benchmark).make_env(
        resolve_robots(recipe.env.test_robots) + robots, seed=0, num_threads=1
    )
    td = env.reset()
    assert td["limbs", "obs"].shape[0] == 3
    action = torch.zeros(env.action_spec["limbs", "action"].shape)
    td = env.step(TensorDict({("limbs", "action"): action}, batch_size=[3]))
    assert np.isfinite(td["next", "reward"].numpy()).all()
    env.close()


def test_another_name_and_out_folder(unimals, morph, tmp_path, capsys, monkeypatch):
    other = tmp_path / "elsewhere"
    assert gcnt(["import-unimal", str(unimals), "--name", "Paper", "--out", str(other)]) == 0
    assert f"GCNT_MORPHOLOGIES={other}" in capsys.readouterr().out
    assert (other / "Paper" / "catalogue.yaml").is_file()
    assert "Paper" not in load_benchmarks()  # gcnt reads the user's folder only
    # as it advises: the set is added to gcnt's own robots, which stay
    monkeypatch.setenv(MORPHOLOGIES_ENV, str(other))
    refresh_catalogues()
    benchmarks = load_benchmarks()
    assert benchmarks["Paper"]["test"] == FAKE["test"]
    assert {"Walker++", "CWHH++", "Unimal"} <= set(benchmarks)
    assert gcnt(["robots", "Paper:test", "walker_7_main"]) == 0


def test_the_user_folder_is_the_default_and_may_be_relative(unimals, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv(MORPHOLOGIES_ENV, raising=False)
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))
    imported = import_unimals(unimals)
    assert imported.folder == tmp_path / "xdg" / "gcnt" / "morphologies" / "Unimal100"
    assert load_benchmarks()["Unimal100"]["test"] == FAKE["test"]
    assert not (morphologies_dir() / "Unimal100").exists()  # never into gcnt's own folder
    # a relative GCNT_MORPHOLOGIES reads as the absolute folder it names
    monkeypatch.setenv(MORPHOLOGIES_ENV, "sets")
    assert gcnt(["import-unimal", str(unimals), "--name", "Rel"]) == 0
    assert (tmp_path / "sets" / "Rel" / "catalogue.yaml").is_file()
    assert load_benchmarks()["Rel"]["train"] == FAKE["train"]
    assert [r.name for r in resolve_robots(["Rel:test", "walker_7_main"])] == [
        *FAKE["test"],
        "walker_7_main",
    ]


def test_out_onto_a_file_is_one_line(unimals, morph, tmp_path, capsys):
    target = tmp_path / "a-file"
    target.write_text("mine\n")
    line = error_line(capsys, ["import-unimal", str(unimals), "--out", str(target)])
    assert line == f"gcnt import-unimal: error: --out {target}: not a folder; give the " + (
        "robot-set folder to import into"
    )
    assert target.read_text() == "mine\n"


def test_a_damaged_imported_set_is_left_out_with_one_warning(unimals, morph, caplog, capsys):
    import_unimals(unimals)
    (morph / "Unimal100" / "test" / "xml" / f"{FAKE['test'][0]}.xml").unlink()
    refresh_catalogues()
    with caplog.at_level("WARNING"):
        assert [r.name for r in resolve_robots(["hopper_3", "CWHH++:test"])][0] == "hopper_3"
        assert gcnt(["robots", "walker_3_main"]) == 0
    warned = [r.getMessage() for r in caplog.records if "left out" in r.getMessage()]
    assert len(warned) == 1, warned
    assert str(morph / "Unimal100") in warned[0] and FAKE["test"][0] in warned[0], warned[0]


def test_a_second_import_into_one_folder_waits_its_turn(unimals, morph, tmp_path, capsys):
    """While one import holds the folder, a second is one line; a temporary folder left by a
    killed import is removed by the next one; SIGTERM removes the import's own."""
    import os
    import signal
    import subprocess
    import sys
    import time

    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    stale = morph / ".Old.importing-999999999"  # no such process
    (stale / "train").mkdir(parents=True)
    with holding("gcnt.morphology.unimal.imported:_import_lock", morph) as holder:
        line = error_line(capsys, ["import-unimal", str(unimals)])
        assert f"{morph}: another gcnt import-unimal (process {holder.pid})" in line, line
    assert stale.exists() and not (morph / "Unimal100").exists()
    assert gcnt(["import-unimal", str(unimals)]) == 0
    assert not stale.exists()

    # SIGTERM while the files are checked: a one-line end, nothing left behind
    code = (
        "import signal, sys\n"
        "import gcnt.morphology.unimal.imported as m\n"
        "check = m.check_member\n"
        "def slow(member):\n"
        "    print('checking', flush=True); signal.pause()  # until SIGTERM\n"
        "m.check_member = slow\n"
        "from gcnt.cli import main\n"
        "sys.exit(main(['import-unimal', sys.argv[1], '--name', 'Other', '--out', sys.argv[2]]))\n"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", code, str(unimals), str(tmp_path / "out")],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    assert proc.stdout.readline() == f"checking every robot file of {unimals} ...\n"
    assert proc.stdout.readline() == "checking\n"
    time.sleep(0.2)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err
    assert err.strip() == "gcnt import-unimal: stopped by SIGTERM; nothing was imported", err
    assert list((tmp_path / "out").iterdir()) == []


def _set_without(unimals: Path, tmp_path: Path, folder: str) -> Path:
    import shutil

    copy = tmp_path / "partial" / "unimals_100"
    shutil.copytree(unimals, copy)
    shutil.rmtree(copy / folder)
    return copy


def _bad_file(unimals: Path, tmp_path: Path, name: str, text: str) -> Path:
    import shutil

    copy = tmp_path / f"with-{name}" / "unimals_100"
    shutil.copytree(unimals, copy)
    (copy / "train" / "xml" / name).write_text(text)
    return copy


def test_refusals_name_the_culprit_and_leave_nothing(unimals, morph, tmp_path, capsys):
    walker = (morphologies_dir() / "smpenv" / "walker_2_main.xml").read_text()
    cases = [
        (_set_without(unimals, tmp_path, "test"), "no test/xml/ folder"),
        (_zip(unimals, tmp_path / "no_test.zip", skip="test"), "no unimals_100/test/xml/ files"),
        (_bad_file(unimals, tmp_path, "broken.xml", "<mujoco><worldbody>"), "broken.xml"),
        (
            _zip(unimals, tmp_path / "bad.zip", extra=[("unimals_100/test/xml/x.xml", "<a")]),
            "bad.zip:unimals_100/test/xml/x.xml",
        ),
        (_bad_file(unimals, tmp_path, "walker.xml", walker), "walker.xml: not a UNIMAL robot"),
        (tmp_path / "missing.zip", "missing.zip: does not exist"),
    ]
    for source, expected in cases:
        line = error_line(capsys, ["import-unimal", str(source)])
        assert expected in line, line
        assert sorted(p.name for p in morph.iterdir() if not p.is_symlink()) == []
    taken = _bad_file(unimals, tmp_path, "unimal_0000.xml", _robot_xml("unimal_0903"))
    line = error_line(capsys, ["import-unimal", str(taken)])
    assert "unimal_0000.xml: robot 'unimal_0000' is already a robot of catalogue 'unimal'" in line
    line = error_line(capsys, ["import-unimal", str(unimals), "--name", "unimal"])
    assert "'unimal' is already a catalogue or benchmark" in line
    line = error_line(capsys, ["import-unimal", str(unimals), "--name", "walker++"])
    assert "'Walker++' is already a catalogue or benchmark" in line
    assert gcnt(["import-unimal", str(unimals)]) == 0
    line = error_line(capsys, ["import-unimal", str(unimals)])
    assert f"{morph / 'Unimal100'}: already imported; remove the folder" in line


def test_every_robot_name_given_twice_is_named_in_the_one_line(unimals, morph, tmp_path, capsys):
    import shutil

    copy = tmp_path / "twice" / "unimals_100"
    shutil.copytree(unimals, copy)
    for name in FAKE["train"]:  # both training robots also in the test set
        shutil.copy(copy / "train" / "xml" / f"{name}.xml", copy / "test" / "xml")
    line = error_line(capsys, ["import-unimal", str(copy)])
    assert "robot names given to more than one file (2)" in line, line
    for name in FAKE["train"]:
        files = f"{copy / 'train' / 'xml' / name}.xml, {copy / 'test' / 'xml' / name}.xml"
        assert f"'{name}' ({files})" in line, line
    assert sorted(p.name for p in morph.iterdir() if not p.is_symlink()) == []


def test_gcnt_robots_says_which_unimal_robots_it_lists(capsys):
    assert gcnt(["robots"]) == 0
    out = capsys.readouterr().out
    assert "not the paper's\nevolved UNIMAL-100" in out and "gcnt import-unimal" in out
    assert "MJCF3D:train" in out and "Mjcf3d" not in out  # the benchmark's display name


def test_the_paper_robots_before_their_import_name_the_command(capsys):
    from cli_helpers import error_line

    line = error_line(capsys, ["robots", "Unimal100:train"])
    assert "not imported here" in line and "gcnt import-unimal unimals_100.zip" in line


def test_the_out_folders_own_catalogues_are_the_ones_checked(unimals, morph, tmp_path, capsys):
    other = tmp_path / "elsewhere"
    assert gcnt(["import-unimal", str(unimals), "--name", "Paper", "--out", str(other)]) == 0
    line = error_line(
        capsys, ["import-unimal", str(unimals), "--name", "Again", "--out", str(other)]
    )
    assert "is already a robot of catalogue 'Paper'" in line, line
    line = error_line(
        capsys, ["import-unimal", str(unimals), "--name", "paper", "--out", str(other)]
    )
    assert "'Paper' is already a catalogue or benchmark" in line, line
    assert gcnt(["import-unimal", str(unimals)]) == 0  # the folder gcnt reads has no Paper


def test_a_copy_of_an_imported_folder_is_left_out_with_a_warning(unimals, morph, caplog):
    import shutil

    import_unimals(unimals)
    shutil.copytree(morph / "Unimal100", morph / "Unimal100.bak")
    refresh_catalogues()
    with caplog.at_level("WARNING"):
        assert [r.name for r in resolve_robots(["hopper_3", "Unimal100:test"])] == [
            "hopper_3",
            *FAKE["test"],
        ]
    warned = [r.getMessage() for r in caplog.records if "left out" in r.getMessage()]
    assert len(warned) == 1 and str(morph / "Unimal100.bak") in warned[0], warned
    assert str(morph / "Unimal100") in warned[0].split("defined by")[1]


def test_encrypted_archives_and_hidden_files_of_a_folder(unimals, morph, tmp_path, capsys):
    import shutil

    archive = _zip(unimals, tmp_path / "locked.zip")
    data = bytearray(archive.read_bytes())
    name = f"unimals_100/test/xml/{FAKE['test'][0]}.xml".encode()
    for header, flags, name_at in ((b"PK\x03\x04", 6, 30), (b"PK\x01\x02", 8, 46)):
        at = data.index(header)  # mark the entry encrypted (flag bit 0)
        while data[at + name_at : at + name_at + len(name)] != name:
            at = data.index(header, at + 1)
        data[at + flags] |= 0x1
    archive.write_bytes(bytes(data))
    line = error_line(capsys, ["import-unimal", str(archive)])
    assert "locked.zip:unimals_100/test/xml/" in line and "cannot read it" in line, line

    copy = tmp_path / "mac" / "unimals_100"
    shutil.copytree(unimals, copy)
    (copy / "train" / "xml" / f"._{FAKE['train'][0]}.xml").write_bytes(b"\x00\x05\x16\x07")
    assert import_unimals(copy).splits == SPLITS


def test_gcnt_robots_lists_an_imported_folder_by_its_benchmark_name(unimals, morph, capsys):
    import_unimals(unimals, name="Paper")
    (morph / "Paper").rename(morph / "renamed")  # the folder's name is not the benchmark's
    refresh_catalogues()
    capsys.readouterr()
    assert gcnt(["robots"]) == 0
    assert "Paper:train (2)" in capsys.readouterr().out
