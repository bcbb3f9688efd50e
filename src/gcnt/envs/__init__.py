"""TorchRL environments over MuJoCo that emit the gcnt TensorDict contract."""

from gcnt.envs.robot_table import STATIC_KEYS, RobotTooLargeError, robot_table

__all__ = ["STATIC_KEYS", "RobotTooLargeError", "robot_table"]
