"""Run a policy chain on plain tensors: the learner's fast path through the same modules.

A chain (``gcnt.nn.chain``) is a ``TensorDictSequential`` of ``TensorDictModule`` stages. Inside
a learner's update, each TensorDict call costs more than the small networks' arithmetic (tensordict
wraps every output, checks keys, ...). :class:`TensorChain` walks the same stages once, at build
time, and then calls each stage's torch module directly on a dict of tensors keyed like the
TensorDict. The parameters are the chain's own (no copy), so an optimiser over the chain's
parameters trains both, and the collector keeps running the TensorDict chain.

Stages whose inputs depend only on the robot (the GraphLookup's static keys, or outputs of other
such stages: GCNT's GCN and distance bias, SWAT's relational bias, ModuMorph's context MLPs) are
computed once per robot of the table and gathered by ``morph_id`` where a per-sample stage reads
them: the same values, gradients summed over the robot's samples, at a fraction of the cost. A
stage with active dropout is never hoisted. Anything that is not a plain ``TensorDictModule``
runs through its TensorDict call (correct, just not faster).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModule, TensorDictModuleBase, TensorDictSequential
from torch import Tensor, nn

from gcnt.envs.robot_table import trim_rows, trim_table
from gcnt.keys import MORPH_ID
from gcnt.nn.graph_lookup import GraphLookup
from gcnt.nn.graph_lookup import buffer_name as table_buffer_name

Key = str | tuple[str, ...]


def _key(key) -> Key:
    return key if isinstance(key, str) else (key[0] if len(key) == 1 else tuple(key))


@dataclass
class _Stage:
    module: TensorDictModuleBase
    in_keys: list[Key]
    out_keys: list[Key]
    #: call ``module.module(*tensors)`` (a plain TensorDictModule) rather than the TD call
    plain: bool
    #: every input depends only on the robot: computed on the table's R rows
    per_robot: bool


def _stages(module: TensorDictModuleBase) -> list[TensorDictModuleBase]:
    if isinstance(module, TensorDictSequential):
        out = []
        inner = module.module
        for m in inner.values() if isinstance(inner, nn.ModuleDict) else inner:
            out += _stages(m)
        return out
    return [module]


def has_dropout(module: nn.Module) -> bool:
    for m in module.modules():
        if isinstance(m, nn.modules.dropout._DropoutNd) and m.p > 0:
            return True
        if getattr(m, "dropout", 0) not in (0, 0.0, None) and isinstance(m.dropout, float):
            return True
    return False


class RobotBatch:
    """Per-batch context shared by every chain call of one update: the sample's ``morph_id``, the
    robot table (per-robot rows) and the per-sample gathers already made."""

    def __init__(self, table: Mapping[Key, Tensor], ids: Tensor) -> None:
        self.table = dict(table)
        device = next(iter(self.table.values())).device if self.table else ids.device
        # the table lives with the networks; ids read from a CPU batch follow it there
        self.ids = ids if ids.device == device else ids.to(device)
        self._gathered: dict[Key, Tensor] = {}

    def gathered(self, key: Key) -> Tensor:
        out = self._gathered.get(key)
        if out is None:
            out = self.table[key].index_select(0, self.ids)
            self._gathered[key] = out
        return out


class TensorChain:
    """``chain`` as a function of a dict of tensors (see the module docstring).

    ``chain(inputs, robots)`` returns a dict holding the inputs and every key the stages wrote;
    ``inputs`` holds the per-sample keys (``limbs/obs``, for critics ``limbs/action``, ``hfield``),
    ``robots`` the :class:`RobotBatch` of the batch (from :meth:`robot_batch`).
    """

    def __init__(self, chain: TensorDictModuleBase) -> None:
        self.chain = chain
        self.lookup: GraphLookup | None = None
        self.stages: list[_Stage] = []
        static: set[Key] = set()
        for st in _stages(chain):
            if isinstance(st, GraphLookup):
                if self.lookup is not None:
                    raise ValueError("TensorChain: a chain with two GraphLookups")
                self.lookup = st
                static |= {_key(k) for k in st.keys}
                continue
            in_keys = [_key(k) for k in st.in_keys]
            out_keys = [_key(k) for k in st.out_keys]
            plain = (
                type(st) is TensorDictModule
                and getattr(st, "_kwargs", None) is None
                and getattr(st, "method", None) is None
                and not getattr(st, "method_kwargs", None)
            )
            per_robot = (
                plain
                and bool(in_keys)
                and all(k in static for k in in_keys)
                and not has_dropout(st)
            )
            if per_robot:
                static |= set(out_keys)
            else:
                static -= set(out_keys)
            self.stages.append(_Stage(st, in_keys, out_keys, plain, per_robot))
        if self.lookup is None:
            raise ValueError("TensorChain: the chain has no GraphLookup at its head")
        self.table_keys: list[Key] = [_key(k) for k in self.lookup.keys]
        self._table_buffers = [(_key(k), table_buffer_name(k)) for k in self.lookup.keys]

    def table(self) -> dict[Key, Tensor]:
        """The lookup's robot table, per robot: its buffers, read at each call so that they
        follow the module's ``.to()`` and ``set_table`` (no TensorDict built: compile-friendly)."""
        return {k: getattr(self.lookup, name) for k, name in self._table_buffers}

    def robot_batch(
        self, ids: Tensor, *others: TensorChain, limbs: int | None = None
    ) -> RobotBatch:
        """The :class:`RobotBatch` of samples with robots ``ids``, for this chain and ``others``
        (the union of their tables: chains of one method and robot set share them).

        ``limbs``: the samples' limb slots, when fewer than the table's (a batch cut to its
        robots' own size, :meth:`gcnt.rl.td3.replay.RobotReplay.sample_robot`): the table is
        cut to match (:func:`~gcnt.envs.robot_table.trim_table`); every robot of ``ids`` must
        have at most ``limbs`` limbs."""
        table = self.table()
        for other in others:
            for k, v in other.table().items():
                table.setdefault(k, v)
        if limbs is not None and limbs < self.lookup.num_limbs:
            rows = trim_rows(self.lookup.limb_counts, limbs)
            if rows is None:
                raise ValueError(
                    f"TensorChain: samples of {limbs} limb slots, but every robot of the table "
                    f"has more ({self.lookup.limb_counts})"
                )
            table = trim_table(table, rows, limbs)
        return RobotBatch(table, ids.reshape(-1).long())

    def __call__(self, inputs: Mapping[Key, Tensor], robots: RobotBatch) -> dict[Key, Tensor]:
        env: dict[Key, Tensor] = dict(inputs)  # per-sample tensors
        per_robot: dict[Key, Tensor] = {}  # outputs of per-robot stages, [R, ...]

        def get(k: Key) -> Tensor:
            v = env.get(k)
            if v is not None:
                return v
            if k in per_robot:
                v = per_robot[k].index_select(0, robots.ids)
                env[k] = v
                return v
            if k in robots.table:
                v = robots.gathered(k)
                env[k] = v
                return v
            raise KeyError(f"TensorChain: no input {k!r} for {type(self.chain).__name__}")

        for st in self.stages:
            if st.per_robot:
                args = [per_robot.get(k, robots.table.get(k)) for k in st.in_keys]
                out = st.module.module(*args)
                dest = per_robot
            elif st.plain:
                out = st.module.module(*[get(k) for k in st.in_keys])
                dest = env
            else:  # anything else: its own TensorDict call
                td = TensorDict(
                    {k: get(k) for k in st.in_keys},
                    batch_size=robots.ids.shape,
                    device=robots.ids.device,
                )
                td = st.module(td)
                for k in st.out_keys:
                    env[k] = td.get(k)
                continue
            if len(st.out_keys) == 1:
                dest[st.out_keys[0]] = out if isinstance(out, Tensor) else out[0]
            else:
                for k, v in zip(st.out_keys, out, strict=True):
                    dest[k] = v
        return env


