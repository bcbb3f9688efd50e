"""UNIMAL env: observation, context, height map, terrain, terminations, resets, determinism, specs.

Few robots and few steps each. Expected values are computed independently from MjData (float64),
from the UNIMAL facts (offsets, bounds, ratios written out here), or by ray casting.
"""

from __future__ import annotations

import copy
import math
import xml.etree.ElementTree as ET

import mujoco
import numpy as np
import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import check_env_specs

from gcnt.envs.benchmark import get_benchmark
from gcnt.envs.unimal import UNIMAL_BENCHMARK, UnimalEnv
from gcnt.envs.unimal import terrain as T
from gcnt.envs.unimal import worlds as W
from gcnt.morphology.catalogues import resolve_robots

WORLDS = ("ft", "incline", "mt", "obstacles")
FALL_RATIO = {"ft": 0.5, "incline": 0.2, "mt": 0.3, "obstacles": 0.5}
TAN10 = math.tan(math.radians(10))

# The height map's offsets, in cells of 0.1 m (from the UNIMAL facts).
_NEAR = [*range(14), 15, 16, 17, 18, 20, 22, 24, 28, 32, 40]
FWD = [-10, -6, -5, -3, -2, -1, *_NEAR]
LAT = [*reversed(_NEAR), *(-c for c in _NEAR[1:])]


@pytest.fixture(scope="module")
def robots():
    # unimal_0000: 11 bodies, limbs with one hinge (x or y) and with two hinges
    return resolve_robots(["unimal_0000", "unimal_0001", "unimal_0002"])


def _random_steps(env, steps, seed=0):
    gen = torch.Generator().manual_seed(seed)
    td = env.reset()
    shape = env.action_spec["limbs", "action"].shape
    for _ in range(steps):
        td.set(("limbs", "action"), torch.rand(shape, generator=gen) * 2 - 1)
        _, td = env.step_and_maybe_reset(td)
    return td


def _z0(robot) -> float:
    root = ET.fromstring(robot.xml)
    torso = next(b for b in root.iter("body") if b.get("name") == "torso/0")
    return float(torso.get("pos").split()[2])


# --------------------------------------------------------------------------- registry, specs


def test_benchmark_record():
    b = get_benchmark("unimal")
    assert b is UNIMAL_BENCHMARK
    assert (b.limb_obs_dim, b.action_slots, b.hfield_dim) == (52, 2, 1410)
    assert b.worlds == WORLDS and b.default_world == "ft"
    assert b.hfield_worlds == ("mt", "obstacles") and b.train_split == "Unimal:train"
    with pytest.raises(ValueError, match="did you mean"):
        b.check_world("mtt")


@pytest.mark.parametrize("world", WORLDS)
def test_check_env_specs(robots, world):
    env = UNIMAL_BENCHMARK.make_env(robots[:2], seed=1, num_threads=1, world=world, max_limbs=12)
    check_env_specs(env, seed=1)
    td = env.reset()
    assert td["limbs", "obs"].shape == (2, 12, 52)
    assert td["limbs", "context"].shape == (2, 12, 35)
    assert td["limbs", "action_mask"].shape == (2, 12, 2)
    assert ("hfield" in td.keys()) == (world in ("mt", "obstacles"))
    if world in ("mt", "obstacles"):
        assert td["hfield"].shape == (2, 1410)
    env.close()


def test_rejects_smpenv_robots():
    with pytest.raises(ValueError, match="UNIMAL robots only"):
        UnimalEnv(resolve_robots(["walker_2_main"]))


# --------------------------------------------------------------------------- observation


