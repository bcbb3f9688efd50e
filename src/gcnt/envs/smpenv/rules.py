"""SMPENV's task rules: reward weights, the healthy test and the reset noise per family, and
:class:`PlanarRootRules`, their :class:`~gcnt.envs.base.TaskRules` for robots on planar root joints.

The rules of the SMPENV benchmark:

=========== ============================== ================================================ ==========================================
family      reward per control step        healthy (the episode terminates when it fails)  reset noise
=========== ============================== ================================================ ==========================================
walker      Δx/dt + 1 − 1e-3·Σa²           0.8 < z < 2.0 and −1 < pitch < 1; both z bounds  qpos, qvel + U(±0.005)
                                           lowered by 0.136 for walker_4, 0.26 for 2 and 3
hopper      Δx/dt + 1 − 1e-3·Σa²           s finite, |s[2:]| < 100, |pitch| < 1, z > 0.45   qpos, qvel + U(±0.005)
                                           (hopper_3), 0.6 (hopper_4), 0.95 (hopper_5)
humanoid    Δx/dt + 1 − 1e-3·Σa²           0.4 < z < 2.1 and −1 < pitch < 1                 qpos, qvel + U(±0.005)
cheetah     Δx/dt − 0.1·Σa²                never terminates                                 qpos + U(±0.1), qvel + N(0, 0.1²)
=========== ============================== ================================================ ==========================================

x is the qpos of the torso's root slide-x joint and s is (qpos, qvel). z and pitch are the torso's
height and tilt as SMPENV's files write them: their root slide-z joint starts at its ref, the
torso's start height (1.25; 1.75 for hopper_5), their hinge-y joint at 0, and z and pitch are
their qpos. Other files write other refs (dm_control's slide-z joints start at 0, the torso's
height being in its body's position), so the rules read z as the SMPENV start height plus the
slide-z joint's rise since its ref, and pitch as the hinge-y joint's turn since its ref (qpos −
qpos0): every file is allowed the same fall, rise and tilt from the pose it is written in as the
SMPENV robot of its family and size, and SMPENV's own files read exactly their qpos. The
size-dependent bounds come from the body count in the robot's name
(``walker_4_main`` → 4, ``hopper_5`` → 5); a name without a number falls back to the robot's limb
count. dt is the control period (frame_skip × timestep: 0.008 s for walker, hopper and humanoid,
0.04 s for cheetah). Everything here is per robot; the env applies the rules of each sub-env right
after stepping it, in the physics threads.
"""

from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass

import mujoco
import numpy as np

from gcnt.envs.plugins import TaskRules
from gcnt.morphology import Robot

log = logging.getLogger(__name__)

#: The control period is ``frame_skip`` physics steps for every SMPENV family.
FRAME_SKIP = 4

_WALKER_Z_SHIFT = {2: 0.26, 3: 0.26, 4: 0.136}
_HOPPER_MIN_Z = {3: 0.45, 4: 0.6, 5: 0.95}
_HOPPER_DEFAULT_MIN_Z = 0.7  # gym's hopper, for a hand-made hopper of another size
#: The torso's start height (root slide-z ref) in SMPENV's files: 1.25, and 1.75 for hopper_5.
_START_Z = 1.25
_HOPPER_START_Z = {5: 1.75}


