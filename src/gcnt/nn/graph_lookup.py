"""Restore a robot's static tensors (mask, types, graph) from its ``morph_id``.

Every policy chain starts with a :class:`GraphLookup`, so the same chain runs on env output (which
carries the static keys already) and on replay-buffer samples (which store only ``morph_id`` and
the per-step data). The table is held as *non-persistent* buffers: it follows ``.to(device)`` but
is not part of the state dict, so a checkpoint trained on one robot set loads into a network built
for another (zero-shot evaluation), and :meth:`GraphLookup.set_table` swaps the robot set in place.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModuleBase

from gcnt import keys as K
from gcnt.envs.robot_table import STATIC_KEYS, RobotTooLargeError

_BUFFER_PREFIX = "table_"


def buffer_name(key: tuple[str, str]) -> str:
    return _BUFFER_PREFIX + "__".join(key)


def is_table_key(state_dict_key: str) -> bool:
    """True for a state-dict entry that holds robot-table data (static, not learnt)."""
    return state_dict_key.rsplit(".", 1)[-1].startswith(_BUFFER_PREFIX)


class GraphLookup(TensorDictModuleBase):
    """Write the static keys of each sample's robot, gathered from the robot table by ``morph_id``.

    Args:
        table: the padded robot table (``gcnt.envs.robot_table.robot_table``), batch [R].
        keys: the static keys to write (default: all of :data:`STATIC_KEYS` present in the table).
            A chain asks only for what it reads.
        max_limbs: the most limbs the model downstream can handle (e.g. SWAT's position tables);
            a table with a larger robot raises :class:`RobotTooLargeError` naming it.
        owner: model name used in error messages.
        robot_names: names of the table's robots (by morph_id), for error messages.
        limits: static key -> (bound, setting name): every value of that key in a table must
            be below the bound (e.g. limb type ids below the GCN's ``num_limb_types``); read on
            the host once per table, so no forward reads a tensor's value.

    Reads ``morph_id`` [*B] (a trailing singleton dim is accepted); writes each key as
    ``table[key][morph_id]``, overwriting what the input had (the env emits the same values).
    """

    def __init__(
        self,
        table: TensorDictBase,
        keys: Sequence[tuple[str, str]] | None = None,
        *,
        max_limbs: int | None = None,
        owner: str = "model",
        robot_names: Sequence[str] | None = None,
        limits: Mapping[tuple[str, str], tuple[int, str]] | None = None,
    ) -> None:
        super().__init__()
        self.limits = dict(limits or {})
        self.keys = (
            tuple(keys)
            if keys is not None
            else tuple(k for k in STATIC_KEYS if k in table.keys(True, True))
        )
        unknown = [k for k in self.keys if k not in STATIC_KEYS]
        if unknown:
            raise ValueError(f"GraphLookup: unknown static keys {unknown}; known: {STATIC_KEYS}")
        self.in_keys = [K.MORPH_ID]
        self.out_keys = list(self.keys)
        self.max_limbs = max_limbs
        self.owner = owner
        self.robot_names: tuple[str, ...] | None = None
        self.num_robots = 0
        self.num_limbs = 0
        #: each robot's real limbs (read on the host once per table)
        self.limb_counts: tuple[int, ...] = ()
        self.set_table(table, robot_names=robot_names)

    def set_table(
        self, table: TensorDictBase, robot_names: Sequence[str] | None = None
    ) -> GraphLookup:
        """Swap the robot table (e.g. for zero-shot evaluation on other robots); keeps the device."""
        missing = [k for k in self.keys if k not in table.keys(True, True)]
        if missing:
            raise KeyError(f"{self.owner}: the robot table lacks the static keys {missing}")
        if table.batch_dims != 1:
            raise ValueError(
                f"GraphLookup: robot table must have batch [R], got {table.batch_size}"
            )
        mask = table.get(K.MASK)
        if robot_names is not None and len(robot_names) != mask.shape[0]:
            raise ValueError(
                f"GraphLookup: {len(robot_names)} robot names for a table of {mask.shape[0]} robots"
            )
        sizes = mask.sum(-1)
        if self.max_limbs is not None and int(sizes.max()) > self.max_limbs:
            i = int(sizes.argmax())
            who = f"robot {robot_names[i]!r}" if robot_names is not None else f"robot morph_id={i}"
            raise RobotTooLargeError(
                f"{who} has {int(sizes[i])} limbs; {self.owner} allows at most {self.max_limbs} "
                "(raise its max_limbs)"
            )
        for key, (bound, setting) in self.limits.items():
            values = table.get(key, None)
            if values is not None and values.numel() and int(values.max()) >= bound:
                raise ValueError(
                    f"{self.owner}: the robot table's {'/'.join(key)} holds {int(values.max())}, "
                    f"past {setting}={bound} (ids 0..{bound - 1})"
                )
        device = self._device()
        for key in self.keys:
            value = table.get(key).to(device)
            old = getattr(self, buffer_name(key), None)
            if old is not None and old.is_floating_point() and value.is_floating_point():
                value = value.to(old.dtype)  # keep a .double() / .half() of the module
            # non-persistent: the table is not part of the state dict
            self.register_buffer(buffer_name(key), value, persistent=False)
        self.robot_names = tuple(robot_names) if robot_names is not None else None
        self.num_robots = int(mask.shape[0])
        self.num_limbs = int(mask.shape[-1])
        self.limb_counts = tuple(int(s) for s in sizes)
        return self

    def _device(self) -> torch.device:
        for b in self.buffers():
            return b.device
        return torch.device("cpu")

    def table(self) -> TensorDict:
        """The current table (only the keys this lookup serves)."""
        out = TensorDict({}, batch_size=[self.num_robots])
        for key in self.keys:
            out.set(key, getattr(self, buffer_name(key)))
        return out

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        ids = tensordict.get(K.MORPH_ID)
        if ids.dim() == tensordict.batch_dims + 1 and ids.shape[-1] == 1:
            ids = ids.squeeze(-1)
        ids = ids.long()
        obs = tensordict.get(K.OBS, None)
        if obs is not None and obs.shape[-2] != self.num_limbs:
            raise ValueError(
                f"{self.owner}: observations have {obs.shape[-2]} limb slots but the robot table "
                f"is padded to {self.num_limbs}; build the table with max_limbs={obs.shape[-2]}"
            )
        # the range is read on the host where that is free: a CPU tensor, not under vmap (a
        # torchrl loss may vmap the chain over its critics) nor while compiling
        if (
            ids.device.type == "cpu"
            and ids.numel()
            and not torch._C._functorch.is_batchedtensor(ids)
            and not torch.compiler.is_compiling()
            and int(ids.max()) >= self.num_robots
        ):
            raise IndexError(
                f"{self.owner}: morph_id {int(ids.max())} out of range for a table of "
                f"{self.num_robots} robots"
            )
        for key in self.keys:
            tensordict.set(key, getattr(self, buffer_name(key))[ids])
        return tensordict

    def extra_repr(self) -> str:
        return f"robots={self.num_robots}, limbs={self.num_limbs}, keys={list(self.keys)}"