def _expected_obs(model, data, robot, k):
    """The 52-d observation from MjData, one body at a time (float64)."""
    data2 = mujoco.MjData(model)
    data2.qpos[:], data2.qvel[:] = data.qpos, data.qvel
    mujoco.mj_forward(model, data2)
    out = np.zeros((k, 52))
    torso = model.body("torso/0").id
    for i, name in enumerate(robot.body_names):
        b = model.body(name).id
        out[i, 0:3] = data2.xpos[b] - [data2.xpos[torso][0], 0, 0]
        vel = np.zeros(6)
        mujoco.mj_objectVelocity(model, data2, mujoco.mjtObj.mjOBJ_XBODY, b, vel, 0)
        out[i, 3:6], out[i, 6:9] = vel[3:], vel[:3]
        out[i, 9:13] = data2.xquat[b]
        g = model.body_geomadr[b]
        out[i, 13:16] = model.body_pos[b]
        out[i, 16:19] = model.body_ipos[b]
        out[i, 19:23] = model.body_iquat[b]
        out[i, 23:27] = model.geom_quat[g]
        out[i, 27] = model.body_mass[b]
        out[i, 28:30] = model.geom_size[g, :2]
        if i == 0:
            continue
        idx = name.split("/")[1]
        for slot, axis in enumerate("xy"):
            jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"limb{axis}/{idx}")
            if jid < 0:
                continue
            base = 30 + 11 * slot
            lo, hi = model.jnt_range[jid]
            q = data2.qpos[model.jnt_qposadr[jid]]
            out[i, base] = (q - lo) / (hi - lo)
            out[i, base + 1] = data2.qvel[model.jnt_dofadr[jid]]
            out[i, base + 2 : base + 5] = model.jnt_pos[jid]
            out[i, base + 5 : base + 7] = (lo, hi)
            out[i, base + 7 : base + 10] = model.jnt_axis[jid]
            act = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, f"limb{axis}/{idx}")
            out[i, base + 10] = model.actuator_gear[act, 0]
    return out


@pytest.mark.parametrize("world", ["ft", "mt"])
def test_observation_matches_mjdata(robots, world):
    env = UnimalEnv(robots[:2], max_limbs=12, world=world, seed=3, num_threads=1)
    td = _random_steps(env, 6)
    feats = env._featurizer.features()  # float64
    for i, r in enumerate(env.robots):
        model, data = env.sim(i)
        exp = _expected_obs(model, data, r, 12)
        np.testing.assert_allclose(feats[i], exp, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(td["limbs", "obs"][i].numpy(), exp, rtol=1e-5, atol=1e-5)
    # the cases the table names: a 1-hinge limb, a 2-hinge limb, the torso, a padded slot
    r0 = env.robots[0]
    n_joints = [len(j) for j in r0.joint_names]
    assert 1 in n_joints[1:] and 2 in n_joints[1:]
    one = n_joints.index(1, 1)
    missing = 1 - r0.action_slots(one)[0]
    assert not feats[0, one, 30 + 11 * missing : 41 + 11 * missing].any()
    assert not feats[0, 0, 30:].any()  # the torso's joint slots
    assert not feats[0, r0.num_limbs :].any()  # padding
    assert feats[0, 0, 0] == 0.0  # the torso's x relative to itself
    env.close()


def test_metamorph_layout_file(robots):
    """A hand-written file in MetaMorph's layout (y hinge listed before x) in a terrain world."""
    from pathlib import Path

    from gcnt.morphology import load_robot

    fixture = Path(__file__).parent / "data" / "unimal" / "unimal_fixture.xml"
    robot = load_robot(fixture)
    env = UnimalEnv([robot, robots[1]], max_limbs=12, world="obstacles", seed=2, num_threads=1)
    _random_steps(env, 3)
    model, data = env.sim(0)
    np.testing.assert_allclose(
        env._featurizer.features()[0], _expected_obs(model, data, robot, 12), rtol=1e-9, atol=1e-9
    )
    env.close()


def test_a_metamorph_file_is_assembled_as_metamorph_assembles_it(robots):
    """MetaMorph's files say ``filterparent="disable"`` and list exclusions; MetaMorph keeps only
    their torso body, motors and sensors and enables the parent filter. gcnt's generated files
    enable it themselves and keep their mirrored-pair exclusions."""
    from pathlib import Path

    from gcnt.envs.unimal.worlds import world_model
    from gcnt.morphology import robot_from_xml

    text = (Path(__file__).parent / "data" / "unimal" / "unimal_fixture.xml").read_text()
    stray = '<geom name="stray" type="sphere" size="0.1" pos="5 5 1"/></worldbody>'
    robot = robot_from_xml(text.replace("</worldbody>", stray), name="fixture")
    model = world_model(robot, "ft")
    assert not model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_FILTERPARENT
    assert model.nexclude == 0
    assert mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "stray") == -1
    assert model.nu == robot.num_motors and model.nsensor == 4  # the file's sensors
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    parent = model.body_parentid
    for c in data.contact[: data.ncon]:  # no parent-child contact survives
        b1, b2 = model.geom_bodyid[c.geom1], model.geom_bodyid[c.geom2]
        assert parent[b1] != b2 and parent[b2] != b1
    generated = robots[0]
    kept = world_model(generated, "ft")
    assert kept.nexclude == generated.xml.count("<exclude")
    assert not kept.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_FILTERPARENT