class TensorChainModule(TensorDictModuleBase):
    """A chain as a TensorDictModule that runs :class:`TensorChain` inside: the same inputs and
    outputs as the chain (its final keys), the same parameters, a fraction of the call cost. For
    the collector's and the evaluator's policy calls, which run every environment step.

    Args:
        chain: the chain (a TensorDictSequential starting with its GraphLookup).
        out_keys: the keys to write back (e.g. ``[("limbs", "action")]``).
    """

    def __init__(self, chain: TensorDictModuleBase, out_keys: list) -> None:
        super().__init__()
        self.chain = chain
        self.fn = TensorChain(chain)
        table = set(self.fn.table_keys)
        self.inputs = [
            _key(k) for k in chain.in_keys if _key(k) != MORPH_ID and _key(k) not in table
        ]
        self.in_keys = [MORPH_ID, *self.inputs]
        self.out_keys = [_key(k) for k in out_keys]

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        ids = tensordict.get(MORPH_ID)
        lead = tensordict.batch_size
        robots = self.fn.robot_batch(ids)
        n = robots.ids.shape[0]
        inputs = {}
        for k in self.inputs:
            v = tensordict.get(k, None)
            if v is not None:
                inputs[k] = v.reshape(n, *v.shape[len(lead) :])
        out = self.fn(inputs, robots)
        for k in self.out_keys:
            v = out[k]
            tensordict.set(k, v.reshape(*lead, *v.shape[1:]))
        return tensordict
