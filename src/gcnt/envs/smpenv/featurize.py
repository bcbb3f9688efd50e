"""SMPENV's featuriser: the 19-d limb observation, vectorised over sub-envs and limbs.

Per limb (bodies in depth-first pre-order, torso first):

======= ====================================================================================
0:3     position of the body frame in world, x made relative to the torso's x
3:6     linear velocity of the body-frame origin, world axes, clipped to ±10
6:9     angular velocity, world axes
9:12    orientation: exponential map (axis × angle, angle in [0, π]) of the world quaternion
12:16   family limb-type one-hot (``Robot.family_slots``; humanoids get real types)
16      joint angle normalised to [0, 1] over its range, in degrees (torso: 0)
17:19   joint range as ((180 + lo°)/360, (180 + hi°)/360) (torso: 0, 0)
======= ====================================================================================

Velocities come from MuJoCo's ``cvel`` (6-d velocity [angular, linear] of each body about the
centre of mass of its kinematic subtree, world axes): the velocity of the body-frame origin ``p``
is ``v = v_com + ω × (p − c)``, which is what ``mj_objectVelocity(mjOBJ_XBODY, flg_local=0)`` and
mujoco-py's ``get_body_xvelp`` (the original SMP code) return. The caller must have run
``mj_kinematics``, ``mj_comPos`` and ``mj_comVel`` on the current ``qpos``/``qvel`` (``mj_step``
leaves ``xpos``/``cvel`` at the state *before* its last integration step).

The work splits in two: :meth:`LimbFeaturizer.gather` copies the needed rows of one ``MjData``
(a handful of numpy calls per sub-env, no loop over limbs), and :meth:`LimbFeaturizer.compute`
turns the gathered arrays of many sub-envs into observations with whole-array numpy operations.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from gcnt.envs.kinematics import origin_velocity, torso_relative_position
from gcnt.envs.plugins import Featurizer
from gcnt.morphology import Robot
from gcnt.morphology.limb_types import FAMILY_TYPE_SLOTS

OBS_DIM = 19
VEL_CLIP = 10.0


@dataclass
class GatherBuffers:
    """Per-sub-env rows copied out of MjData, for n sub-envs padded to K limbs."""

    xpos: np.ndarray  # [n, K, 3]
    xquat: np.ndarray  # [n, K, 4]
    cvel: np.ndarray  # [n, K, 6]
    com: np.ndarray  # [n, 3]     subtree centre of mass of the torso (the root of cvel)
    jpos: np.ndarray  # [n, K]     qpos of each limb's hinge (0 on the torso and padding)

    @classmethod
    def empty(cls, n: int, k: int) -> GatherBuffers:
        xquat = np.zeros((n, k, 4))
        xquat[..., 0] = 1.0
        return cls(
            xpos=np.zeros((n, k, 3)),
            xquat=xquat,
            cvel=np.zeros((n, k, 6)),
            com=np.zeros((n, 3)),
            jpos=np.zeros((n, k)),
        )


@dataclass(frozen=True)
class LimbIndex:
    """Where a robot's limbs live in its MjData, padded to K."""

    bodies: np.ndarray  # int64 [K] MuJoCo body id per limb (0 = world on padding)
    joint_qpos: np.ndarray  # int64 [K] qpos address of the limb's hinge (0 on torso/padding)
    has_joint: np.ndarray  # bool [K]
    root_body: int  # body whose subtree com is cvel's reference point


def limb_index(robot: Robot, model: mujoco.MjModel, k: int) -> LimbIndex:
    m = robot.num_limbs
    bodies = np.zeros(k, np.int64)
    bodies[:m] = robot.mj_body_ids
    jq = np.zeros(k, np.int64)
    has = np.zeros(k, bool)
    for i, joints in enumerate(robot.mj_joint_ids):
        if joints:  # SMPENV limbs have exactly one hinge; the observation uses the first
            jq[i] = model.jnt_qposadr[joints[0]]
            has[i] = True
    return LimbIndex(bodies, jq, has, int(model.body_rootid[robot.mj_body_ids[0]]))