def test_action_slots_drive_their_hinges(robots):
    env = UnimalEnv(robots[:1], world="ft", seed=0, num_threads=1)
    env.reset()
    r = env.robots[0]
    a = torch.zeros(env.action_spec["limbs", "action"].shape)
    two = next(i for i, j in enumerate(r.joint_names) if len(j) == 2)
    a[0, two, 0], a[0, two, 1] = 0.25, -0.75
    a[0, 0] = float("nan")  # torso: no motor, ignored
    env.step(TensorDict({("limbs", "action"): a}, batch_size=[1]))
    model, data = env.sim(0)
    idx = r.body_names[two].split("/")[1]
    assert data.ctrl[model.actuator(f"limbx/{idx}").id] == 0.25
    assert data.ctrl[model.actuator(f"limby/{idx}").id] == -0.75
    mask = env.table["limbs", "action_mask"][0]
    assert not mask[0].any() and mask[two].all()
    env.close()


# --------------------------------------------------------------------------- context

LO = np.array(
    [-0.5, -0.45, -0.49, -0.225, -0.225, -0.225, 0.707, -0.707, -0.707, 0, 0.707, -0.707, -0.707, 0]
    + [1.178, 0.05, 0]
    + 2 * [-0.05, -0.05, 0, -math.pi / 2, 0, -0.5, -0.5, -1, 0]
)
HI = np.array(
    [0.5, 0.45, 2.04, 0.225, 0.225, 0, 1, 0.707, 0.707, 0, 1, 0.707, 0.707, 0]
    + [4.189, 0.1, 0.226]
    + 2 * [0.05, 0.05, 0.05, 0, math.pi / 2, 1, 1, 1, 300]
)


def test_context_scaling(robots):
    env = UnimalEnv(robots[:2], max_limbs=12, world="ft", seed=0, num_threads=1)
    ctx = env.table["limbs", "context"].numpy()
    assert ctx.shape == (2, 12, 35)
    for i, r in enumerate(env.distinct_robots):
        model = env.sim(i)[0]
        obs = _expected_obs(model, mujoco.MjData(model), r, 12)
        raw = obs[:, np.r_[13:30, 32:41, 43:52]]
        # ModuMorph's get_context: the -1 only where the bounds differ
        exp = np.clip(-1.0 * (LO != HI) + 2 * (raw - LO) / (HI - LO + 1e-8), -1, 1)
        for slot in range(2):  # empty slots (no joint, torso, padding) stay 0
            empty = ~obs[:, 40 + 11 * slot].astype(bool)  # gear 0 <=> no joint
            exp[empty, 17 + 9 * slot : 26 + 9 * slot] = 0
        exp[r.num_limbs :] = 0
        np.testing.assert_allclose(ctx[i], exp, atol=1e-6)
    assert np.abs(ctx).max() <= 1.0
    real = env.table["limbs", "mask"].numpy()
    assert (ctx[:, :, [9, 13]][real] == 0).all()  # body_iquat[3], geom_quat[3]: bounds 0, 0
    # the env emits the table's context
    td = env.reset()
    assert torch.equal(td["limbs", "context"], env.table["limbs", "context"][env.local_ids])
    env.close()


