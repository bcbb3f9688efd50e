"""Task rules of a general 3-D robot: UNIMAL's rules with a fall height read from the robot.

Start state, reset noise (U(±0.005) on every qpos and qvel), per-episode terrain, reward (the
torso's forward velocity Δx/dt, no control cost) and the side limit of MT and Obstacles are
UNIMAL's (:class:`gcnt.envs.unimal.rules.UnimalRules`). The episode terminates when the torso's
height above the local ground is at most ``fall_ratio × h0``:

* ``h0`` is the torso's start height above the robot's lowest point, both in the file's pose
  (every joint at its ref; the lowest point of spheres and capsules exactly, of other shapes the
  lowest corner of their bounding boxes). For most UNIMAL files this is UNIMAL's own threshold (which
  takes the lowest point 0.2 m above the floor; a limb tilted down can reach a few cm lower);
* ``fall_ratio`` is the world's (FT and Obstacles 0.5, MT 0.3), unless the robot file sets its
  own with ``<custom><numeric name="gcnt_fall_ratio" data="0.3"/></custom>``.
"""

from __future__ import annotations

import mujoco
import numpy as np

from gcnt.envs.unimal import worlds as W
from gcnt.envs.unimal.rules import UnimalRules
from gcnt.morphology import Robot, RobotFileError

#: ``<custom><numeric>`` entry of a robot file that sets its own fall ratio
FALL_RATIO_NUMERIC = "gcnt_fall_ratio"


def lowest_point(model: mujoco.MjModel, data: mujoco.MjData) -> float:
    """The lowest z of the geoms of bodies other than the world body at ``data``'s kinematics:
    exact for spheres and capsules, the lowest corner of the bounding box for other shapes."""
    robot = np.nonzero(model.geom_bodyid > 0)[0]
    if not len(robot):
        return float("nan")
    centre, half = model.geom_aabb[robot, :3], model.geom_aabb[robot, 3:]
    rows = data.geom_xmat[robot].reshape(-1, 3, 3)[:, 2, :]  # world z of each geom axis
    z = data.geom_xpos[robot, 2] + (rows * centre).sum(1) - (np.abs(rows) * half).sum(1)
    kind, size = model.geom_type[robot], model.geom_size[robot]
    sphere = kind == mujoco.mjtGeom.mjGEOM_SPHERE
    z[sphere] = data.geom_xpos[robot[sphere], 2] - size[sphere, 0]
    capsule = kind == mujoco.mjtGeom.mjGEOM_CAPSULE
    z[capsule] = (
        data.geom_xpos[robot[capsule], 2]
        - np.abs(rows[capsule, 2]) * size[capsule, 1]
        - size[capsule, 0]
    )
    return float(z.min())


def fall_ratio(robot: Robot, model: mujoco.MjModel, world: str) -> float:
    """The robot file's ``gcnt_fall_ratio`` if it has one, else the world's fall ratio."""
    for i in range(model.nnumeric):
        if model.numeric(i).name == FALL_RATIO_NUMERIC:
            value = float(model.numeric_data[model.numeric_adr[i]])
            if not 0.0 < value < 1.0:
                raise RobotFileError(
                    f"{robot.source}: {FALL_RATIO_NUMERIC} must be in (0, 1), got {value}"
                )
            return value
    return W.WORLDS[world].fall_ratio


def fall_height(robot: Robot, model: mujoco.MjModel, world: str) -> float:
    """Torso height above the local ground at (or below) which the episode ends."""
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    z0 = float(data.xpos[int(robot.mj_body_ids[0]), 2])
    return fall_ratio(robot, model, world) * (z0 - lowest_point(model, data))


class Mjcf3dRules(UnimalRules):
    """:class:`~gcnt.envs.plugins.TaskRules` of one general 3-D sub-env in ``world``."""

    def __init__(self, robot: Robot, model: mujoco.MjModel, dt: float, world: str = "ft"):
        super().__init__(robot, model, dt, world)
        self.threshold = fall_height(robot, model, world)
