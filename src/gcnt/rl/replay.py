"""Per-robot replay buffers, routed by ``morph_id`` (torchrl's ReplayBufferEnsemble).

Only what learning needs is stored: ``morph_id``, the limb observations and actions, and the next
step's observations, reward and done flags. Graph tensors are static per robot and are restored by
the policy's GraphLookup, so they are not duplicated per transition.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torchrl.data import LazyTensorStorage, ReplayBuffer, ReplayBufferEnsemble

#: keys kept per transition
STORED_KEYS: tuple = (
    "morph_id",
    ("limbs", "obs"),
    ("limbs", "action"),
    ("next", "limbs", "obs"),
    ("next", "reward"),
    ("next", "done"),
    ("next", "terminated"),
    ("next", "truncated"),
)


def per_robot_capacity(num_robots: int, size_per_robot: int, total_size: int) -> int:
    return max(1, min(size_per_robot, total_size // max(num_robots, 1)))


def make_replay(
    num_robots: int, capacity: int, batch_size: int, device: str | torch.device = "cpu"
) -> ReplayBufferEnsemble:
    """One buffer per robot; ``sample()`` draws ``batch_size`` transitions from every robot."""
    buffers = [
        ReplayBuffer(storage=LazyTensorStorage(capacity, device=device), batch_size=batch_size)
        for _ in range(num_robots)
    ]
    return ReplayBufferEnsemble(
        *buffers, routing_key="morph_id", sample_from_all=True, batch_size=batch_size * num_robots
    )


def store(replay: ReplayBufferEnsemble, data: TensorDictBase) -> int:
    """Add a collected batch (any batch shape) to the per-robot buffers; returns its size."""
    flat = data.select(*STORED_KEYS).reshape(-1)
    replay.extend(flat)
    return flat.numel()


def sample_robot(replay: ReplayBufferEnsemble, robot: int) -> TensorDictBase:
    """A mini-batch from one robot's buffer (the paper's schedule)."""
    return replay[robot].sample()


def sample_mixed(replay: ReplayBufferEnsemble) -> TensorDictBase:
    """A padded mini-batch mixing every robot (batch_size of each), flattened to [R * batch]."""
    batch = replay.sample()
    return batch.exclude("index").reshape(-1)
