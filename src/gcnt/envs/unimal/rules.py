"""UNIMAL's task rules of one sub-env: start state, reward and termination per world.

* Start: every joint at its ref, the torso where the robot file puts it (x = y = 0, its lowest
  point 0.2 m above the floor; Incline: the same pose pitched with the slab and moved to its low
  end), then U(±0.005) added to every qpos (root position and quaternion included) and qvel. MT
  and Obstacles draw their terrain anew first (``terrain.py``), from the same generator.
* Reward per control step: the torso's forward velocity Δx / dt (Incline: divided by cos 10°, the
  speed along the slab). No control cost.
* Terminated when the torso's height above the local ground (FT, Obstacles: 0; Incline:
  x·tan 10°; MT: the terrain under the torso) is at most ``fall_ratio × (z0 − 0.2)``, z0 being
  the torso's z in the robot file; on MT and Obstacles also when |torso y| >= 19.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from gcnt.envs.plugins import TaskRules
from gcnt.envs.unimal import worlds as W
from gcnt.envs.unimal.terrain import MTTerrain, ObstacleField
from gcnt.morphology import Robot

RESET_NOISE = 0.005


def fall_threshold(z0: float, world: str) -> float:
    """Height of the torso above the local ground at (or below) which the episode ends."""
    return W.WORLDS[world].fall_ratio * (z0 - W.START_CLEARANCE)


def _root_addresses(robot: Robot, model: mujoco.MjModel) -> tuple[int, int]:
    body = int(robot.mj_body_ids[0])
    j = int(model.body_jntadr[body])
    if int(model.body_jntnum[body]) != 1 or model.jnt_type[j] != mujoco.mjtJoint.mjJNT_FREE:
        raise ValueError(
            f"robot {robot.name!r} ({robot.source}): torso {robot.body_names[0]!r} needs one free "
            "joint"
        )
    return int(model.jnt_qposadr[j]), int(model.jnt_dofadr[j])


class UnimalRules(TaskRules):
    """:class:`~gcnt.envs.base.TaskRules` of one UNIMAL sub-env in ``world``."""

    def __init__(self, robot: Robot, model: mujoco.MjModel, dt: float, world: str = "ft"):
        if world not in W.WORLDS:
            raise ValueError(f"unknown UNIMAL world {world!r} (known: {', '.join(W.WORLDS)})")
        self.world = W.WORLDS[world]
        self.edits_model = self.world.edits_model
        self.robot = robot
        self.qadr, _ = _root_addresses(robot, model)
        self.z0 = float(model.qpos0[self.qadr + 2])
        self.threshold = fall_threshold(self.z0, world)
        self.inv_dt = 1.0 / dt
        if world == "incline":
            self.inv_dt /= W.INCLINE_COS
        self.terrain: MTTerrain | ObstacleField | None = None
        if world == "mt":
            self.terrain = MTTerrain(model)
        elif world == "obstacles":
            self.terrain = ObstacleField(model)
        self.x_prev = 0.0
        self.qpos: np.ndarray | None = None

    def reset(self, model: mujoco.MjModel, data: mujoco.MjData, rng: np.random.Generator) -> None:
        if self.terrain is not None:
            self.terrain.redraw(rng)
        a = self.qadr
        if self.world.name == "incline":
            # the file's pose, pitched with the slab, its ground point at x = INCLINE_START_X
            s, c = math.sin(math.radians(W.INCLINE_DEG)), W.INCLINE_COS
            x0 = W.INCLINE_START_X
            data.qpos[a : a + 3] = (x0 - self.z0 * s, 0.0, x0 * W.INCLINE_TAN + self.z0 * c)
            pitch = np.zeros(4)  # rotation about y by -10°: +x turns up the slope
            mujoco.mju_axisAngle2Quat(
                pitch, np.array([0.0, 1.0, 0.0]), -math.radians(W.INCLINE_DEG)
            )
            quat = np.zeros(4)
            mujoco.mju_mulQuat(quat, pitch, data.qpos[a + 3 : a + 7].copy())
            data.qpos[a + 3 : a + 7] = quat
        data.qpos[:] += rng.uniform(-RESET_NOISE, RESET_NOISE, model.nq)
        data.qvel[:] += rng.uniform(-RESET_NOISE, RESET_NOISE, model.nv)

    def begin(self, data: mujoco.MjData) -> None:
        self.qpos = data.qpos
        self.x_prev = float(data.qpos[self.qadr])

    def ground(self, x: float, y: float) -> float:
        """Height of the local ground under (x, y)."""
        if self.world.name == "incline":
            return x * W.INCLINE_TAN
        if self.terrain is not None:
            return self.terrain.ground(x, y)
        return 0.0

    def step(self, data: mujoco.MjData, action_sq: float) -> tuple[float, bool]:
        q = self.qpos
        if q is None:
            self.begin(data)
            q = self.qpos
        a = self.qadr
        x, y, z = float(q[a]), float(q[a + 1]), float(q[a + 2])
        reward = (x - self.x_prev) * self.inv_dt
        self.x_prev = x
        fallen = z - self.ground(x, y) <= self.threshold
        off_side = self.world.side_limit and abs(y) >= W.SIDE_LIMIT
        # NaN compares False: a blown-up state is caught by the env itself
        return reward, bool(fallen or off_side)

    def sync_render(self, model: mujoco.MjModel, renderer) -> None:
        if self.terrain is not None:
            self.terrain.sync_render(model, renderer)