# --------------------------------------------------------------------------- height map


def _ray_heights(model, data, points):
    """Terrain height under each (x, y) by a vertical ray that sees only the world's geoms
    (the robot's geoms moved to another group); None where nothing is hit."""
    m = copy.copy(model)
    robot_geoms = m.geom_bodyid > 0
    m.geom_group[robot_geoms] = 5
    d = mujoco.MjData(m)
    d.qpos[:] = data.qpos
    mujoco.mj_forward(m, d)
    groups = np.array([1, 0, 0, 0, 0, 0], np.uint8)
    out = []
    gid = np.zeros(1, np.int32)
    for x, y in points:
        dist = mujoco.mj_ray(
            m, d, np.array([x, y, 20.0]), np.array([0, 0, -1.0]), groups, 1, -1, gid
        )
        out.append(None if dist < 0 else 20.0 - dist)
    return out


def _place(env, i, x, y, yaw_deg, z=None):
    model, data = env.sim(i)
    qpos = data.qpos.copy()
    qpos[0:2] = x, y
    if z is not None:
        qpos[2] = z
    qpos[3:7] = [math.cos(math.radians(yaw_deg) / 2), 0, 0, math.sin(math.radians(yaw_deg) / 2)]
    env.set_state(i, qpos=qpos)
    return model, data


@pytest.mark.parametrize(
    ("world", "x", "y", "yaw"),
    [("mt", 30.02, -3.07, 30.0), ("mt", -1.0, 17.5, 200.0), ("obstacles", 40.3, 2.2, -65.0),
     ("obstacles", 95.0, -18.0, 10.0)],
)  # fmt: skip
def test_height_map_against_rays(robots, world, x, y, yaw):
    env = UnimalEnv(robots[:1], world=world, seed=5, num_threads=1)
    env.reset()
    if world == "obstacles":  # put a box under part of the map
        field = env.task_rules(0).terrain
        boxes = field.boxes.copy()
        # 2 m to the robot's left
        boxes[0, :2] = x - 2.0 * math.sin(math.radians(yaw)), y + 2.0 * math.cos(math.radians(yaw))
        field.place(boxes)
    model, data = _place(env, 0, x, y, yaw)
    hmap = env.observe()["hfield"][0].numpy().reshape(47, 30)
    c, s = math.cos(math.radians(yaw)), math.sin(math.radians(yaw))
    rows, cols = np.meshgrid(range(47), range(30), indexing="ij")
    pts, keep = [], []
    for r_, c_ in zip(rows.ravel()[::7], cols.ravel()[::7], strict=True):
        f, lat = FWD[c_] * 0.1, LAT[r_] * 0.1
        px, py = x + c * f - s * lat, y + s * f + c * lat
        pts.append((px, py))
        keep.append((r_, c_))
    # nearest grid vertex (MT: the height field's vertices; Obstacles: the same 0.1 m lattice)
    x0 = -3.0 if world == "mt" else -4.0
    y0 = -20.0 if world == "mt" else -21.0
    snap = [
        (x0 + round((px - x0) / 0.1) * 0.1, y0 + round((py - y0) / 0.1) * 0.1) for px, py in pts
    ]
    centre = (x0 + round((x - x0) / 0.1) * 0.1, y0 + round((y - y0) / 0.1) * 0.1)
    heights = _ray_heights(model, data, [centre, *snap])
    under = heights[0] if heights[0] is not None else -10.0

    def table_value(px, py, h):
        if world == "obstacles":
            if not (-4 <= px <= 98 and -21 <= py <= 21):
                return -10.0
            if px < -3 or px > 97 or abs(py) > 20:
                return 4.0  # walls read 4 in the map
        elif not (-3 <= px <= 107 and -20 <= py <= 20):
            return -10.0
        return h

    checked = 0
    for (r_, c_), (px, py), h in zip(keep, snap, heights[1:], strict=True):
        eps = 1e-6
        edge = (
            abs(px + 3) < eps or abs(px - 97) < eps or abs(abs(py) - 20) < eps
            or abs(px - 107) < eps
        )  # fmt: skip
        if edge:
            continue
        exp = table_value(px, py, h if h is not None else -10.0) - under
        assert hmap[r_, c_] == pytest.approx(exp, abs=1e-4), (r_, c_, px, py)
        checked += 1
    assert checked > 150
    if x < 0 or x > 90:  # the map reaches out of the world
        assert np.isclose(hmap, -10 - under, atol=1e-4).any()
    if world == "obstacles":
        assert np.isclose(hmap, 4.1 - under, atol=1e-4).any()  # the box
        if x > 90:
            assert np.isclose(hmap, 4.0 - under, atol=1e-4).any()  # the wall
    env.close()


