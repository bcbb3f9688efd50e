"""gcnt: morphology-agnostic reinforcement learning with GCNT and its baselines."""

__version__ = "0.1.0"
