"""Robots from MJCF (errors, limb order and types) and the graph features of limb trees."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gcnt.morphology import GLOBAL_TYPE_ID, RobotFileError, load_robot, smpenv_robot
from gcnt.morphology.graph import (
    RobotGraph,
    adjacency,
    check_tree,
    hop_distances,
    normalized_laplacian,
    personalized_pagerank,
    traversal_indices,
    wl_counts,
)

# ------------------------------------------------------------------------- robot file errors


def mjcf(bodies: str, actuators: str = "", model: str = "walker_test", custom: str = "") -> str:
    return f"""<mujoco model="{model}">
  <worldbody>
    <geom name="floor" type="plane" size="5 5 0.1"/>
    {bodies}
  </worldbody>
  <actuator>{actuators}</actuator>
  {custom}
</mujoco>"""


TORSO = '<body name="torso" pos="0 0 1"><joint name="rootx" type="slide" axis="1 0 0"/>'
CAPSULE = '<geom type="capsule" size="0.05" fromto="0 0 0 0 0 -0.3"/>'


def limb(name: str, joints: tuple[str, ...], inner: str = "") -> str:
    js = "".join(f'<joint name="{j}" type="hinge" axis="0 1 0" range="-1 1"/>' for j in joints)
    return f'<body name="{name}" pos="0 0 -0.3">{js}{CAPSULE}{inner}</body>'


def motor(joint: str) -> str:
    return f'<motor name="m_{joint}" joint="{joint}" gear="10" ctrlrange="-1 1"/>'


GOOD = mjcf(
    TORSO + CAPSULE + limb("left1", ("j1",), limb("left2", ("j2",))) + "</body>",
    motor("j1") + motor("j2"),
)


def load_text(tmp_path, text: str, name: str = "robot.xml"):
    path = tmp_path / name
    path.write_text(text)
    return path, load_robot(path)


def error_of(tmp_path, text: str, name: str = "bad_robot.xml") -> str:
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(RobotFileError) as info:
        load_robot(path)
    msg = str(info.value)
    assert str(path) in msg, msg  # every error names the file
    return msg


def test_a_good_file_loads(tmp_path):
    _, robot = load_text(tmp_path, GOOD)
    assert robot.body_names == ("torso", "left1", "left2")
    assert robot.parents.tolist() == [-1, 0, 1]
    assert robot.family == "walker"
    assert robot.joint_names == ((), ("j1",), ("j2",))
    assert robot.num_motors == 2


def test_unparseable_xml(tmp_path):
    msg = error_of(tmp_path, GOOD.replace("</worldbody>", ""))
    assert "not valid XML" in msg


def test_missing_file(tmp_path):
    with pytest.raises(RobotFileError, match="no_such_robot.xml"):
        load_robot(tmp_path / "no_such_robot.xml")


def test_several_root_bodies(tmp_path):
    two = TORSO + CAPSULE + limb("left1", ("j1",)) + "</body>"
    two += '<body name="second_torso" pos="2 0 1">' + CAPSULE + "</body>"
    msg = error_of(tmp_path, mjcf(two, motor("j1")))
    assert "second_torso" in msg and "root" in msg


def test_limb_without_joint(tmp_path):
    body = TORSO + CAPSULE + limb("left1", ("j1",), limb("left2", ())) + "</body>"
    msg = error_of(tmp_path, mjcf(body, motor("j1")))
    assert "'left2'" in msg and "no hinge joint" in msg


def test_limb_with_too_many_joints(tmp_path):
    body = TORSO + CAPSULE + limb("left1", ("j1", "j1b")) + "</body>"
    msg = error_of(tmp_path, mjcf(body, motor("j1") + motor("j1b")))
    assert "'left1'" in msg and "2 joints" in msg and "walker" in msg


def test_joint_without_motor(tmp_path):
    body = TORSO + CAPSULE + limb("left1", ("j1",), limb("left2", ("j2",))) + "</body>"
    msg = error_of(tmp_path, mjcf(body, motor("j1")))
    assert "'j2'" in msg and "no motor" in msg


def test_unknown_family(tmp_path):
    body = TORSO + CAPSULE + limb("left1", ("j1",)) + "</body>"
    custom = '<custom><text name="gcnt_family" data="spider"/></custom>'
    msg = error_of(tmp_path, mjcf(body, motor("j1"), custom=custom))
    assert "'spider'" in msg and "family" in msg
    msg = error_of(tmp_path, mjcf(body, motor("j1"), model="octopus_3"), name="octopus_3.xml")
    assert "'octopus_3'" in msg and "family" in msg


def test_limb_name_without_a_type_is_typed_by_its_place_in_the_tree(tmp_path):
    body = TORSO + CAPSULE + limb("tentacle", ("j1",), limb("sucker", ("j2",))) + "</body>"
    _, robot = load_text(tmp_path, mjcf(body, motor("j1") + motor("j2")))
    assert robot.global_types.tolist() == types("torso", "thigh", "shin")
    assert robot.family_slots.tolist() == [0, 1, 2]


# -------------------------------------------------------------------- known robots: order, types


def types(*names: str) -> list[int]:
    return [GLOBAL_TYPE_ID[n] for n in names]


def test_humanoid_order_parents_types():
    r = smpenv_robot("humanoid_2d_9_full")
    assert r.family == "humanoid"
    assert r.body_names == (
        "torso",
        "right_thigh",
        "right_shin",
        "left_thigh",
        "left_shin",
        "right_upper_arm",
        "right_lower_arm",
        "left_upper_arm",
        "left_lower_arm",
    )
    assert r.parents.tolist() == [-1, 0, 1, 0, 3, 0, 5, 0, 7]
    assert r.global_types.tolist() == types(
        "torso",
        "thigh",
        "shin",
        "thigh",
        "shin",
        "upper_arm",
        "lower_arm",
        "upper_arm",
        "lower_arm",
    )
    assert r.family_slots.tolist() == [0, 1, 2, 1, 2, 1, 2, 1, 2]
    assert r.joint_names[1:3] == (("right_hip_y",), ("right_knee",))
    np.testing.assert_allclose(r.joint_ranges[2], [[-2.79253, -0.0349066]])


def test_walker_cheetah_hopper_order_and_types():
    w = smpenv_robot("walker_7_main")
    assert w.body_names == ("torso", "left1", "left2", "left3", "right1", "right2", "right3")
    assert w.parents.tolist() == [-1, 0, 1, 2, 0, 4, 5]
    assert w.global_types.tolist() == types(
        "torso", "thigh", "shin", "foot", "thigh", "shin", "foot"
    )
    assert w.family_slots.tolist() == [0, 1, 2, 3, 1, 2, 3]

    c = smpenv_robot("cheetah_5_back")
    assert c.body_names == ("torso", "bthigh", "bshin", "bfoot", "fthigh")
    assert c.parents.tolist() == [-1, 0, 1, 2, 0]
    assert c.family_slots.tolist() == [0, 1, 2, 3, 1]

    h = smpenv_robot("hopper_5")
    assert h.body_names == ("torso", "thigh", "leg", "lower_leg", "foot")
    assert h.parents.tolist() == [-1, 0, 1, 2, 3]
    # lower_leg counts as leg
    assert h.global_types.tolist() == types("torso", "thigh", "shin", "shin", "foot")
    assert h.family_slots.tolist() == [0, 1, 2, 2, 3]


# --------------------------------------------------------------------- graph features, by hand

CHAIN3 = np.array([-1, 0, 1])


def test_chain_adjacency_and_distances():
    adj = adjacency(CHAIN3)
    assert adj.dtype == bool
    assert adj.astype(int).tolist() == [[0, 1, 0], [1, 0, 1], [0, 1, 0]]
    assert hop_distances(adj).tolist() == [[0, 1, 2], [1, 0, 1], [2, 1, 0]]


def test_swat_traversal_of_a_small_tree():
    # 0 has children 1, 3, 4; 1 has child 2; 4 has child 5.  Left-child right-sibling tree:
    # left(0)=1, left(1)=2, right(1)=3, right(3)=4, left(4)=5.
    # in-order  : 2 1 3 5 4 0   -> positions of limbs 0..5: 5 1 0 2 4 3
    # post-order: 2 5 4 3 1 0   -> positions of limbs 0..5: 5 4 0 3 2 1
    parents = np.array([-1, 0, 1, 0, 0, 4])
    t = traversal_indices(parents)
    assert t[:, 0].tolist() == [0, 1, 2, 3, 4, 5]
    assert t[:, 1].tolist() == [5, 1, 0, 2, 4, 3]
    assert t[:, 2].tolist() == [5, 4, 0, 3, 2, 1]


def test_ppr_and_laplacian_of_robots():
    for name in ("walker_7_main", "humanoid_2d_9_full", "cheetah_2_back", "hopper_3"):
        g = smpenv_robot(name).graph
        np.testing.assert_allclose(g.ppr.sum(1), 1.0, rtol=1e-5)
        assert (g.ppr >= 0).all()
        assert (np.diag(g.ppr) >= g.ppr.max(0) - 1e-6).all()  # a walk is most often at its start
        ev = np.linalg.eigvalsh(g.laplacian.astype(np.float64))
        assert ev.min() > -1e-5 and ev.max() < 2 + 1e-5
        assert abs(ev.min()) < 1e-5  # connected: exactly one zero eigenvalue
        assert (ev > 1e-5).sum() == len(ev) - 1


def test_check_tree_rejects_non_trees():
    for bad in ([0, 0, 1], [-1, 2, 0], [-1, 0, 3, 1], [-1, -1, 0]):
        with pytest.raises(ValueError, match="parent|root"):
            check_tree(np.array(bad))


# ---------------------------------------------------------------------------- WL colour counts

WALKER7_WL = {
    3: 2,
    7: 2,
    8: 1,
    9: 2,
    15: 1,
    26: 3,
    35: 2,
    41: 1,
    47: 2,
    50: 2,
    51: 2,
    53: 4,
    61: 2,
    63: 2,
}


def nonzero(w: np.ndarray) -> dict[int, int]:
    return {int(i): int(w[i]) for i in np.nonzero(w)[0]}


def test_wl_counts_are_pinned():
    w = smpenv_robot("walker_7_main").graph.wl
    assert w.shape == (64,) and w.dtype == np.float32
    assert nonzero(w) == WALKER7_WL
    assert w.sum() == 7 * 4  # every limb, every round (type colouring + 3 rounds)


def test_wl_counts_are_the_same_in_another_process():
    code = (
        "import json; from gcnt.morphology import smpenv_robot; "
        "print(json.dumps({n: smpenv_robot(n).graph.wl.tolist() "
        "for n in ['walker_7_main', 'humanoid_2d_9_full', 'cheetah_6_front']}))"
    )
    env = {**os.environ, "PYTHONHASHSEED": "12345"}
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True
    )
    theirs = json.loads(out.stdout.strip().splitlines()[-1])
    for name, counts in theirs.items():
        assert counts == smpenv_robot(name).graph.wl.tolist(), name


def test_wl_tells_different_shapes_apart():
    t = np.zeros(4, dtype=np.int64)
    chain = wl_counts(t, adjacency(np.array([-1, 0, 1, 2])))
    star = wl_counts(t, adjacency(np.array([-1, 0, 0, 0])))
    assert not np.array_equal(chain, star)
    # and different types on the same shape
    assert not np.array_equal(
        chain, wl_counts(np.array([0, 1, 1, 1]), adjacency(np.array([-1, 0, 1, 2])))
    )


# ------------------------------------------------------------------------ property tests (trees)


@st.composite
def trees(draw, max_limbs: int = 14):
    """(parents in depth-first pre-order, types): limb i's parent lies on the path to limb i-1."""
    k = draw(st.integers(1, max_limbs))
    parents = [-1]
    path = [0]  # root .. previous limb
    for i in range(1, k):
        depth = draw(st.integers(0, len(path) - 1))
        path = path[: depth + 1]
        parents.append(path[-1])
        path.append(i)
    types = draw(st.lists(st.integers(0, 6), min_size=k, max_size=k))
    return np.array(parents, dtype=np.int64), np.array(types, dtype=np.int64)