def test_height_map_layout():
    from gcnt.envs.unimal import hfield as H

    assert list(H.FORWARD_CELLS) == FWD and list(H.LATERAL_CELLS) == LAT
    assert H.LATERAL_CELLS[0] == 40  # row 0 at +4 m
    pts = H.sample_points(np.zeros((1, 2)), np.array([[0.0, 1.0]]))[0]  # facing +y
    # forward +4 m along +y; row 0 (left, +4 m) lies at -x
    np.testing.assert_allclose(pts[29], [-4.0, 4.0], atol=1e-12)
    assert H.CENTRE == 23 * 30 + 6


# --------------------------------------------------------------------------- terrain


def test_mt_terrain_statistics():
    kinds = set()
    for seed in range(40):
        h = T.draw_mt(np.random.default_rng(seed))
        assert h.shape == (401, 1101)
        assert h.min() >= 0.0 and h.max() <= 1.2 + 1e-12
        assert not h[:, : 60 + 20 + 1].any()  # 6 m start and at least 2 m of flat
        assert not h[:, -1].any()  # the corridor ends at ground level
        cols = h.any(axis=0)
        top = h.max(axis=0)
        if np.isclose(top, 0.6).any() and np.isin(np.round(top, 6), [0.2, 0.4, 0.6]).any():
            kinds.add("stairs")
        rows_differ = (h != h[:1]).any(axis=0)
        if rows_differ.any():
            kinds.add("rugged")
            assert h[:, rows_differ].max() <= 0.3 + 1e-12
        if (top > 0.6 + 1e-9).any():
            kinds.add("bump")
        assert cols.sum() > 0
    assert kinds == {"stairs", "rugged", "bump"}


def test_obstacle_boxes_statistics():
    counts = []
    for seed in range(200):
        b = T.draw_boxes(np.random.default_rng(seed))
        counts.append(len(b))
        assert 0 < len(b) <= 50
        x, y, lx, ly = b.T
        assert ((lx >= 0.5) & (lx <= 1.0) & (ly >= 0.5) & (ly <= 1.0)).all()
        assert ((x >= 3 + lx) & (x < 91 - lx)).all()
        assert ((y - ly >= -20) & (y + ly <= 20)).all()
        dx = np.abs(x[:, None] - x[None]) < lx[:, None] + lx[None]
        dy = np.abs(y[:, None] - y[None]) < ly[:, None] + ly[None]
        overlap = dx & dy
        np.fill_diagonal(overlap, False)
        assert not overlap.any()
    assert max(counts) == 50


