"""The featuriser of general 3-D robots: a 63-d limb token, a 44-number limb context and, on MT
and Obstacles, UNIMAL's 1410-value height map.

A limb is a body with hinges plus the bodies welded to it (``gcnt.morphology.robot``). Its state
is the state of its own body, seen in the torso's *heading frame* (origin below the torso, x the
torso's heading projected on the ground, z up), so that a robot walking in any direction sees the
same numbers. Per limb (limbs in depth-first pre-order, torso first; padding rows all zeros):

======= ==================================================================================
0:3     body position, x and y relative to the torso's, heading frame; z: height
3:6     linear velocity of the body-frame origin, heading frame
6:9     angular velocity, heading frame
9:13    body orientation quaternion (w, x, y, z) relative to the heading frame
13:16   position in the parent limb's body frame (torso: its start position), file pose
16:20   orientation quaternion in the parent limb's body frame, file pose
20:23   centre of mass of the limb (its body and welded bodies), limb frame
23      mass of the limb
24:27   centre of the box that bounds the limb's geoms, limb frame
27:30   half sizes of that box
30:41   hinge slot 0 (the limb's first hinge in the file), 11 numbers:
          angle (limited hinge: scaled to [0, 1] over its range; else radians), angular
          velocity, joint position in the body frame (3), range in radians (2; 0 0 if
          unlimited), axis in the body frame (3), torque per unit of action (|gear × gain|,
          the gain scaled by half the control range, see ``world.py``)
41:52   hinge slot 1, the same 11 numbers
52:63   hinge slot 2, the same 11 numbers
======= ==================================================================================

"File pose" is every joint at its ref (``qpos0``). Missing hinges and the torso's slots are zeros.
Velocities come from MuJoCo's ``cvel`` as in UNIMAL's featuriser
(``gcnt.envs.kinematics.origin_velocity``).

The static context (``limbs/context``, 44 numbers: 13:30 and, per slot, its 9 constant numbers)
is squashed into (−1, 1) with ``x / (1 + |x|)``: a general robot has no fixed bounds to scale by.
Missing slots stay 0.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import mujoco
import numpy as np

from gcnt import keys as K
from gcnt.envs.kinematics import origin_velocity
from gcnt.envs.plugins import Featurizer
from gcnt.envs.unimal import hfield as H
from gcnt.envs.unimal.featurize import TerrainLookup
from gcnt.morphology import Robot

OBS_DIM = 63
ACTION_SLOTS = 3
SLOT0, SLOT_WIDTH = 30, 11
#: columns of the observation that make up the context
CONTEXT_COLUMNS = np.concatenate(
    [np.arange(13, 30), *(np.arange(b + 2, b + 11) for b in range(SLOT0, OBS_DIM, SLOT_WIDTH))]
)
CONTEXT_DIM = len(CONTEXT_COLUMNS)
assert CONTEXT_DIM == 44


def limb_of_bodies(robot: Robot, model: mujoco.MjModel) -> np.ndarray:
    """The limb of every body of ``model`` ([nbody] int64; the world body and bodies outside the
    robot: -1). A body that is not a limb's own body is welded into its parent's limb."""
    out = np.full(model.nbody, -1, np.int64)
    own = {int(b): i for i, b in enumerate(robot.mj_body_ids)}
    for b in range(1, model.nbody):  # MuJoCo numbers parents before children
        out[b] = own.get(b, out[int(model.body_parentid[b])])
    return out


def _conj_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """conj(a) ⊗ b for quaternions (w, x, y, z), broadcast over leading axes."""
    aw, ax, ay, az = (a[..., i] for i in range(4))
    bw, bx, by, bz = (b[..., i] for i in range(4))
    return np.stack(
        [
            aw * bw + ax * bx + ay * by + az * bz,
            aw * bx - ax * bw - ay * bz + az * by,
            aw * by + ax * bz - ay * bw - az * bx,
            aw * bz - ax * by + ay * bx - az * bw,
        ],
        axis=-1,
    )


def static_features(robot: Robot, model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    """The constant columns of a robot's tokens and where its hinges live.

    Returns ``(obs [m, 63] float64 with 13:30 and the slots' constant parts filled, joints
    [m, 3] int64 joint id per slot or -1)``; ``model`` is the robot in its world (motor gains
    scaled, see ``world.py``).
    """
    m = robot.num_limbs
    out = np.zeros((m, OBS_DIM))
    joints = np.full((m, ACTION_SLOTS), -1, np.int64)
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    limb_of = limb_of_bodies(robot, model)
    xmat = data.xmat.reshape(-1, 3, 3)
    heads = np.asarray(robot.mj_body_ids, np.int64)
    torque = np.abs(model.actuator_gear[:, 0] * model.actuator_gainprm[:, 0])
    for i, b in enumerate(heads):
        b = int(b)
        rot, pos = xmat[b], data.xpos[b]
        p = int(heads[robot.parents[i]]) if i else 0
        out[i, 13:16] = xmat[p].T @ (pos - data.xpos[p])
        out[i, 16:20] = _conj_mul(data.xquat[p], data.xquat[b])
        bodies = np.nonzero(limb_of == i)[0]
        mass = model.body_mass[bodies]
        out[i, 23] = mass.sum()
        if out[i, 23] > 0:
            com = (mass[:, None] * data.xipos[bodies]).sum(0) / out[i, 23]
            out[i, 20:23] = rot.T @ (com - pos)
        geoms = np.nonzero(np.isin(model.geom_bodyid, bodies))[0]
        if len(geoms):
            # each geom's box in the limb frame: centre R^T (x_g + R_g c - x_b), half |R^T R_g| h
            to_limb = rot.T @ data.geom_xmat[geoms].reshape(-1, 3, 3)
            centre = (rot.T @ (data.geom_xpos[geoms] - pos).T).T
            centre += (to_limb @ model.geom_aabb[geoms, :3, None])[..., 0]
            half = (np.abs(to_limb) @ model.geom_aabb[geoms, 3:, None])[..., 0]
            lo, hi = (centre - half).min(0), (centre + half).max(0)
            out[i, 24:27] = (lo + hi) / 2.0
            out[i, 27:30] = (hi - lo) / 2.0
        for slot, (jid, act) in enumerate(
            zip(robot.mj_joint_ids[i], robot.actuator_ids[i], strict=True)
        ):
            base = SLOT0 + SLOT_WIDTH * slot
            out[i, base + 2 : base + 5] = model.jnt_pos[jid]
            if model.jnt_limited[jid]:
                out[i, base + 5 : base + 7] = model.jnt_range[jid]
            out[i, base + 7 : base + 10] = model.jnt_axis[jid]
            out[i, base + 10] = torque[act]
            joints[i, slot] = jid
    return out, joints


def squash_context(features: np.ndarray, has_slot: np.ndarray) -> np.ndarray:
    """The context of the 44 constant numbers ``features`` [..., 44]: ``x / (1 + |x|)``, missing
    slots (``has_slot`` [..., 3] False) 0."""
    c = features / (1.0 + np.abs(features))
    for s in range(ACTION_SLOTS):
        c[..., 17 + 9 * s : 26 + 9 * s] *= has_slot[..., s : s + 1]
    return c


class Mjcf3dFeaturizer(Featurizer):
    """The :class:`~gcnt.envs.plugins.Featurizer` of general 3-D robots (see the module doc);
    with ``terrain_of``, also UNIMAL's height map ``hfield``."""

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
        self.body = np.zeros((n, k), np.int64)
        slots = k * ACTION_SLOTS
        self.qadr = np.zeros((n, slots), np.int64)
        self.dadr = np.zeros((n, slots), np.int64)
        self.has = np.zeros((n, k, ACTION_SLOTS))
        self.lo = np.zeros((n, k, ACTION_SLOTS))
        self.span = np.ones((n, k, ACTION_SLOTS))
        self.root = np.zeros(n, np.int64)
        for j, (r, model) in enumerate(zip(robots, models, strict=True)):
            m = r.num_limbs
            tpl, joints = static_features(r, model)
            self.template[j, :m] = tpl
            self.mask[j, :m] = True
            self.body[j, :m] = r.mj_body_ids
            has = joints >= 0
            jid = np.where(has, joints, 0)
            self.has[j, :m] = has
            self.qadr[j, : m * ACTION_SLOTS] = model.jnt_qposadr[jid].reshape(-1)
            self.dadr[j, : m * ACTION_SLOTS] = model.jnt_dofadr[jid].reshape(-1)
            limited = has & model.jnt_limited[jid].astype(bool)
            rng = model.jnt_range[jid]  # [m, 3, 2]
            self.lo[j, :m] = np.where(limited, rng[..., 0], 0.0)
            self.span[j, :m] = np.where(limited, rng[..., 1] - rng[..., 0], 1.0)
            self.root[j] = int(model.body_rootid[int(r.mj_body_ids[0])])
        nb = max(int(mdl.nbody) for mdl in models)
        nq = max(int(mdl.nq) for mdl in models)
        nv = max(int(mdl.nv) for mdl in models)
        self.xpos = np.zeros((n, nb, 3))
        self.xquat = np.zeros((n, nb, 4))
        self.xquat[..., 0] = 1.0
        self.cvel = np.zeros((n, nb, 6))
        self.com = np.zeros((n, 3))
        self.qpos = np.zeros((n, nq))
        self.qvel = np.zeros((n, nv))
        self._maskf = self.mask.astype(np.float64)
        self._terrains = None
        if terrain_of is not None:
            self._terrains = [terrain_of(mdl) for mdl in models]
            self._origin = self._terrains[0].origin
            self._tables = H.stack_terrains(self._terrains)
            self._hwork = H.Workspace.empty(n)

    @property
    def root_outputs(self) -> Mapping[str, int]:
        return {K.HFIELD: H.HFIELD_DIM} if self._terrains is not None else {}

    def limb_context(self, robot: Robot, model: mujoco.MjModel) -> np.ndarray:
        tpl, joints = static_features(robot, model)
        return squash_context(tpl[:, CONTEXT_COLUMNS], joints >= 0).astype(np.float32)

    def bind(self, j: int, data: mujoco.MjData) -> list[tuple[np.ndarray, np.ndarray]]:
        nb = data.xpos.shape[0]
        return [
            (self.xpos[j, :nb], data.xpos),
            (self.xquat[j, :nb], data.xquat),
            (self.cvel[j, :nb], data.cvel),
            (self.com[j], data.subtree_com[self.root[j]]),
            (self.qpos[j, : data.qpos.shape[0]], data.qpos),
            (self.qvel[j, : data.qvel.shape[0]], data.qvel),
        ]

    def gather(self, j: int, data: mujoco.MjData) -> None:
        for dst, src in self.bind(j, data):
            dst[...] = src

    def compute(self, rows: np.ndarray | None = None) -> np.ndarray:
        return self.features(rows).astype(np.float32)

    def features(self, rows: np.ndarray | None = None) -> np.ndarray:
        """The observations of :meth:`compute` in float64 [n, K, 63]."""
        sel = slice(None) if rows is None else rows
        body, maskf = self.body[sel], self._maskf[sel]
        n, k = body.shape
        out = self.template[sel].copy()
        xpos = np.take_along_axis(self.xpos[sel], body[..., None], axis=1)
        xquat = np.take_along_axis(self.xquat[sel], body[..., None], axis=1)
        cvel = np.take_along_axis(self.cvel[sel], body[..., None], axis=1)
        heading = H.heading_from_quat(xquat[:, 0])
        c, s = heading[:, 0:1], heading[:, 1:2]  # [n, 1]

        def to_heading(v: np.ndarray, dst: np.ndarray) -> None:
            dst[..., 0] = c * v[..., 0] + s * v[..., 1]
            dst[..., 1] = c * v[..., 1] - s * v[..., 0]
            dst[..., 2] = v[..., 2]
            dst *= maskf[..., None]

        rel = xpos.copy()
        rel[..., :2] -= xpos[:, :1, :2]
        to_heading(rel, out[..., 0:3])
        v = np.empty((n, k, 3))
        origin_velocity(xpos, self.com[sel], cvel, v)
        to_heading(v, out[..., 3:6])
        to_heading(cvel[..., :3], out[..., 6:9])
        # the heading frame's quaternion: a turn by yaw about z, from (cos yaw, sin yaw)
        half_c = np.sqrt(np.clip((1.0 + c) / 2.0, 0.0, 1.0))
        half_s = np.copysign(np.sqrt(np.clip((1.0 - c) / 2.0, 0.0, 1.0)), s)
        zero = np.zeros_like(half_c)
        q_heading = np.concatenate([half_c, zero, zero, half_s], axis=1)[:, None, :]
        out[..., 9:13] = _conj_mul(q_heading, xquat) * maskf[..., None]
        q = np.take_along_axis(self.qpos[sel], self.qadr[sel], axis=1).reshape(n, k, ACTION_SLOTS)
        dq = np.take_along_axis(self.qvel[sel], self.dadr[sel], axis=1)
        dq = dq.reshape(n, k, ACTION_SLOTS)
        has = self.has[sel]
        out[..., SLOT0::SLOT_WIDTH] = (q - self.lo[sel]) / self.span[sel] * has
        out[..., SLOT0 + 1 :: SLOT_WIDTH] = dq * has
        return out

    def compute_root(self, rows: np.ndarray | None = None) -> dict[str, np.ndarray]:
        if self._terrains is None:
            return {}
        body0 = self.body[:, 0] if rows is None else self.body[rows, 0]
        which = np.arange(len(self.body)) if rows is None else np.asarray(rows)
        xy = self.xpos[which, body0, :2]
        heading = H.heading_from_quat(self.xquat[which, body0])
        out = np.empty((len(which), H.HFIELD_DIM), np.float32)
        H.height_map(xy, heading, self._tables, self._origin, which, self._hwork, out)
        return {K.HFIELD: out}
