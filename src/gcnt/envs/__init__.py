"""TorchRL environments over MuJoCo that emit the gcnt TensorDict contract."""

from gcnt.envs.robot_table import STATIC_KEYS, RobotTooLargeError, robot_table
from gcnt.envs.smpenv import PhysicsBlowupWarning, SMPEnv

__all__ = ["STATIC_KEYS", "PhysicsBlowupWarning", "RobotTooLargeError", "SMPEnv", "robot_table"]