def test_terrain_is_edited_in_place_and_seeded(robots):
    a = UnimalEnv(robots[:2], world="mt", seed=7, num_threads=1)
    b = UnimalEnv(robots[:2], world="mt", seed=7, num_threads=1)
    c = UnimalEnv(robots[:2], world="mt", seed=8, num_threads=1)
    models = [a.sim(i)[0] for i in range(2)]
    a.reset(), b.reset(), c.reset()
    assert [a.sim(i)[0] for i in range(2)] == models  # same model objects: no recompiling
    ha = [a.sim(i)[0].hfield_data.copy() for i in range(2)]
    assert not np.array_equal(ha[0], ha[1])  # two sub-envs, two terrains
    assert ha[0].min() >= 0 and ha[0].max() <= 1
    assert all(np.array_equal(h, b.sim(i)[0].hfield_data) for i, h in enumerate(ha))
    assert not np.array_equal(ha[0], c.sim(0)[0].hfield_data)
    a.reset()
    assert not np.array_equal(ha[0], a.sim(0)[0].hfield_data)  # a new episode, a new terrain
    for env in (a, b, c):
        env.close()


def test_obstacle_geoms_follow_the_draw(robots):
    env = UnimalEnv(robots[:1], world="obstacles", seed=2, num_threads=1)
    env.reset()
    model = env.sim(0)[0]
    boxes = env.task_rules(0).terrain.boxes
    for i in range(50):
        g = model.geom(f"box/{i}").id
        if i < len(boxes):
            np.testing.assert_allclose(model.geom_pos[g], [*boxes[i, :2], 2.1])
            np.testing.assert_allclose(model.geom_size[g], [*boxes[i, 2:], 2.0])
            assert model.geom_contype[g] == 1
        else:
            assert model.geom_contype[g] == 0 and model.geom_conaffinity[g] == 0
    env.close()


def test_obstacle_table_after_many_redraws_equals_a_fresh_one(robots):
    """A redraw restores only the cells the previous boxes covered: after several episodes the
    lookup table is the one a new field would build for the same boxes."""
    env = UnimalEnv(robots[:1], world="obstacles", seed=3, num_threads=1)
    field = env.task_rules(0).terrain
    rng = np.random.default_rng(0)
    for _ in range(5):
        field.redraw(rng)
    boxes = field.boxes
    fresh = T.ObstacleField(env.sim(0)[0])
    fresh.place(boxes)
    np.testing.assert_array_equal(field.grid, fresh.grid)
    # and the table has the walls, the floor and one box top under every box centre
    x0, y0 = field.origin
    rows = np.floor((boxes[:, 1] - y0) / W.CELL + 0.5).astype(int)
    cols = np.floor((boxes[:, 0] - x0) / W.CELL + 0.5).astype(int)
    assert (field.grid[rows, cols] == field.top).all()
    assert (field.grid == field.top).sum() < field.grid.size // 4
    field.place(np.zeros((0, 4)))
    np.testing.assert_array_equal(field.grid, field._floor)
    env.close()


def test_sync_render_copies_the_edits(robots):
    env = UnimalEnv(robots[:1], world="mt", seed=2, num_threads=1)
    env.reset()
    model = env.sim(0)[0]
    copy_ = copy.copy(model)
    env.reset()
    assert not np.array_equal(copy_.hfield_data, model.hfield_data)
    env.sync_render(0, copy_, None)
    assert np.array_equal(copy_.hfield_data, model.hfield_data)
    env.close()


# --------------------------------------------------------------------------- rules


