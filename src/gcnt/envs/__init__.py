"""TorchRL environments over MuJoCo that emit the gcnt TensorDict contract.

:class:`BatchedMujocoEnv` steps N robots of any benchmark; a benchmark plugs in a
:class:`Featurizer` and :class:`TaskRules` (SMPENV: :class:`SMPEnv`).
"""

from gcnt.envs.base import BatchedMujocoEnv, PhysicsBlowupWarning
from gcnt.envs.plugins import Featurizer, TaskRules
from gcnt.envs.robot_table import STATIC_KEYS, RobotTooLargeError, robot_table
from gcnt.envs.smpenv import SMPEnv

__all__ = [
    "STATIC_KEYS",
    "BatchedMujocoEnv",
    "Featurizer",
    "PhysicsBlowupWarning",
    "RobotTooLargeError",
    "SMPEnv",
    "TaskRules",
    "robot_table",
]