@dataclass(frozen=True)
class FamilyRules:
    """Reward, termination and reset-noise rules of one SMPENV robot."""

    family: str
    healthy_reward: float  # per control step while alive
    ctrl_cost: float  # weight of Σa² (a: the clipped actions)
    z_low: float = -math.inf  # healthy iff z_low < z < z_high ...
    z_high: float = math.inf
    pitch_max: float = math.inf  # ... and |pitch| < pitch_max
    state_check: bool = False  # ... and (hopper) s finite and |s[2:]| < state_max
    state_max: float = 100.0
    start_z: float = _START_Z  # z at the start pose (see the module doc)
    qpos_noise: float = 0.005  # U(±qpos_noise) on every qpos
    qvel_noise: float = 0.005  # U(±qvel_noise), or N(0, qvel_noise²) if qvel_noise_normal
    qvel_noise_normal: bool = False

    @property
    def can_terminate(self) -> bool:
        return (
            self.state_check
            or self.z_low > -math.inf
            or self.z_high < math.inf
            or self.pitch_max < math.inf
        )

    def healthy(self, z: float, pitch: float, *state: np.ndarray) -> bool:
        """The healthy test of one robot. ``state``: the arrays that make up s[2:], i.e. qpos
        without root x and z, and qvel (read only by the hopper's test). NaN is unhealthy."""
        if not self.can_terminate:
            return True
        if not (self.z_low < z < self.z_high and -self.pitch_max < pitch < self.pitch_max):
            return False
        if self.state_check:
            # max() propagates NaN, and NaN < x is False: non-finite states fail too
            return all(bool(np.abs(a).max(initial=0.0) < self.state_max) for a in state)
        return True


def body_count(robot: Robot) -> int:
    """The body count in the robot's name (``walker_4_main`` → 4), else its limb count."""
    m = re.match(rf"{re.escape(robot.family)}(?:_2d)?_(\d+)", robot.name)
    return int(m.group(1)) if m else robot.num_limbs


def task_rules(robot: Robot) -> FamilyRules:
    """The SMPENV rules of ``robot``, from its family and name."""
    fam = robot.family
    if fam == "walker":
        shift = _WALKER_Z_SHIFT.get(body_count(robot), 0.0)
        return FamilyRules(fam, 1.0, 1e-3, z_low=0.8 - shift, z_high=2.0 - shift, pitch_max=1.0)
    if fam == "hopper":
        n = body_count(robot)
        if n not in _HOPPER_MIN_Z:
            log.warning(
                "robot %r: no SMPENV hopper has %d bodies; using gym's healthy height z > %.2f",
                robot.name,
                n,
                _HOPPER_DEFAULT_MIN_Z,
            )
        z_low = _HOPPER_MIN_Z.get(n, _HOPPER_DEFAULT_MIN_Z)
        start_z = _HOPPER_START_Z.get(n, _START_Z)
        return FamilyRules(
            fam, 1.0, 1e-3, z_low=z_low, pitch_max=1.0, state_check=True, start_z=start_z
        )
    if fam == "humanoid":
        return FamilyRules(fam, 1.0, 1e-3, z_low=0.4, z_high=2.1, pitch_max=1.0)
    if fam == "cheetah":
        return FamilyRules(fam, 0.0, 0.1, qpos_noise=0.1, qvel_noise=0.1, qvel_noise_normal=True)
    raise ValueError(f"robot {robot.name!r}: family {fam!r} has no SMPENV task rules")


@dataclass(frozen=True)
class RootJoints:
    """qpos/qvel addresses of the torso's planar root joints (slide x, slide z, hinge y)."""

    x: int
    z: int
    pitch: int
    x_dof: int
    z_dof: int


def root_joints(robot: Robot, model: mujoco.MjModel) -> RootJoints:
    """Find the torso's slide-x, slide-z and hinge-y joints; a clear error if one is missing."""
    body = int(robot.mj_body_ids[0])
    start, num = int(model.body_jntadr[body]), int(model.body_jntnum[body])
    found: dict[str, int] = {}
    for j in range(start, start + num):
        axis = np.round(np.abs(model.jnt_axis[j]), 6)
        if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_SLIDE and np.array_equal(axis, [1, 0, 0]):
            found.setdefault("x", j)
        elif model.jnt_type[j] == mujoco.mjtJoint.mjJNT_SLIDE and np.array_equal(axis, [0, 0, 1]):
            found.setdefault("z", j)
        elif model.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE and np.array_equal(axis, [0, 1, 0]):
            found.setdefault("pitch", j)
    missing = [k for k in ("x", "z", "pitch") if k not in found]
    if missing:
        raise ValueError(
            f"robot {robot.name!r} ({robot.source}): torso {robot.body_names[0]!r} lacks the planar "
            f"root joint(s) {', '.join(missing)} (expected slide x, slide z, hinge y)"
        )
    return RootJoints(
        x=int(model.jnt_qposadr[found["x"]]),
        z=int(model.jnt_qposadr[found["z"]]),
        pitch=int(model.jnt_qposadr[found["pitch"]]),
        x_dof=int(model.jnt_dofadr[found["x"]]),
        z_dof=int(model.jnt_dofadr[found["z"]]),
    )


