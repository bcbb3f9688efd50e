"""gcnt: morphology-agnostic reinforcement learning with GCNT and its baselines."""

import os
import sys

# Headless rendering by default (EGL works on CPU-only machines through Mesa); a user's own
# MUJOCO_GL wins. Set before dm_control/mujoco rendering modules are imported.
os.environ.setdefault("MUJOCO_GL", "egl")

# OpenMP threads that sleep between parallel regions. By default torch's OpenMP workers spin for a
# while after each parallel torch op, on the very cores where the env's physics threads then run:
# on a 2-core machine `gcnt bench-env` (UNIMAL FT, 2 physics threads) measured 0.22-0.60 of the raw
# mj_step loop with spinning workers against 0.86-0.99 with OMP_WAIT_POLICY=PASSIVE. Read once,
# when torch loads its OpenMP runtime: it only takes effect if gcnt is imported before torch (the
# `gcnt` command always is); a user's own OMP_WAIT_POLICY wins.
#: True when torch was imported before gcnt with no OMP_WAIT_POLICY (its workers spin)
OPENMP_SPINS = "torch" in sys.modules and "OMP_WAIT_POLICY" not in os.environ
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

__version__ = "0.1.0"
