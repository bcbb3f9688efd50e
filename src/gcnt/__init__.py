"""gcnt: morphology-agnostic reinforcement learning with GCNT and its baselines."""

import os

# Headless rendering by default (EGL works on CPU-only machines through Mesa); a user's own
# MUJOCO_GL wins. Set before dm_control/mujoco rendering modules are imported.
os.environ.setdefault("MUJOCO_GL", "egl")

__version__ = "0.1.0"