@pytest.mark.parametrize("world", WORLDS)
def test_fall_threshold_at_plus_minus_eps(robots, world):
    env = UnimalEnv(robots[:1], world=world, seed=0, num_threads=1)
    env.reset()
    robot = env.robots[0]
    thr = FALL_RATIO[world] * (_z0(robot) - 0.2)
    rules = env.task_rules(0)
    model, data = env.sim(0)
    x, y = 1.234, 0.5
    ground = 0.0
    if world == "incline":
        x = -50.0
        ground = x * TAN10
    elif world == "mt":  # stand over a raised part of this episode's terrain
        h = model.hfield_data.reshape(401, 1101).astype(np.float64) * 1.2
        r, c = np.argwhere(h[:200] > 0.3)[-1]  # a row near y = 0
        x, y = -3 + 0.1 * c, -20 + 0.1 * r
        ground = h[r, c]
    eps = 1e-6
    for dz, ends in ((eps, False), (-eps, True)):
        data.qpos[0:3] = x, y, ground + thr + dz
        rules.begin(data)
        assert rules.step(data, 0.0)[1] is ends, (world, dz)
    # sideways limit on the terrain worlds
    data.qpos[0:3] = x, 19.0 - 1e-6, ground + thr + 1.0
    assert rules.step(data, 0.0)[1] is False
    data.qpos[1] = -19.0
    assert rules.step(data, 0.0)[1] is (world in ("mt", "obstacles"))
    env.close()


@pytest.mark.parametrize("world", ["ft", "incline"])
def test_reward_is_forward_velocity(robots, world):
    env = UnimalEnv(robots[:2], world=world, seed=4, num_threads=1)
    td = env.reset()
    x_before = np.array([env.sim(i)[1].qpos[0] for i in range(2)])
    td.set(("limbs", "action"), env.action_spec.rand()["limbs", "action"])
    out = env.step(td)
    x_after = np.array([env.sim(i)[1].qpos[0] for i in range(2)])
    exp = (x_after - x_before) / 0.02
    if world == "incline":
        exp /= math.cos(math.radians(10))
    np.testing.assert_allclose(out["next", "reward"].numpy()[:, 0], exp, rtol=1e-5, atol=1e-5)
    env.close()


@pytest.mark.parametrize("world", WORLDS)
def test_start_above_the_ground_with_noise(robots, world):
    env = UnimalEnv(robots, world=world, seed=9, num_threads=1)
    env.reset()
    for i, r in enumerate(env.robots):
        model, data = env.sim(i)
        q0 = model.qpos0.copy()
        d = mujoco.MjData(model)
        d.qpos[:] = data.qpos
        mujoco.mj_forward(model, d)
        touching = [
            c
            for c in d.contact[: d.ncon]
            if 0 in (model.geom_bodyid[c.geom1], model.geom_bodyid[c.geom2])
        ]
        assert not touching, (world, r.name)
        if world == "incline":
            assert data.qpos[0] == pytest.approx(
                -72 - _z0(r) * math.sin(math.radians(10)), abs=0.01
            )
            z_above = data.qpos[2] - data.qpos[0] * TAN10
            assert z_above > 0.2 * (_z0(r) - 0.2)
        else:
            dq = data.qpos - q0
            assert np.abs(dq).max() <= 0.005 and np.abs(data.qvel).max() <= 0.005
            assert np.abs(dq).max() > 0  # noise was added
    env.close()


def test_truncation_at_the_time_limit(robots):
    env = UnimalEnv(robots[:1], world="ft", seed=0, num_threads=1, max_episode_steps=3)
    td = env.reset()
    for _ in range(3):
        td.set(("limbs", "action"), torch.zeros(1, env.max_limbs, 2))
        out, td = env.step_and_maybe_reset(td)
    assert out["next", "truncated"].item() and not out["next", "terminated"].item()
    env.close()


# --------------------------------------------------------------------------- batching


