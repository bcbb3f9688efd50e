"""The checked-in SMPENV robot files against the spec's fact tables, and the benchmark splits."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import mujoco
import numpy as np
import pytest

from gcnt.cli import main as cli_main
from gcnt.morphology import load_robot
from gcnt.morphology.catalogues import (
    BenchmarkFileError,
    load_benchmarks,
    morphologies_dir,
    resolve_robots,
)
from gcnt.morphology.smpenv import (
    SMPENV_FULL_ROBOTS,
    SMPENV_ROBOTS,
    build_mjcf,
    full_robot_of,
    write_all,
)

REFERENCE = json.loads((Path(__file__).parent / "data" / "smpenv_reference.json").read_text())[
    "robots"
]
SMPENV_DIR = morphologies_dir() / "smpenv"
RTOL = 1e-4
ATOL = 1e-6


def compile_file(name: str) -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_path(str(SMPENV_DIR / f"{name}.xml"))


def close(actual, expected, what: str) -> None:
    np.testing.assert_allclose(
        np.asarray(actual, dtype=float), np.asarray(expected, dtype=float), RTOL, ATOL, err_msg=what
    )


JOINT_TYPES = {"slide": mujoco.mjtJoint.mjJNT_SLIDE, "hinge": mujoco.mjtJoint.mjJNT_HINGE}
GEOM_TYPES = {
    "capsule": mujoco.mjtGeom.mjGEOM_CAPSULE,
    "sphere": mujoco.mjtGeom.mjGEOM_SPHERE,
}
INTEGRATORS = {"RK4": mujoco.mjtIntegrator.mjINT_RK4, "Euler": mujoco.mjtIntegrator.mjINT_EULER}


def test_reference_covers_the_six_distinct_robots():
    assert set(REFERENCE) == set(SMPENV_FULL_ROBOTS.values())


@pytest.mark.parametrize("name", sorted(REFERENCE))
def test_full_robot_matches_the_fact_tables(name):
    ref = REFERENCE[name]
    m = compile_file(name)
    close(m.opt.timestep, ref["timestep"], "timestep")
    assert m.opt.integrator == INTEGRATORS[ref["integrator"]]
    assert m.nbody - 1 == ref["nbody"]
    assert abs(m.body_mass.sum() - ref["total_mass"]) < 6e-4

    # bodies, in this order (depth-first pre-order)
    assert [m.body(b).name for b in range(1, m.nbody)] == [b["name"] for b in ref["bodies"]]
    for b in ref["bodies"]:
        body = m.body(b["name"])
        assert m.body(int(body.parentid[0])).name == b["parent"], b["name"]
        close(body.pos, b["pos"], f"{name} body {b['name']} pos")
        close(body.quat, b["quat"], f"{name} body {b['name']} quat")
        assert abs(body.mass[0] - b["mass"]) <= 5.01e-5, (b["name"], body.mass[0], b["mass"])

    # geoms: the floor plus the robot's
    robot_geoms = [m.geom(g).name for g in range(m.ngeom) if m.geom_bodyid[g] != 0]
    assert robot_geoms == [g["name"] for g in ref["geoms"]]
    for g in ref["geoms"]:
        geom = m.geom(g["name"])
        what = f"{name} geom {g['name']}"
        assert m.body(int(geom.bodyid[0])).name == g["body"], what
        assert geom.type[0] == GEOM_TYPES[g["type"]], what
        close(geom.size[: len(g["size"])], g["size"], f"{what} size")
        assert np.all(geom.size[len(g["size"]) :] == 0), what
        close(geom.pos, g["pos"], f"{what} pos")
        close(geom.quat, g["quat"], f"{what} quat")
        close(geom.friction, g["friction"], f"{what} friction")
        assert (geom.contype[0], geom.conaffinity[0], geom.condim[0]) == (
            g["contype"],
            g["conaffinity"],
            g["condim"],
        ), what
        close(geom.solref, ref["geom_solref"], f"{what} solref")
        close(geom.solimp, ref["geom_solimp"], f"{what} solimp")
        close(geom.margin, ref["geom_margin"], f"{what} margin")

    floor = m.geom("floor")
    assert floor.type[0] == mujoco.mjtGeom.mjGEOM_PLANE and floor.bodyid[0] == 0
    close(floor.friction, ref["floor"]["friction"], "floor friction")
    assert (floor.contype[0], floor.conaffinity[0], floor.condim[0]) == (
        ref["floor"]["contype"],
        ref["floor"]["conaffinity"],
        ref["floor"]["condim"],
    )
    half = 20.0 if name.startswith(("hopper", "humanoid")) else 40.0
    close(floor.size[:2], [half, half], "floor size")

    # joints
    assert [m.joint(j).name for j in range(m.njnt)] == [j["name"] for j in ref["joints"]]
    for j in ref["joints"]:
        joint = m.joint(j["name"])
        what = f"{name} joint {j['name']}"
        dof = int(joint.dofadr[0])
        assert m.body(int(joint.bodyid[0])).name == j["body"], what
        assert joint.type[0] == JOINT_TYPES[j["type"]], what
        close(joint.axis, j["axis"], f"{what} axis")
        close(joint.pos, j["pos"], f"{what} pos")
        assert bool(joint.limited[0]) == j["limited"], what
        if j["range"] is not None:
            close(joint.range, j["range"], f"{what} range")
        close(m.qpos0[joint.qposadr[0]], j["ref"], f"{what} ref")
        close(joint.stiffness, j["stiffness"], f"{what} stiffness")
        close(m.dof_damping[dof], j["damping"], f"{what} damping")
        close(m.dof_armature[dof], j["armature"], f"{what} armature")
        close(joint.solref, ref["joint_solreflimit"], f"{what} solreflimit")
        close(joint.solimp, ref["joint_solimplimit"], f"{what} solimplimit")

    # actuators: one motor per limb joint, gear and ctrlrange
    assert m.nu == len(ref["actuators"])
    for a, act in enumerate(ref["actuators"]):
        assert m.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT
        assert m.joint(int(m.actuator_trnid[a, 0])).name == act["joint"]
        close(m.actuator_gear[a, 0], act["gear"], f"{name} gear {act['joint']}")
        assert np.all(m.actuator_gear[a, 1:] == 0)
        assert m.actuator_ctrllimited[a]
        close(m.actuator_ctrlrange[a], act["ctrlrange"], f"{name} ctrlrange {act['joint']}")


EXPECTED_BODIES = {
    **{f"walker_{n}_main": n for n in range(2, 8)},
    **{n: int(n.split("_")[1]) for n in SMPENV_ROBOTS if n.startswith("cheetah")},
    **{n: int(n.split("_")[2]) for n in SMPENV_ROBOTS if n.startswith("humanoid")},
    "hopper_3": 3,
    "hopper_4": 4,
    "hopper_5": 5,
}


def test_the_32_names():
    assert len(SMPENV_ROBOTS) == 32 == len(set(SMPENV_ROBOTS))
    assert set(EXPECTED_BODIES) == set(SMPENV_ROBOTS)
    assert sorted(p.stem for p in SMPENV_DIR.glob("*.xml")) == sorted(SMPENV_ROBOTS)


@pytest.mark.parametrize("name", SMPENV_ROBOTS)
def test_every_robot_loads_and_is_a_subtree_of_its_full_robot(name):
    m = compile_file(name)
    assert m.nbody - 1 == EXPECTED_BODIES[name]
    robot = load_robot(SMPENV_DIR / f"{name}.xml")
    assert robot.name == name
    assert robot.num_limbs == EXPECTED_BODIES[name]
    assert robot.num_motors == robot.num_limbs - 1 == m.nu
    assert all(len(j) == 1 for j in robot.joint_names[1:])
    assert robot.family == name.split("_")[0]

    full = compile_file(full_robot_of(name))
    for field in ("timestep", "integrator", "gravity"):
        assert np.all(getattr(m.opt, field) == getattr(full.opt, field)), field
    # every body / geom / joint / motor exists in the full robot with identical parameters
    for b in range(1, m.nbody):
        nm = m.body(b).name
        fb = full.body(nm)
        assert m.body(int(m.body_parentid[b])).name == full.body(int(fb.parentid[0])).name
        for attr in ("pos", "quat", "mass", "inertia", "ipos", "iquat"):
            assert np.array_equal(getattr(m.body(b), attr), getattr(fb, attr)), (nm, attr)
    geom_attrs = ("type", "size", "pos", "quat", "friction", "contype", "conaffinity", "condim",
                  "solref", "solimp", "margin")  # fmt: skip
    for g in range(m.ngeom):
        nm = m.geom(g).name
        fg = full.geom(nm)
        assert m.body(int(m.geom_bodyid[g])).name == full.body(int(fg.bodyid[0])).name
        for attr in geom_attrs:
            assert np.array_equal(getattr(m.geom(g), attr), getattr(fg, attr)), (nm, attr)
    for j in range(m.njnt):
        nm = m.joint(j).name
        fj = full.joint(nm)
        for attr in ("type", "axis", "pos", "range", "limited", "stiffness", "solref", "solimp"):
            assert np.array_equal(getattr(m.joint(j), attr), getattr(fj, attr)), (nm, attr)
        assert m.qpos0[m.jnt_qposadr[j]] == full.qpos0[fj.qposadr[0]]
        d, fd = m.jnt_dofadr[j], fj.dofadr[0]
        assert m.dof_damping[d] == full.dof_damping[fd]
        assert m.dof_armature[d] == full.dof_armature[fd]
    for a in range(m.nu):
        fa = full.actuator(m.actuator(a).name)
        assert np.array_equal(m.actuator_gear[a], fa.gear)
        assert np.array_equal(m.actuator_ctrlrange[a], fa.ctrlrange)
    # variants differ only by whole subtrees: a kept body's parent chain is all kept, and each
    # removed body is the root of a subtree with none of its descendants kept
    kept = {m.body(b).name for b in range(m.nbody)}
    for b in range(1, full.nbody):
        nm = full.body(b).name
        parent = full.body(int(full.body_parentid[b])).name
        if nm in kept:
            assert parent in kept


def test_variants_match_the_spec_table():
    def bodies(name):
        m = compile_file(name)
        return {m.body(b).name for b in range(2, m.nbody)}  # limbs (no world, no torso)

    assert bodies("walker_2_main") == {"left1"}
    assert bodies("walker_3_main") == {"left1", "right1"}
    assert bodies("walker_4_main") == {"left1", "left2", "right1"}
    assert bodies("walker_6_main") == {"left1", "left2", "left3", "right1", "right2"}
    assert bodies("cheetah_5_back") == {"bthigh", "bshin", "bfoot", "fthigh"}
    assert bodies("cheetah_4_front") == {"bthigh", "fthigh", "fshin"}
    assert bodies("cheetah_3_balanced") == {"bthigh", "fthigh"}
    full_h = bodies("humanoid_2d_9_full")
    assert bodies("humanoid_2d_7_left_arm") == full_h - {"left_upper_arm", "left_lower_arm"}
    assert bodies("humanoid_2d_7_lower_arms") == full_h - {"left_lower_arm", "right_lower_arm"}
    assert bodies("humanoid_2d_7_right_leg") == full_h - {"right_thigh", "right_shin"}
    assert bodies("humanoid_2d_8_left_knee") == full_h - {"left_shin"}


def test_regeneration_is_byte_identical(tmp_path):
    paths = write_all(tmp_path)
    assert [p.name for p in paths] == [f"{n}.xml" for n in SMPENV_ROBOTS]
    for p in paths:
        assert p.read_bytes() == (SMPENV_DIR / p.name).read_bytes(), p.name
    assert build_mjcf("cheetah_6_front") == build_mjcf("cheetah_6_front")


def test_unknown_robot_names_close_matches():
    with pytest.raises(ValueError, match="walker_7_main"):
        build_mjcf("walker_7_mian")


SPLITS = {
    "Walker++": (4, 2),
    "Cheetah++": (12, 3),
    "Humanoid++": (6, 2),
    "Hopper++": (3, 0),
    "CWHH++": (25, 7),
}


def test_benchmark_splits():
    bench = load_benchmarks(catalogue="smpenv")
    assert {k: (len(v["train"]), len(v["test"])) for k, v in bench.items()} == SPLITS
    assert set(bench["Walker++"]["test"]) == {"walker_3_main", "walker_6_main"}
    assert set(bench["Cheetah++"]["test"]) == {
        "cheetah_3_balanced",
        "cheetah_5_back",
        "cheetah_6_front",
    }
    assert set(bench["Humanoid++"]["test"]) == {
        "humanoid_2d_7_left_leg",
        "humanoid_2d_8_right_knee",
    }
    four = ("Walker++", "Cheetah++", "Humanoid++", "Hopper++")
    for split in ("train", "test"):
        union = [r for b in four for r in bench[b][split]]
        assert sorted(bench["CWHH++"][split]) == sorted(union)
    for b in four:
        assert not set(bench[b]["train"]) & set(bench[b]["test"])
        fam = {n.split("_")[0] for n in bench[b]["train"] + bench[b]["test"]}
        assert len(fam) == 1
    everything = set(bench["CWHH++"]["train"]) | set(bench["CWHH++"]["test"])
    assert everything == set(SMPENV_ROBOTS)


def test_resolve_robots():
    robots = resolve_robots(["Walker++:test", "hopper_4", str(SMPENV_DIR / "cheetah_2_back.xml")])
    assert [r.name for r in robots] == [
        "walker_3_main",
        "walker_6_main",
        "hopper_4",
        "cheetah_2_back",
    ]
    assert [r.name for r in resolve_robots(["Hopper++"])] == ["hopper_3", "hopper_4", "hopper_5"]
    assert len(resolve_robots(["CWHH++:train"])) == 25
    with pytest.raises(ValueError, match="walker_7_main"):
        resolve_robots(["walker_7"])
    with pytest.raises(ValueError, match="Walker\\+\\+"):
        resolve_robots(["Walkr++:train"])
    with pytest.raises(ValueError, match="split"):
        resolve_robots(["Walker++:validation"])


def test_benchmark_file_errors_name_the_culprit(tmp_path):
    bad = tmp_path / "bench.yaml"
    bad.write_text("Walker++:\n  train: [walker_2_main, walker_9_main]\n  test: []\n")
    with pytest.raises(BenchmarkFileError, match="walker_9_main") as info:
        load_benchmarks(bad)
    assert str(bad) in str(info.value)
    bad.write_text("Walker++:\n  train: [walker_2_main]\n  validate: [walker_3_main]\n")
    with pytest.raises(BenchmarkFileError, match="validate"):
        load_benchmarks(bad)
    bad.write_text("Walker++:\n  train: [walker_2_main]\n  test: [walker_2_main]\n")
    with pytest.raises(BenchmarkFileError, match="both"):
        load_benchmarks(bad)


def test_the_user_folder_adds_to_the_packaged_robots(tmp_path, monkeypatch):
    packaged = morphologies_dir()
    assert (packaged / "smpenv.yaml").is_file()
    monkeypatch.setenv("GCNT_MORPHOLOGIES", str(tmp_path))  # an empty user folder
    assert morphologies_dir() == packaged
    assert "Walker++" in load_benchmarks()


def test_robots_command(tmp_path, monkeypatch, capsys):
    assert cli_main(["robots"]) == 0
    out = capsys.readouterr().out
    assert "CWHH++:test" in out and "humanoid_2d_8_right_knee" in out
    assert "hopper_5  " in out and "lower_leg" in out and "published train" in out

    assert cli_main(["robots", "--check", "--catalogue", "smpenv"]) == 0
    copy = tmp_path / "morph"
    shutil.copytree(morphologies_dir(), copy)
    (copy / "smpenv" / "hopper_4.xml").write_text(build_mjcf("hopper_4").replace("200", "201"))
    (copy / "smpenv" / "walker_2_main.xml").unlink()
    capsys.readouterr()
    check = ["robots", "--check", "--catalogue", "smpenv", "--out", str(copy)]
    assert cli_main(check) == 1
    out = capsys.readouterr().out
    assert "hopper_4.xml" in out and "walker_2_main.xml: missing" in out
    assert cli_main(["robots", "--rebuild", "--catalogue", "smpenv", "--out", str(copy)]) == 0
    assert cli_main(check) == 0
    assert cli_main(["robots", "walker_9"]) == 2
    assert "walker_" in capsys.readouterr().err
