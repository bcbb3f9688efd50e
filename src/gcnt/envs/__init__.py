"""TorchRL environments over MuJoCo that emit the gcnt TensorDict contract.

:class:`BatchedMujocoEnv` steps N robots of any benchmark; a benchmark plugs in a
:class:`Featurizer` and :class:`TaskRules` (SMPENV: :class:`SMPEnv`).

The names below load on first use, so that :mod:`gcnt.envs.benchmark` (the benchmark registry,
read when a run's record is checked) is imported without torch or MuJoCo.
"""

import importlib

_EXPORTS = {
    "BatchedMujocoEnv": "gcnt.envs.base",
    "PhysicsBlowupWarning": "gcnt.envs.base",
    "Featurizer": "gcnt.envs.plugins",
    "TaskRules": "gcnt.envs.plugins",
    "STATIC_KEYS": "gcnt.envs.robot_table",
    "RobotTooLargeError": "gcnt.envs.robot_table",
    "robot_table": "gcnt.envs.robot_table",
    "SMPEnv": "gcnt.envs.smpenv",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name not in _EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(_EXPORTS[name]), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_EXPORTS})
