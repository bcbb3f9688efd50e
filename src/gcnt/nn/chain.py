"""Assemble a method's backbone into a full policy/value chain for one role.

A chain is a ``TensorDictSequential`` of named stages::

    lookup (GraphLookup) → input (obs, or obs ‖ masked action) → <backbone stages> → head → output

wrapped in a ``ProbabilisticActor`` for ``ppo_actor``. Its ``in_keys`` are ``morph_id``,
``limbs/obs`` (and ``limbs/action`` for a TD3 critic); intermediate keys are dropped from the
output unless ``keep_intermediates=True``.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass, field

from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase, TensorDictSequential

from gcnt.nn import keys as K
from gcnt.nn.graph_lookup import GraphLookup
from gcnt.nn.heads import final_keys, probabilistic_actor, role_output
from gcnt.nn.stages import input_stage


class Chain(TensorDictSequential):
    """A ``TensorDictSequential`` of named stages that can also be indexed by position:
    ``chain["gcn"]`` or ``chain[0]`` (the GraphLookup)."""

    def __getitem__(self, index):
        if isinstance(index, int):
            return list(self.module.values())[index]
        if isinstance(index, slice):
            return TensorDictSequential(*list(self.module.values())[index])
        return self.module[index]


@dataclass
class Backbone:
    """A method's stages from ``limbs/input`` to ``limbs/out`` (head included)."""

    stages: list[tuple[str, TensorDictModuleBase]]
    #: static keys the stages read (limbs/mask and limbs/action_mask are always looked up)
    static_keys: tuple = ()
    #: the most limbs the method supports (None: any)
    max_limbs: int | None = None
    #: extra names for the GraphLookup error messages
    name: str = "model"
    notes: dict = field(default_factory=dict)


def assemble(
    backbone: Backbone,
    role: str,
    table: TensorDictBase,
    num_actions: int,
    *,
    ppo_std: str = "fixed",
    ppo_init_std: float = 0.9,
    robot_names: Sequence[str] | None = None,
    keep_intermediates: bool = False,
) -> TensorDictModuleBase:
    static = [K.MASK, K.ACTION_MASK] + [
        k for k in backbone.static_keys if k not in (K.MASK, K.ACTION_MASK)
    ]
    lookup = GraphLookup(
        table, static, max_limbs=backbone.max_limbs, owner=backbone.name, robot_names=robot_names
    )
    stages: OrderedDict[str, TensorDictModuleBase] = OrderedDict()
    stages["lookup"] = lookup
    stages["input"] = input_stage(critic=role == "td3_critic")
    for name, st in backbone.stages:
        stages[name] = st
    stages["output"] = role_output(role, num_actions, ppo_std, ppo_init_std)
    selected = None if keep_intermediates else final_keys(role)
    seq = Chain(stages, selected_out_keys=selected)
    if role == "ppo_actor":
        return probabilistic_actor(seq)
    return seq


def graph_lookup_of(chain: TensorDictModuleBase) -> GraphLookup:
    """The GraphLookup at the head of a chain built by :func:`assemble` (for ``set_table``)."""
    for m in chain.modules():
        if isinstance(m, GraphLookup):
            return m
    raise ValueError("no GraphLookup in this module")