def test_padding_invariance(robots):
    outs = []
    for k in (None, 12):
        env = UnimalEnv(robots, max_limbs=k, world="obstacles", seed=11, num_threads=1)
        td = _random_steps(env, 5, seed=1) if k is None else None
        if k is not None:  # the same actions, padded with NaN on the extra slots
            gen = torch.Generator().manual_seed(1)
            td = env.reset()
            kk = outs[0][0].shape[1]
            for _ in range(5):
                a = torch.full(env.action_spec["limbs", "action"].shape, float("nan"))
                a[:, :kk] = torch.rand((len(robots), kk, 2), generator=gen) * 2 - 1
                td.set(("limbs", "action"), a)
                _, td = env.step_and_maybe_reset(td)
        outs.append((td["limbs", "obs"], td["hfield"]))
        env.close()
    (o1, h1), (o2, h2) = outs
    kk = o1.shape[1]
    assert torch.equal(o1, o2[:, :kk]) and not o2[:, kk:].any()
    assert torch.equal(h1, h2)


def test_partial_reset(robots):
    env = UnimalEnv(robots[:2], world="mt", seed=3, num_threads=1)
    td = _random_steps(env, 4)
    keep_q = env.sim(1)[1].qpos.copy()
    keep_h = env.sim(1)[0].hfield_data.copy()
    old_h0 = env.sim(0)[0].hfield_data.copy()
    obs1 = td["limbs", "obs"][1].clone()
    td["_reset"] = torch.tensor([[True], [False]])
    td = env.reset(td)
    assert np.array_equal(env.sim(1)[1].qpos, keep_q)
    assert np.array_equal(env.sim(1)[0].hfield_data, keep_h)
    assert torch.equal(td["limbs", "obs"][1], obs1)
    assert not np.array_equal(env.sim(0)[0].hfield_data, old_h0)
    assert abs(env.sim(0)[1].qpos[0]) <= 0.005
    env.close()


@pytest.mark.parametrize("world", ["incline", "obstacles"])
def test_determinism(robots, world):
    """Same seed, same worlds and outputs, on one thread or two (with 18 sub-envs, two threads
    also split the batch's height maps between them)."""
    from gcnt.envs.unimal.featurize import _PARALLEL_HEIGHT_MAPS

    subenvs = robots * 6
    assert len(subenvs) >= _PARALLEL_HEIGHT_MAPS
    runs = []
    for threads in (1, 2):
        env = UnimalEnv(subenvs, world=world, seed=21, num_threads=threads)
        gen = torch.Generator().manual_seed(0)
        td = env.reset()
        rewards = []
        for _ in range(8):
            td.set(("limbs", "action"), torch.rand(env.action_spec["limbs", "action"].shape,
                                                    generator=gen) * 2 - 1)  # fmt: skip
            out, td = env.step_and_maybe_reset(td)
            rewards.append(out["next", "reward"])
        runs.append((td, torch.stack(rewards)))
        env.close()
    (a, ra), (b, rb) = runs
    assert torch.equal(ra, rb)
    assert torch.equal(a["limbs", "obs"], b["limbs", "obs"])
    if world == "obstacles":
        assert torch.equal(a["hfield"], b["hfield"])


def test_a_robot_pool_on_mt_keeps_one_terrain_per_sub_env(robots):
    """Robots changing slots at resets (PPO's robot sampling) on a world with per-episode
    terrain: each new robot gets a private model with its own height field, the retired models'
    terrains are forgotten (no growth over many resets), and the height map still reads the
    current terrain of each sub-env."""
    env = UnimalEnv(robots[:2], world="mt", seed=4, num_threads=1, max_limbs=12)
    order = iter([[2, 0], [1, 2], [0, 1], [2, 2], [1, 0], [0, 2]] * 3)
    env.use_robot_pool(robots, lambda rows: np.array(next(order)[: len(rows)]))
    for _ in range(18):
        td = env.reset()
        assert len(env._terrains.by_model) == 2
        models = [env.sim(i)[0] for i in range(2)]
        assert models[0] is not models[1]
        assert {id(m) for m in models} == set(env._terrains.by_model)
    for i in range(2):  # the height map reads the sub-env's own terrain table
        assert env.task_rules(i).terrain.grid.base is env._featurizer._tables
    assert torch.isfinite(td["hfield"]).all()
    env.close()
