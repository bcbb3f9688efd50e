"""Replay for many robots: one storage of shape [robots, capacity], sampled with one index draw.

Each robot has its own ring of ``capacity`` transitions (the paper's per-robot buffers), but all
rings live in one TensorDict [R, C], so a mixed mini-batch of every robot is one ``rand`` and one
gather per stored key, and one robot's mini-batch is one ``randint`` and one gather.

Only what learning needs is stored: ``morph_id``, the limb observations and actions, and the next
step's observations, reward and done flags (and the height map on worlds that have one). Graph
tensors are static per robot and are restored from the robot table, so they are not duplicated per
transition.

:func:`make_ensemble` builds the previous layout (torchrl's ``ReplayBufferEnsemble`` of per-robot
buffers, routed by ``morph_id``) for comparisons; training uses :class:`RobotReplay`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase

from gcnt import keys as K

#: keys kept per transition
STORED_KEYS: tuple = (
    K.MORPH_ID,
    K.OBS,
    K.ACTION,
    (K.NEXT, *K.OBS),
    (K.NEXT, K.REWARD),
    (K.NEXT, K.DONE),
    (K.NEXT, K.TERMINATED),
    (K.NEXT, K.TRUNCATED),
)
#: kept too when the env emits them (height-map worlds)
OPTIONAL_KEYS: tuple = (K.HFIELD, (K.NEXT, K.HFIELD))
#: the stored keys with a limb axis (the one after the transition's): what a sample cut to its
#: robot's own limbs narrows
LIMB_KEYS: tuple = (K.OBS, K.ACTION, (K.NEXT, *K.OBS))


def per_robot_capacity(num_robots: int, size_per_robot: int, total_size: int) -> int:
    return max(1, min(size_per_robot, total_size // max(num_robots, 1)))


class RobotReplay:
    """Per-robot rings in one [R, C] storage (allocated at the first :meth:`extend`).

    Args:
        num_robots: R; a transition's ring is its ``morph_id``.
        capacity: C, transitions kept per robot (the oldest are overwritten).
        batch_size: transitions per robot in a mini-batch.
        device: where the storage lives (``cpu``, or the learner's GPU).
    """

    def __init__(
        self, num_robots: int, capacity: int, batch_size: int, device: str | torch.device = "cpu"
    ) -> None:
        if num_robots < 1 or capacity < 1 or batch_size < 1:
            raise ValueError(
                f"RobotReplay needs robots, capacity and batch_size >= 1, got {num_robots}, "
                f"{capacity}, {batch_size}"
            )
        self.num_robots, self.capacity, self.batch_size = num_robots, capacity, batch_size
        self.device = torch.device(device)
        self.storage: TensorDictBase | None = None
        self.keys: list = []
        self._flat: list[torch.Tensor] = []  # each stored key as [R * C, ...] (views)
        self.cursor = torch.zeros(num_robots, dtype=torch.long)  # next slot per robot (CPU)
        self.sizes = torch.zeros(num_robots, dtype=torch.long)  # filled slots per robot (CPU)
        self._robot_offset = torch.arange(num_robots, device=self.device) * capacity
        self._sizes_dev = self.sizes.to(self.device)  # for sampling without a host copy

    # ------------------------------------------------------------------ filling
    def __len__(self) -> int:
        return int(self.sizes.sum())

    def robot_len(self, robot: int) -> int:
        return int(self.sizes[robot])

    def _allocate(self, flat: TensorDictBase) -> None:
        self.keys = [k for k in (*STORED_KEYS, *OPTIONAL_KEYS) if k in flat.keys(True, True)]
        missing = [k for k in STORED_KEYS if k not in self.keys]
        if missing:
            raise KeyError(f"RobotReplay: the collected data lacks the keys {missing}")
        r, c = self.num_robots, self.capacity
        self.storage = TensorDict(
            {
                k: torch.zeros(
                    (r, c, *flat.get(k).shape[1:]), dtype=flat.get(k).dtype, device=self.device
                )
                for k in self.keys
            },
            batch_size=[r, c],
            device=self.device,
        )
        self._flat = [self.storage.get(k).flatten(0, 1) for k in self.keys]

    def extend(self, data: TensorDictBase) -> int:
        """Add a collected batch (any batch shape); returns how many transitions it held."""
        flat = data.reshape(-1)
        n = flat.numel()
        if n == 0:
            return 0
        if self.storage is None:
            self._allocate(flat)
        ids = flat.get(K.MORPH_ID).reshape(n).to("cpu", torch.long)
        if int(ids.min()) < 0 or int(ids.max()) >= self.num_robots:
            raise IndexError(
                f"RobotReplay: morph_id {int(ids.max())} out of range for {self.num_robots} robots"
            )
        # each transition's place in its robot's ring, in collection order within each robot
        order = torch.argsort(ids, stable=True)
        sorted_ids = ids[order]
        counts = torch.bincount(ids, minlength=self.num_robots)
        starts = torch.cumsum(counts, 0) - counts
        rank = torch.arange(n) - starts[sorted_ids]
        keep = rank >= (counts - self.capacity)[sorted_ids]  # more than C new: the last C win
        order, sorted_ids, rank = order[keep], sorted_ids[keep], rank[keep]
        slot = (self.cursor[sorted_ids] + rank) % self.capacity
        dest = (sorted_ids * self.capacity + slot).to(self.device)
        src = order.to(flat.device)
        for key, store in zip(self.keys, self._flat, strict=True):
            store[dest] = flat.get(key).index_select(0, src).to(self.device, store.dtype)
        self.cursor = (self.cursor + counts) % self.capacity
        self.sizes = torch.clamp(self.sizes + counts, max=self.capacity)
        self._sizes_dev = self.sizes.to(self.device)
        return n

    # ------------------------------------------------------------------ sampling
    def _gather(self, index: torch.Tensor, limbs: int | None = None) -> TensorDictBase:
        """The transitions at ``index``; ``limbs``: only the first ``limbs`` limb slots of the
        per-limb keys (:data:`LIMB_KEYS`), gathered from the slots kept (no padding copied)."""

        def cut(k, store: torch.Tensor) -> torch.Tensor:
            if limbs is None or k not in LIMB_KEYS or limbs >= store.shape[1]:
                return store
            return store.narrow(1, 0, limbs)

        return TensorDict(
            {
                k: cut(k, store).index_select(0, index)
                for k, store in zip(self.keys, self._flat, strict=True)
            },
            batch_size=index.shape,
            device=self.device,
        )

    def _check(self, robots: torch.Tensor) -> None:
        if self.storage is None or bool((self.sizes[robots] == 0).any()):
            empty = [int(r) for r in robots if int(self.sizes[r]) == 0]
            raise RuntimeError(f"RobotReplay: nothing stored yet for robot(s) {empty[:5]}")

    def sample_robot(
        self, robot: int, batch_size: int | None = None, limbs: int | None = None
    ) -> TensorDictBase:
        """``batch_size`` transitions of one robot, uniformly with replacement (one randint);
        ``limbs``: cut to the robot's first ``limbs`` limb slots (its own size: the padding
        dropped, see :meth:`gcnt.rl.td3.tensor_chain.TensorChain.robot_batch`)."""
        self._check(torch.tensor([robot]))
        b = batch_size or self.batch_size
        idx = torch.randint(int(self.sizes[robot]), (b,), device=self.device)
        return self._gather(idx + robot * self.capacity, limbs)

    def sample_mixed(self, batch_size: int | None = None) -> TensorDictBase:
        """``batch_size`` transitions of every robot, robot-major, flattened to [R * batch]
        (one ``rand`` and one gather per key)."""
        self._check(torch.arange(self.num_robots))
        b = batch_size or self.batch_size
        sizes = self._sizes_dev
        idx = (torch.rand(self.num_robots, b, device=self.device) * sizes[:, None]).long()
        idx = torch.minimum(idx, (sizes - 1)[:, None])  # rand() * n may round up to n
        return self._gather((idx + self._robot_offset[:, None]).reshape(-1))

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict[str, Any]:
        """The filled part of every ring (slots past the fullest robot's size are left out)."""
        used = int(self.sizes.max()) if self.storage is not None else 0
        data = None
        if self.storage is not None:
            data = {
                "__".join((k,) if isinstance(k, str) else k): self.storage.get(k)[:, :used]
                .to("cpu")
                .clone()
                for k in self.keys
            }
        return {
            "num_robots": self.num_robots,
            "capacity": self.capacity,
            "cursor": self.cursor.clone(),
            "sizes": self.sizes.clone(),
            "data": data,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if state["num_robots"] != self.num_robots or state["capacity"] != self.capacity:
            raise ValueError(
                f"replay checkpoint holds {state['num_robots']} robots x {state['capacity']} "
                f"transitions; this run has {self.num_robots} x {self.capacity}"
            )
        self.cursor, self.sizes = state["cursor"].clone(), state["sizes"].clone()
        self._sizes_dev = self.sizes.to(self.device)
        self.storage, self.keys, self._flat = None, [], []
        if state["data"] is None:
            return
        r, c = self.num_robots, self.capacity
        tensors = {}
        for name, value in state["data"].items():
            key = name if "__" not in name else tuple(name.split("__"))
            full = torch.zeros((r, c, *value.shape[2:]), dtype=value.dtype, device=self.device)
            full[:, : value.shape[1]] = value.to(self.device)
            tensors[key] = full
        self.keys = [k for k in (*STORED_KEYS, *OPTIONAL_KEYS) if k in tensors]
        self.storage = TensorDict(tensors, batch_size=[r, c], device=self.device)
        self._flat = [self.storage.get(k).flatten(0, 1) for k in self.keys]

    def save(self, path: str | Path) -> Path:
        """Write :meth:`state_dict` to ``path`` atomically (a killed save keeps the old file)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        from gcnt.files import save_torch

        save_torch(self.state_dict(), path)
        return path

    def load(self, path: str | Path) -> None:
        """Read :meth:`save`'s file (tensors and plain types only: ``weights_only=True``); an
        unreadable or refused file is a CheckpointError naming it."""
        from gcnt.files import GiB, open_regular
        from gcnt.run.directory import CheckpointError, load_error_detail

        what = "a replay file is what gcnt train writes next to its checkpoint"
        f = open_regular(path, 1024 * GiB, what, CheckpointError)
        try:
            with f:
                state = torch.load(f, map_location="cpu", weights_only=True)
        except Exception as e:  # torch raises many kinds for a truncated or foreign file
            raise CheckpointError(
                f"{path}: not a readable replay checkpoint ({load_error_detail(e)})"
            ) from None
        self.load_state_dict(state)
