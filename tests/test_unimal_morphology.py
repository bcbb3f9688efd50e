"""UNIMAL robots: the generator's properties, the file layout, loading, mutations, the checked-in set."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gcnt.cli import main as cli_main
from gcnt.morphology import GLOBAL_TYPE_ID, RobotFileError, load_robot, robot_from_xml
from gcnt.morphology.catalogues import load_benchmarks, morphologies_dir, resolve_robots
from gcnt.morphology.unimal import OPERATORS, Rng, build_mjcf, generate, make_variant, mutate
from gcnt.morphology.unimal.catalogue import load_unimal, robot_name, split_yaml, topology
from gcnt.morphology.unimal.mjcf import rest_state
from gcnt.morphology.unimal.mutate import TOPOLOGY_KEEPING
from gcnt.morphology.unimal.space import MAX_LIMBS

FIXTURE = Path(__file__).parent / "data" / "unimal" / "unimal_fixture.xml"
SEEDS = st.integers(min_value=0, max_value=10**6)


def loaded(u, name="u"):
    return robot_from_xml(build_mjcf(u), name=name)


# ------------------------------------------------------------------------------ generator


@settings(max_examples=8, deadline=None)
@given(seed=SEEDS)
def test_generated_robots_are_valid_and_deterministic(seed):
    u = generate(seed)
    text = build_mjcf(u)
    assert text == build_mjcf(generate(seed))
    assert 1 <= len(u.limbs) <= MAX_LIMBS
    assert all(1 <= len(limb.hinges) <= 2 for limb in u.limbs)
    for i, limb in enumerate(u.limbs):  # mirrored pairs mirror each other
        if limb.mirror >= 0:
            m = u.limbs[limb.mirror]
            assert m.mirror == i and (m.h, m.hinges, m.phi) == (limb.h, limb.hinges, limb.phi)
            if limb.parent == m.parent:
                assert (limb.theta + m.theta) % 360 == 0
            else:
                assert u.limbs[limb.parent].mirror == m.parent and m.theta == limb.theta
        else:
            assert limb.theta in (0, 180) or limb.phi == 180
    model, data = rest_state(text)
    assert abs(data.subtree_com[1, 1]) < 1e-12  # float64: exactly mirrored numbers
    assert data.ncon == 0  # nothing touches at rest (with the file's own excludes)
    torso_z = model.body("torso/0").pos[2]
    lowest = min(
        data.site_xpos[s, 2] for s in range(model.nsite) if "btm_pos" in model.site(s).name
    )
    assert lowest == pytest.approx(0.2, abs=0.011) and torso_z > 0.2
    r = robot_from_xml(text, name="g")
    assert r.num_motors == u.num_dof and r.num_limbs == len(u.limbs) + 1


def test_hinge_axes_are_the_capsule_frame_axes():
    for seed in range(5):
        model, data = rest_state(build_mjcf(generate(seed)))
        for j in range(model.njnt):
            if model.jnt_type[j] != mujoco.mjtJoint.mjJNT_HINGE:
                continue
            geom = model.body_geomadr[model.jnt_bodyid[j]]
            frame = data.geom_xmat[geom].reshape(3, 3)
            column = "xy".index(model.joint(j).name[4])  # limbx/i, limby/i
            np.testing.assert_allclose(model.jnt_axis[j], frame[:, column], atol=1e-4)


def test_loaded_slots_and_types_follow_the_tree_and_axes():
    r = loaded(generate(11))
    assert r.catalogue == "unimal" and r.family == "unimal"
    for limb, names in enumerate(r.joint_names):
        assert r.action_slots(limb) == tuple("xy".index(n[4]) for n in names)
    kids = {int(p) for p in r.parents if p >= 0}
    for i, p in enumerate(r.parents):
        want = (
            "torso" if p < 0
            else "unimal_proximal" if p == 0
            else "unimal_inner" if i in kids
            else "unimal_distal"
        )  # fmt: skip
        assert r.global_types[i] == GLOBAL_TYPE_ID[want]
    assert GLOBAL_TYPE_ID["unimal_proximal"] > GLOBAL_TYPE_ID["lower_arm"]  # appended ids


# ------------------------------------------------------------------------------ mutations


@pytest.mark.parametrize("op", sorted(OPERATORS))
def test_mutations(op):
    u = generate(1)  # 6 limbs: room to grow, leaves to delete
    v = mutate(u, op, Rng(op))
    assert v != u and mutate(u, op, Rng(op)) == v
    a, b = loaded(u), loaded(v)
    if op in TOPOLOGY_KEEPING:
        assert np.array_equal(a.parents, b.parents) and a.joint_names == b.joint_names
        assert a.joint_slots == b.joint_slots and np.array_equal(a.global_types, b.global_types)
    elif op == "grow_limb":
        assert b.num_limbs > a.num_limbs
    elif op == "delete_limb":
        assert b.num_limbs < a.num_limbs


def test_variant_splits():
    bench = load_benchmarks()["Unimal"]
    assert len(bench["variants-dynamics"]) == len(bench["variants-kinematics"]) == 400
    base = generate(3)
    for name in ("unimal_0003-gear1", "unimal_0003-length2"):
        v = make_variant(base, name)
        assert v == make_variant(base, name) and topology(v) == topology(base)
    r = resolve_robots(["unimal_0003-density1"])[0]
    assert r.name == "unimal_0003-density1" and r.catalogue == "unimal"
    assert np.array_equal(r.parents, resolve_robots(["unimal_0003"])[0].parents)


# ------------------------------------------------------------------------------ the checked-in set


def test_checked_in_set():
    bench = load_benchmarks()["Unimal"]
    train, test = bench["train"], bench["test"]
    assert train == [robot_name(s) for s in range(100)] and len(test) == 100
    folder = morphologies_dir() / "unimal"
    assert (morphologies_dir() / "unimal.yaml").read_text() == split_yaml(train, test)
    for name in (train[0], train[57], test[0], test[-1]):  # byte-identical on regeneration
        seed = int(name.removeprefix("unimal_"))
        assert (folder / f"{name}.xml").read_text() == build_mjcf(generate(seed)), name

    def tree(robot):
        kids = {i: [] for i in range(robot.num_limbs)}
        for i, p in enumerate(robot.parents[1:], start=1):
            kids[int(p)].append(i)

        def enc(i):
            return "(" + "".join(sorted(enc(c) for c in kids[i])) + ")"

        return enc(0)

    robots = resolve_robots(["Unimal:all"])
    assert all(r.num_limbs <= 11 and r.catalogue == "unimal" for r in robots)
    assert not {tree(r) for r in robots[:100]} & {tree(r) for r in robots[100:]}


# ------------------------------------------------------------------------------ files and errors


def test_hand_written_unimal_file_loads():
    r = load_unimal(FIXTURE)
    assert r.body_names == ("torso/0", "limb/0", "limb/2", "limb/1", "limb/3", "limb/4")
    assert r.parents.tolist() == [-1, 0, 1, 0, 3, 0]
    assert r.joint_names[1] == ("limby/0", "limbx/0")  # y listed first in the file...
    assert r.joint_slots[1] == (1, 0)  # ...still goes to slot 1, by its axis
    assert r.joint_slots[5] == (1,) and r.num_motors == 7 and r.catalogue == "unimal"
    assert r.global_types.tolist() == [GLOBAL_TYPE_ID[t] for t in (
        "torso", "unimal_proximal", "unimal_distal", "unimal_proximal", "unimal_distal",
        "unimal_proximal",
    )]  # fmt: skip


def bad(tmp_path, old: str, new: str, count: int = 1) -> str:
    text = FIXTURE.read_text()
    assert old in text
    path = tmp_path / "bad_unimal.xml"
    path.write_text(text.replace(old, new, count))
    with pytest.raises(RobotFileError) as info:
        load_unimal(path)
    assert str(path) in str(info.value)
    return str(info.value)


def test_bad_unimal_files_name_file_and_culprit(tmp_path):
    walker = morphologies_dir() / "smpenv" / "walker_2_main.xml"
    with pytest.raises(RobotFileError, match=f"{walker}.*not a UNIMAL robot"):
        load_unimal(walker)
    msg = bad(tmp_path, '<joint name="root" type="free" class="free" />', "")
    assert "'torso/0'" in msg and "free root" in msg
    extra = '<joint name="limbz/4" type="hinge" class="normal_joint" axis="0 0 1" />'
    msg = bad(tmp_path, '<geom name="limb/4"', extra + '<geom name="limb/4"')
    assert "'limbz/4'" in msg  # a third hinge, about the limb's own axis, has no motor
    extra = '<joint name="limbq/4" type="hinge" axis="0 1 0" /><joint name="limbr/4" axis="1 0 0"/>'
    motors = '<motor joint="limbq/4" name="q" /><motor joint="limbr/4" name="r" /></actuator>'
    text = FIXTURE.read_text().replace('<geom name="limb/4"', extra + '<geom name="limb/4"')
    path = tmp_path / "three_hinges.xml"
    path.write_text(text.replace("</actuator>", motors))
    with pytest.raises(RobotFileError, match="'limb/4' has 3 joints.*at most 2"):
        load_unimal(path)
    msg = bad(tmp_path, '<motor gear="150" joint="limby/4" name="limby/4" />',
              '<motor gear="150" joint="limby/4" name="limby/4" /><motor gear="1" name="loose" />')  # fmt: skip
    assert "'loose'" in msg and "no joint" in msg
    many = "".join(
        f'<body name="extra/{k}" pos="0.1 0 0"><joint name="ey/{k}" type="hinge" axis="0 1 0"/>'
        f'<geom fromto="0 0 0 0.45 0 0" size="0.05"/></body>'
        for k in range(7)
    )
    motors = "".join(f'<motor joint="ey/{k}" name="ey/{k}" />' for k in range(7)) + "</actuator>"
    text = FIXTURE.read_text().replace("\t\t</body>\n\t</worldbody>", many + "</body></worldbody>")
    path = tmp_path / "too_many.xml"
    path.write_text(text.replace("</actuator>", motors))
    with pytest.raises(RobotFileError, match="13 bodies.*at most 12"):
        load_unimal(path)


def test_robots_command_lists_folders_and_generates(tmp_path, capsys):
    assert cli_main(["robots", str(FIXTURE.parent), "hopper_3"]) == 0
    out = capsys.readouterr().out
    assert "unimal_fixture" in out and "limb/4" in out and "published train" in out
    assert cli_main(["robots", "--generate", "2", "--seed", "7", "--out", str(tmp_path)]) == 0
    assert (tmp_path / "unimal_0008.xml").read_text() == build_mjcf(generate(8))
    assert load_robot(tmp_path / "unimal_0007.xml").catalogue == "unimal"
