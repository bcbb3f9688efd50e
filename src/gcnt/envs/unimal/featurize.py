"""UNIMAL's featuriser: the 52-d limb observation, the 35-number limb context and the height map.

Per limb (bodies in depth-first pre-order, torso first; padding rows all zeros):

======= ==================================================================================
0:3     body position in world, x minus the torso's x (y and z as they are)
3:6     linear velocity of the body-frame origin, world axes
6:9     angular velocity, world axes
9:13    body orientation quaternion (w, x, y, z), world
13:16   body position in its parent (model constant)
16:19   inertial frame position in the body
19:23   inertial frame quaternion
23:27   quaternion of the body's (first) geom
27      body mass
28:30   geom size: capsule radius and half-length (torso sphere: 0.1, 0)
30:41   joint slot 0 (the limb's hinge about its x axis), 11 numbers:
          angle scaled to [0, 1] over its range, angular velocity, joint position in the body
          frame (3), range in radians (2), axis in the body frame (3), motor gear
41:52   joint slot 1 (the hinge about the limb's y axis), the same 11 numbers
======= ==================================================================================

A missing joint and the torso's two slots are zeros. Velocities come from MuJoCo's ``cvel``
(velocity about the kinematic subtree's centre of mass ``c``, world axes): the body-frame
origin ``p`` moves at ``v(c) + ω × (p − c)``, which is what ``mj_objectVelocity(mjOBJ_XBODY,
flg_local=0)`` returns.

The static context (35 numbers per limb: 13:30 and, per slot, joint position, range, axis and
gear) is scaled to [−1, 1] with ModuMorph's fixed bounds, ``c = −1 + 2 (x − lo) / (hi − lo +
1e-8)`` (without the −1 where lo = hi, as ModuMorph: the quaternions' z components, bounds both
0, are 0 there), then clipped to [−1, 1] (a robot outside the bounds, or such a component away
from 0, would otherwise give huge values); missing joint slots stay 0.

``gather`` copies whole slices of a sub-env's MjData (a few array copies, no loop over limbs);
``compute`` works on all sub-envs at once.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence

import mujoco
import numpy as np

from gcnt import keys as K
from gcnt.envs.kinematics import origin_velocity, torso_relative_position
from gcnt.envs.plugins import Featurizer
from gcnt.envs.unimal import hfield as H
from gcnt.morphology import Robot

OBS_DIM = 52
CONTEXT_DIM = 35
ACTION_SLOTS = 2
#: batches of at least this many height maps are split over two threads when the env has them
_PARALLEL_HEIGHT_MAPS = 16
SLOT0, SLOT_WIDTH = 30, 11
#: columns of the observation that make up the context
CONTEXT_COLUMNS = np.r_[13:30, 32:41, 43:52]

_HALF_PI = np.pi / 2
_Q_LO, _Q_HI = [0.707, -0.707, -0.707, 0.0], [1.0, 0.707, 0.707, 0.0]
_SLOT_LO = [-0.05, -0.05, 0.0, -_HALF_PI, 0.0, -0.5, -0.5, -1.0, 0.0]
_SLOT_HI = [0.05, 0.05, 0.05, 0.0, _HALF_PI, 1.0, 1.0, 1.0, 300.0]
#: ModuMorph's fixed context bounds, in the order of CONTEXT_COLUMNS
CONTEXT_LO = np.array(
    [-0.5, -0.45, -0.49, -0.225, -0.225, -0.225, *_Q_LO, *_Q_LO, 1.178, 0.05, 0.0, *_SLOT_LO,
     *_SLOT_LO]
)  # fmt: skip
CONTEXT_HI = np.array(
    [0.5, 0.45, 2.04, 0.225, 0.225, 0.0, *_Q_HI, *_Q_HI, 4.189, 0.1, 0.226, *_SLOT_HI, *_SLOT_HI]
)
assert CONTEXT_LO.shape == CONTEXT_HI.shape == (CONTEXT_DIM,)
#: the −1 offset applies where the bounds differ (ModuMorph's ``get_context``: ``-1 * (lo != hi)``):
#: a component whose bounds are equal (the quaternions' z) is 0 at its bound
_SPANNED = (CONTEXT_LO != CONTEXT_HI).astype(np.float64)


def static_features(robot: Robot, model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    """The constant columns of a robot's observation and where its joints live.

    Returns ``(obs [m, 52] float64 with 13:30 and the slots' static parts filled, joints
    [m, 2] int64 joint id per slot or -1)``.
    """
    m = robot.num_limbs
    out = np.zeros((m, OBS_DIM))
    joints = np.full((m, ACTION_SLOTS), -1, np.int64)
    motor_gear = model.actuator_gear[:, 0]
    for i, b in enumerate(robot.mj_body_ids):
        b = int(b)
        if int(model.body_geomnum[b]) == 0:
            raise ValueError(f"robot {robot.name!r}: body {robot.body_names[i]!r} has no geom")
        g = int(model.body_geomadr[b])
        out[i, 13:16] = model.body_pos[b]
        out[i, 16:19] = model.body_ipos[b]
        out[i, 19:23] = model.body_iquat[b]
        out[i, 23:27] = model.geom_quat[g]
        out[i, 27] = model.body_mass[b]
        out[i, 28:30] = model.geom_size[g, :2]
        for jid, act, slot in zip(
            robot.mj_joint_ids[i], robot.actuator_ids[i], robot.action_slots(i), strict=True
        ):
            base = SLOT0 + SLOT_WIDTH * slot
            out[i, base + 2 : base + 5] = model.jnt_pos[jid]
            out[i, base + 5 : base + 7] = model.jnt_range[jid]
            out[i, base + 7 : base + 10] = model.jnt_axis[jid]
            out[i, base + 10] = motor_gear[act]
            joints[i, slot] = jid
    return out, joints


def scale_context(features: np.ndarray, has_slot: np.ndarray) -> np.ndarray:
    """ModuMorph's scaling of the 35 context numbers ``features`` [..., 35] (see the module
    doc); ``has_slot`` [..., 2] marks existing joint slots (the others stay 0)."""
    c = -_SPANNED + 2.0 * (features - CONTEXT_LO) / (CONTEXT_HI - CONTEXT_LO + 1e-8)
    np.clip(c, -1.0, 1.0, out=c)
    c[..., 17:26] *= has_slot[..., 0:1]
    c[..., 26:35] *= has_slot[..., 1:2]
    return c


#: ``terrain_of(model)``: the per-episode terrain of a sub-env's model (has the height map's
#: lookup table ``grid`` and its ``origin``, see ``hfield.height_map``), for worlds with a
#: height map
TerrainLookup = Callable[[mujoco.MjModel], object]


class UnimalFeaturizer(Featurizer):
    """UNIMAL's :class:`~gcnt.envs.base.Featurizer`: the 52-d observation of a fixed list of
    sub-envs padded to K limbs, the 35-number limb context, and (``terrain_of`` given) the
    1410-value height map ``hfield``."""

    obs_dim = OBS_DIM
    context_dim = CONTEXT_DIM

    def __init__(
        self,
        robots: Sequence[Robot],
        models: Sequence[mujoco.MjModel],
        k: int,
        terrain_of: TerrainLookup | None = None,
    ):
        n = len(robots)
        self.k = k
        self.template = np.zeros((n, k, OBS_DIM))
        self.mask = np.zeros((n, k), bool)
        self.qadr = np.zeros((n, k * ACTION_SLOTS), np.int64)
        self.dadr = np.zeros((n, k * ACTION_SLOTS), np.int64)
        self.has = np.zeros((n, k, ACTION_SLOTS))
        self.lo = np.zeros((n, k, ACTION_SLOTS))
        self.span = np.ones((n, k, ACTION_SLOTS))
        nq = max(int(m.nq) for m in models)
        nv = max(int(m.nv) for m in models)
        self._plan: list[tuple[int, int, int]] = []  # first body, limb count, root body
        for j, (r, model) in enumerate(zip(robots, models, strict=True)):
            m = r.num_limbs
            tpl, joints = static_features(r, model)
            self.template[j, :m] = tpl
            self.mask[j, :m] = True
            has = joints >= 0
            jid = np.where(has, joints, 0)
            self.has[j, :m] = has
            self.qadr[j, : m * ACTION_SLOTS] = model.jnt_qposadr[jid].reshape(-1)
            self.dadr[j, : m * ACTION_SLOTS] = model.jnt_dofadr[jid].reshape(-1)
            rng = model.jnt_range[jid]  # [m, 2, 2]
            span = rng[..., 1] - rng[..., 0]
            if (span[has] <= 0).any():
                raise ValueError(
                    f"robot {r.name!r} ({r.source}): a limb hinge has an empty range; UNIMAL "
                    "joints must be limited"
                )
            self.lo[j, :m] = np.where(has, rng[..., 0], 0.0)
            self.span[j, :m] = np.where(has, span, 1.0)
            ids = np.asarray(r.mj_body_ids)
            if not np.array_equal(ids, np.arange(ids[0], ids[0] + m)):
                raise ValueError(
                    f"robot {r.name!r} ({r.source}): its bodies are not numbered in depth-first "
                    "pre-order"
                )
            self._plan.append((int(ids[0]), m, int(model.body_rootid[ids[0]])))
        self.xpos = np.zeros((n, k, 3))
        self.xquat = np.zeros((n, k, 4))
        self.xquat[:, 0, 0] = 1.0
        self.cvel = np.zeros((n, k, 6))
        self.com = np.zeros((n, 3))
        self.qpos = np.zeros((n, nq))
        self.qvel = np.zeros((n, nv))
        self._maskf = self.mask.astype(np.float64)
        # height map
        self._terrains = None
        if terrain_of is not None:
            self._terrains = [terrain_of(mdl) for mdl in models]
            self._origin = self._terrains[0].origin
            self._tables = H.stack_terrains(self._terrains)
            self._hwork = H.Workspace.empty(n)
            self._hmap = np.empty((n, H.HFIELD_DIM), np.float32)
        self._out64 = np.empty((n, k, OBS_DIM))
        self._out32 = np.empty((n, k, OBS_DIM), np.float32)
        #: seconds spent computing height maps (for ``gcnt bench-env``)
        self.hfield_seconds = 0.0

    @property
    def root_outputs(self) -> Mapping[str, int]:
        return {K.HFIELD: H.HFIELD_DIM} if self._terrains is not None else {}

    def limb_context(self, robot: Robot, model: mujoco.MjModel) -> np.ndarray:
        tpl, joints = static_features(robot, model)
        return scale_context(tpl[:, CONTEXT_COLUMNS], joints >= 0).astype(np.float32)

    def bind(self, j: int, data: mujoco.MjData) -> list[tuple[np.ndarray, np.ndarray]]:
        first, m, root = self._plan[j]
        bodies = slice(first, first + m)
        return [
            (self.xpos[j, :m], data.xpos[bodies]),
            (self.xquat[j, :m], data.xquat[bodies]),
            (self.cvel[j, :m], data.cvel[bodies]),
            (self.com[j], data.subtree_com[root]),
            (self.qpos[j, : data.qpos.shape[0]], data.qpos),
            (self.qvel[j, : data.qvel.shape[0]], data.qvel),
        ]

    def gather(self, j: int, data: mujoco.MjData) -> None:
        for dst, src in self.bind(j, data):
            dst[...] = src

    def compute(self, rows: np.ndarray | None = None) -> np.ndarray:
        if rows is not None:
            return self.features(rows).astype(np.float32)
        # the whole batch: into kept buffers (see hfield.Workspace on fresh big arrays)
        np.copyto(self._out32, self.features(out=self._out64))
        return self._out32

    def features(self, rows: np.ndarray | None = None, out: np.ndarray | None = None) -> np.ndarray:
        """The observations of :meth:`compute` in float64 [n, K, 52] (into ``out`` if given)."""
        if rows is None:
            xpos, xquat, cvel, com, qpos, qvel = (
                self.xpos, self.xquat, self.cvel, self.com, self.qpos, self.qvel
            )  # fmt: skip
            tpl, maskf, qadr, dadr, has, lo, span = (
                self.template, self._maskf, self.qadr, self.dadr, self.has, self.lo, self.span
            )  # fmt: skip
        else:
            xpos, xquat, cvel, com, qpos, qvel = (
                self.xpos[rows], self.xquat[rows], self.cvel[rows], self.com[rows],
                self.qpos[rows], self.qvel[rows],
            )  # fmt: skip
            tpl, maskf, qadr, dadr, has, lo, span = (
                self.template[rows], self._maskf[rows], self.qadr[rows], self.dadr[rows],
                self.has[rows], self.lo[rows], self.span[rows],
            )  # fmt: skip
        n, k = xpos.shape[:2]
        if out is None:
            out = tpl.copy()
        else:
            np.copyto(out, tpl)
        # 0:3 position, x relative to the torso
        torso_relative_position(xpos, maskf, out[..., 0:3])
        # 3:6 velocity of the body-frame origin: v(c) + ω × (p − c)
        v = out[..., 3:6]
        origin_velocity(xpos, com, cvel, v)
        v *= maskf[..., None]
        w = cvel[..., :3]
        # 6:9 angular velocity, 9:13 orientation
        out[..., 6:9] = w
        out[..., 9:13] = xquat
        out[..., 9] *= maskf
        # joint slots: angle scaled over the range, angular velocity
        q = np.take_along_axis(qpos, qadr, axis=1).reshape(n, k, ACTION_SLOTS)
        dq = np.take_along_axis(qvel, dadr, axis=1).reshape(n, k, ACTION_SLOTS)
        q -= lo
        q /= span
        q *= has
        dq *= has
        out[..., SLOT0::SLOT_WIDTH] = q
        out[..., SLOT0 + 1 :: SLOT_WIDTH] = dq
        return out

    def compute_root(self, rows: np.ndarray | None = None) -> dict[str, np.ndarray]:
        if self._terrains is None:
            return {}
        t = time.perf_counter()
        if rows is None:
            xy, quat = self.xpos[:, 0, :2], self.xquat[:, 0]
            rows, out = np.arange(len(xy)), self._hmap
        else:
            xy, quat = self.xpos[rows, 0, :2], self.xquat[rows, 0]
            out = np.empty((len(rows), H.HFIELD_DIM), np.float32)
        heading = H.heading_from_quat(quat)

        def part(lo: int, hi: int, work: H.Workspace) -> None:
            H.height_map(
                xy[lo:hi], heading[lo:hi], self._tables, self._origin, rows[lo:hi], work, out[lo:hi]
            )

        n, mid, work = len(rows), len(rows) // 2, self._hwork
        if self.pool is not None and n >= _PARALLEL_HEIGHT_MAPS:
            # the first half on a helper thread, the second here (each in its own rows of the
            # workspace): measured on 2 cores, the 100-robot MT and Obstacles envs step 6-9%
            # faster than with one thread
            first = self.pool.submit(part, 0, mid, work.rows(0, mid))
            part(mid, n, work.rows(mid, n))
            if first.cancel():  # the helper had not started it (a busy machine)
                part(0, mid, work.rows(0, mid))
            else:
                first.result()
        else:
            part(0, n, work)
        self.hfield_seconds += time.perf_counter() - t
        return {K.HFIELD: out}