def depth_of(parents: np.ndarray) -> np.ndarray:
    d = np.zeros(len(parents), dtype=np.int64)
    for i in range(1, len(parents)):
        d[i] = d[parents[i]] + 1
    return d


def ancestors(parents: np.ndarray, i: int) -> list[int]:
    out = [i]
    while parents[out[-1]] >= 0:
        out.append(int(parents[out[-1]]))
    return out


@settings(max_examples=60, deadline=None)
@given(trees(), st.randoms(use_true_random=False))
def test_wl_counts_do_not_depend_on_limb_numbering(tree, rnd):
    parents, types = tree
    check_tree(parents)
    adj = adjacency(parents)
    perm = np.arange(len(parents))
    rnd.shuffle(perm)
    assert np.array_equal(wl_counts(types[perm], adj[perm][:, perm]), wl_counts(types, adj))
    # a renumbering that keeps a depth-first pre-order (children visited in another order),
    # through the whole RobotGraph pipeline
    kids = [[c for c in range(len(parents)) if parents[c] == p] for p in range(len(parents))]
    for c in kids:
        rnd.shuffle(c)
    order, stack = [], [0]
    while stack:
        n = stack.pop()
        order.append(n)
        stack.extend(reversed(kids[n]))
    new = np.empty_like(perm)
    new[order] = np.arange(len(order))
    new_parents = np.array([-1] + [new[parents[o]] for o in order[1:]])
    check_tree(new_parents)
    graph = RobotGraph.from_tree(new_parents, types[order])
    assert np.array_equal(graph.wl, wl_counts(types, adj))
    assert sorted(graph.dist.ravel().tolist()) == sorted(hop_distances(adj).ravel().tolist())


