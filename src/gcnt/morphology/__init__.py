"""Robots as data and as graphs (numpy, mujoco and dm_control only; no torch)."""

from gcnt.morphology.graph import DIST_PAD, WL_BUCKETS, WL_ROUNDS, RobotGraph
from gcnt.morphology.limb_types import GLOBAL_LIMB_TYPES, GLOBAL_TYPE_ID
from gcnt.morphology.robot import Robot, RobotFileError, load_robot, robot_from_xml

__all__ = [
    "DIST_PAD",
    "GLOBAL_LIMB_TYPES",
    "GLOBAL_TYPE_ID",
    "WL_BUCKETS",
    "WL_ROUNDS",
    "Robot",
    "RobotFileError",
    "RobotGraph",
    "load_robot",
    "robot_from_xml",
]