def static_features(robot: Robot, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The constant part of a robot's observation and its joint ranges in degrees.

    Returns ``(template [K, 19] float32, range_deg [K, 2] float64)``; the template holds the type
    one-hot and the mapped joint range, zeros elsewhere; range_deg is (0, 1) where there is no
    joint, so that the normalisation never divides by zero.
    """
    m = robot.num_limbs
    template = np.zeros((k, OBS_DIM), np.float32)
    slots = np.asarray(robot.family_slots)
    if slots.max(initial=0) >= FAMILY_TYPE_SLOTS:
        raise ValueError(f"robot {robot.name!r}: family slot {slots.max()} out of range")
    template[np.arange(m), 12 + slots] = 1.0
    rng = np.tile([0.0, 1.0], (k, 1))
    for i, r in enumerate(robot.joint_ranges):
        if len(r):
            lo, hi = np.degrees(r[0])
            rng[i] = lo, hi
            template[i, 17] = (180.0 + lo) / 360.0
            template[i, 18] = (180.0 + hi) / 360.0
    return template, rng


class LimbFeaturizer(Featurizer):
    """SMPENV's :class:`~gcnt.envs.base.Featurizer`: the 19-d observation of a fixed list of
    sub-envs (given by their robots) padded to K limbs. No root outputs, no limb context."""

    obs_dim = OBS_DIM

    def __init__(self, robots: Sequence[Robot], models: Sequence[mujoco.MjModel], k: int):
        self.k = k
        n = len(robots)
        self.index = [limb_index(r, mdl, k) for r, mdl in zip(robots, models, strict=True)]
        self.mask = np.zeros((n, k), bool)
        self.template = np.zeros((n, k, OBS_DIM), np.float32)
        self.range_lo = np.zeros((n, k))
        self.range_span = np.ones((n, k))
        self.has_joint = np.zeros((n, k), bool)
        for j, r in enumerate(robots):
            self.mask[j, : r.num_limbs] = True
            tpl, rng = static_features(r, k)
            self.template[j] = tpl
            self.range_lo[j] = rng[:, 0]
            self.range_span[j] = rng[:, 1] - rng[:, 0]
            self.has_joint[j] = self.index[j].has_joint
        if (self.range_span[self.has_joint] <= 0).any():
            bad = [
                r.name
                for j, r in enumerate(robots)
                if (self.range_span[j][self.has_joint[j]] <= 0).any()
            ]
            raise ValueError(
                f"robots {bad}: a limb joint has an empty range (limited joints needed)"
            )
        self.buffers = GatherBuffers.empty(n, k)
        # How gather() copies each sub-env: a slice when the limbs are consecutive bodies (so the
        # padded rows are never written and keep their neutral values), else index arrays.
        self._plan: list[tuple[slice | np.ndarray, int, np.ndarray]] = []
        for ix, r in zip(self.index, robots, strict=True):
            m = r.num_limbs
            ids = ix.bodies[:m]
            if np.array_equal(ids, np.arange(ids[0], ids[0] + m)):
                self._plan.append((slice(int(ids[0]), int(ids[0]) + m), m, ix.joint_qpos))
            else:
                self._plan.append((ix.bodies, m, ix.joint_qpos))
        self._mask2f = self.mask.astype(np.float64)
        self._has_joint_f = self.has_joint.astype(np.float64)

    def bind(self, j: int, data: mujoco.MjData) -> list[tuple[np.ndarray, np.ndarray]] | None:
        """Copy pairs ``(buffer view, MjData view)`` that do :meth:`gather` for sub-env ``j``.

        ``dst[...] = src`` over these pairs is the fastest gather (MjData arrays never move, so
        the views stay valid for the life of ``data``). None if the limbs are not consecutive
        bodies with consecutive hinge qpos; use :meth:`gather` then.
        """
        bodies, m, jq = self._plan[j]
        if not isinstance(bodies, slice):
            return None
        b = self.buffers
        pairs = [
            (b.xpos[j, :m], data.xpos[bodies]),
            (b.xquat[j, :m], data.xquat[bodies]),
            (b.cvel[j, :m], data.cvel[bodies]),
            (b.com[j : j + 1], data.subtree_com[self.index[j].root_body][None]),
        ]
        if m > 1:
            q = jq[1:m]
            if not np.array_equal(q, np.arange(q[0], q[0] + m - 1)):
                return None
            pairs.append((b.jpos[j, 1:m], data.qpos[int(q[0]) : int(q[0]) + m - 1]))
        return pairs

    def gather(self, j: int, data: mujoco.MjData) -> None:
        """Copy sub-env ``j``'s rows out of its MjData (kinematics must be current)."""
        b = self.buffers
        bodies, m, jq = self._plan[j]
        if isinstance(bodies, slice):  # limbs are consecutive bodies: plain slice copies
            b.xpos[j, :m] = data.xpos[bodies]
            b.xquat[j, :m] = data.xquat[bodies]
            b.cvel[j, :m] = data.cvel[bodies]
        else:
            data.xpos.take(bodies, axis=0, out=b.xpos[j])
            data.xquat.take(bodies, axis=0, out=b.xquat[j])
            data.cvel.take(bodies, axis=0, out=b.cvel[j])
        b.com[j] = data.subtree_com[self.index[j].root_body]
        data.qpos.take(jq, out=b.jpos[j])

    def compute(self, rows: np.ndarray | None = None) -> np.ndarray:
        """Observations float32 [n, K, 19] of the gathered sub-envs (``rows``: a subset).

        Written for few numpy calls (their count, not the array size, is the cost here). Padded
        limb rows hold the world body's values (position 0, identity rotation, velocity 0), which
        featurise to zeros, so only the torso-relative x needs the mask.
        """
        b = self.buffers
        if rows is None:
            xpos, xquat, cvel, com, jpos = b.xpos, b.xquat, b.cvel, b.com, b.jpos
            tpl, maskf, lo, span, hasj = (
                self.template,
                self._mask2f,
                self.range_lo,
                self.range_span,
                self._has_joint_f,
            )
        else:
            xpos, xquat, cvel, com, jpos = (
                b.xpos[rows],
                b.xquat[rows],
                b.cvel[rows],
                b.com[rows],
                b.jpos[rows],
            )
            tpl, maskf, lo, span, hasj = (
                self.template[rows], self._mask2f[rows], self.range_lo[rows],
                self.range_span[rows], self._has_joint_f[rows],
            )  # fmt: skip
        dyn = np.empty((*xpos.shape[:2], 12))
        w = cvel[..., :3]
        # 0:3 body-frame position, x relative to the torso's x
        torso_relative_position(xpos, maskf, dyn[..., 0:3])
        # 3:6 velocity of the body-frame origin p: v(p) = v(c) + ω × (p − c), clipped
        v = dyn[..., 3:6]
        origin_velocity(xpos, com, cvel, v)
        np.clip(v, -VEL_CLIP, VEL_CLIP, out=v)
        # 6:9 angular velocity
        dyn[..., 6:9] = w
        # 9:12 exponential map of the world quaternion (w >= 0 representative, angle in [0, π])
        qw, qv = xquat[..., 0], xquat[..., 1:]
        sin_half = np.sqrt(np.einsum("...i,...i->...", qv, qv))
        angle = np.arctan2(sin_half, np.abs(qw))
        angle *= 2.0
        scale = np.divide(angle, sin_half, out=np.full_like(angle, 2.0), where=sin_half > 1e-12)
        np.negative(scale, out=scale, where=qw < 0)
        np.multiply(qv, scale[..., None], out=dyn[..., 9:12])
        out = tpl.copy()
        out[..., :12] = dyn
        # 16 joint angle normalised over its range, in degrees
        ang = np.degrees(jpos)
        ang -= lo
        ang /= span
        ang *= hasj
        out[..., 16] = ang
        return out
