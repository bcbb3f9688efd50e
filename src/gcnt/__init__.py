"""gcnt: morphology-agnostic reinforcement learning with GCNT and its baselines."""

import os
import sys

# Headless rendering by default (EGL works on CPU-only machines through Mesa); a user's own
# MUJOCO_GL wins. Set before dm_control/mujoco rendering modules are imported.
os.environ.setdefault("MUJOCO_GL", "egl")

# torch's OpenMP workers (GNU libgomp) spin-wait after each parallel torch op, 300,000 rounds by
# default, on the very cores where the env's physics threads then run. A short spin keeps the
# update as fast and frees the cores for the physics. Measured on a 2-core machine, UNIMAL FT
# `gcnt bench-env` (2 physics threads) against the raw mj_step loop, and `gcnt bench-train` of the
# quick start (bare paper-schedule updates/s, mixed end-to-end env steps/s):
#   GOMP_SPINCOUNT=300000 (libgomp's default): env 0.64, updates 53.6/s, 111 steps/s
#   GOMP_SPINCOUNT=10000  (gcnt's default)   : env 0.97, updates 63.2/s, 117 steps/s
#   OMP_WAIT_POLICY=PASSIVE (no spinning)    : env 0.84-0.99, updates 22.5/s, 63 steps/s
# libgomp reads it once, when torch loads it: it only takes effect if gcnt is imported before
# torch (the `gcnt` command always is). A user's own GOMP_SPINCOUNT or OMP_WAIT_POLICY wins.
_OPENMP_KEYS = ("GOMP_SPINCOUNT", "OMP_WAIT_POLICY")
#: True when torch was imported before gcnt with libgomp's default spinning
OPENMP_SPINS = "torch" in sys.modules and not any(k in os.environ for k in _OPENMP_KEYS)
if not any(k in os.environ for k in _OPENMP_KEYS):
    os.environ["GOMP_SPINCOUNT"] = "10000"

__version__ = "0.1.0"

#: the Python API (:mod:`gcnt.api`), imported on first use: ``import gcnt`` stays light
_API = ("load_run", "load_policy", "make_env", "LoadedRun")


def __getattr__(name: str):
    if name in _API:
        from gcnt import api

        return getattr(api, name)
    raise AttributeError(f"module 'gcnt' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_API])