@settings(max_examples=60, deadline=None)
@given(trees())
def test_hop_distances_form_a_tree_metric(tree):
    parents, _ = tree
    adj = adjacency(parents)
    d = hop_distances(adj)
    k = len(parents)
    assert (d >= 0).all()  # connected
    assert np.array_equal(d, d.T)
    assert (np.diag(d) == 0).all()
    assert np.array_equal(d == 1, adj)  # exactly 1 on edges, and only there
    # triangle inequality: d[i, j] <= d[i, m] + d[m, j] for all i, j, m
    assert (d[:, None, :] <= d[:, :, None] + d[None, :, :]).all()
    # the tree metric: depth(i) + depth(j) - 2 depth(lowest common ancestor)
    depth = depth_of(parents)
    for i in range(k):
        anc_i = ancestors(parents, i)
        for j in range(k):
            lca = next(a for a in ancestors(parents, j) if a in anc_i)
            assert d[i, j] == depth[i] + depth[j] - 2 * depth[lca]


@settings(max_examples=40, deadline=None)
@given(trees())
def test_ppr_rows_and_laplacian_spectrum_on_random_trees(tree):
    parents, _ = tree
    adj = adjacency(parents)
    ppr = personalized_pagerank(adj)
    np.testing.assert_allclose(ppr.sum(1), 1.0, rtol=1e-5)
    ev = np.linalg.eigvalsh(normalized_laplacian(adj).astype(np.float64))
    assert ev.min() > -1e-5 and ev.max() < 2 + 1e-5
    t = traversal_indices(parents)
    for c in range(3):  # each column is a permutation of 0..K-1
        assert sorted(t[:, c].tolist()) == list(range(len(parents)))