def reset_noise(
    rules: FamilyRules, rng: np.random.Generator, nq: int, nv: int
) -> tuple[np.ndarray, np.ndarray]:
    """Draw the reset noise of one sub-env: (qpos noise [nq], qvel noise [nv])."""
    dq = rng.uniform(-rules.qpos_noise, rules.qpos_noise, nq)
    if rules.qvel_noise_normal:
        dv = rng.normal(0.0, rules.qvel_noise, nv)
    else:
        dv = rng.uniform(-rules.qvel_noise, rules.qvel_noise, nv)
    return dq, dv


class PlanarRootRules(TaskRules):
    """SMPENV's :class:`~gcnt.envs.base.TaskRules` of one sub-env: a robot on planar root joints.

    Start: every joint at its ref (``qpos0``) plus the family's reset noise. Reward per control
    step: Δx/dt + healthy reward − ctrl_cost·Σa², x being the root slide-x qpos; the episode
    terminates when the family's healthy test fails (see :func:`task_rules`), which reads the
    height z = slide-z qpos + ``z_offset`` (the family's start height minus the joint's ref: 0 for
    SMPENV's files, 1.25 for a walker file whose joint starts at 0) and the tilt pitch = hinge-y
    qpos − ``pitch_ref`` (see the module doc).
    """

    __slots__ = (
        "family",
        "inv_dt",
        "pitch_ref",
        "qpos",
        "qvel",
        "rest",
        "root",
        "x_prev",
        "z_offset",
    )

    def __init__(self, robot: Robot, model: mujoco.MjModel, dt: float):
        self.family = task_rules(robot)
        self.root = root_joints(robot, model)
        self.inv_dt = 1.0 / dt
        self.z_offset = self.family.start_z - float(model.qpos0[self.root.z])
        self.pitch_ref = float(model.qpos0[self.root.pitch])
        self.x_prev = 0.0
        # qpos addresses of s[2:] (all but root x and z), for the hopper's state test
        self.rest = np.setdiff1d(np.arange(model.nq), [self.root.x, self.root.z])
        self.qpos: np.ndarray | None = None  # the sub-env's qpos and qvel, bound on first use
        self.qvel: np.ndarray | None = None

    def reset(self, model: mujoco.MjModel, data: mujoco.MjData, rng: np.random.Generator) -> None:
        dq, dv = reset_noise(self.family, rng, model.nq, model.nv)
        data.qpos[:] += dq
        data.qvel[:] += dv

    def begin(self, data: mujoco.MjData) -> None:
        self.qpos, self.qvel = data.qpos, data.qvel
        self.x_prev = data.qpos[self.root.x]

    def step(self, data: mujoco.MjData, action_sq: float) -> tuple[float, bool]:
        q, rules, root = self.qpos, self.family, self.root
        if q is None:
            self.begin(data)
            q = self.qpos
        x, z, pitch = float(q[root.x]), q[root.z] + self.z_offset, q[root.pitch] - self.pitch_ref
        if rules.state_check:
            ok = rules.healthy(z, pitch, q[self.rest], self.qvel)
        else:
            ok = rules.healthy(z, pitch)
        reward = (
            (x - self.x_prev) * self.inv_dt + rules.healthy_reward - rules.ctrl_cost * action_sq
        )
        self.x_prev = x
        return reward, not ok
