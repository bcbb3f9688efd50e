"""Assemble a method's backbone into a full policy/value chain for one role.

A chain is a ``TensorDictSequential`` of named stages::

    lookup (GraphLookup) → input (obs, or obs ‖ masked action) [→ hfield (height-map MLP)]
      → <backbone stages, ending with the decoder writing limbs/out> → output (role)

wrapped in a ``ProbabilisticActor`` for ``ppo_actor``. Its ``in_keys`` are ``morph_id``,
``limbs/obs`` (and ``limbs/action`` for a TD3 critic, ``hfield`` on height-map worlds);
intermediate keys are dropped from the output unless ``keep_intermediates=True``.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass, field

from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase, TensorDictSequential

from gcnt import keys as K
from gcnt.nn.graph_lookup import GraphLookup
from gcnt.nn.heads import final_keys, probabilistic_actor, role_output
from gcnt.nn.stages import DECODER_HIDDEN, HFIELD_WIDTH, hfield_stage, input_stage


class Chain(TensorDictSequential):
    """A ``TensorDictSequential`` of named stages that can also be indexed by position:
    ``chain["gcn"]`` or ``chain[0]`` (the GraphLookup)."""

    def __getitem__(self, index):
        if isinstance(index, int):
            return list(self.module.values())[index]
        if isinstance(index, slice):
            return TensorDictSequential(*list(self.module.values())[index])
        return self.module[index]


@dataclass(frozen=True)
class NetIO:
    """The widths a method's builder sizes its stages for."""

    #: width of ``limbs/input``: F (actors, PPO critic) or F + A (TD3 critic)
    in_dim: int
    #: width of ``limbs/out`` per limb: A (actors) or 1 (critics)
    out_dim: int
    #: width of the encoded height map ``hfield_embed`` the decoder must join to every limb's
    #: features (0: no height map). Pass it to ``limb_head_stage(..., hfield_width=...)``.
    hfield_width: int = 0
    #: width A of the limb action at the end of ``limbs/input`` (TD3 critics; 0 otherwise)
    action_dim: int = 0
    #: hidden widths of the limb decoder (the originals' ``DECODER_DIMS``). Pass it to
    #: ``limb_head_stage(..., hidden=...)``.
    decoder_hidden: tuple[int, ...] = ()


@dataclass
class Backbone:
    """A method's stages from ``limbs/input`` to ``limbs/out`` (decoder included)."""

    stages: list[tuple[str, TensorDictModuleBase]]
    #: static keys the stages read (limbs/mask and limbs/action_mask are always looked up)
    static_keys: tuple = ()
    #: the most limbs the method supports (None: any)
    max_limbs: int | None = None
    #: the method's name in error messages
    name: str = "model"
    #: static key -> (bound, setting): the table's values of that key must stay below the
    #: bound (e.g. limb type ids below ``num_limb_types``), checked once per robot table
    limits: dict = field(default_factory=dict)


def assemble(
    backbone: Backbone,
    role: str,
    table: TensorDictBase,
    num_actions: int,
    *,
    hfield_dim: int = 0,
    ppo_std: str = "fixed",
    ppo_init_std: float = 0.9,
    robot_names: Sequence[str] | None = None,
    keep_intermediates: bool = False,
) -> TensorDictModuleBase:
    """The full chain of ``backbone`` for ``role``: graph lookup, input, height-map encoder (if
    ``hfield_dim``), the backbone's stages, the role output."""
    static = [K.MASK, K.ACTION_MASK] + [
        k for k in backbone.static_keys if k not in (K.MASK, K.ACTION_MASK)
    ]
    if hfield_dim and not any(K.HFIELD_EMBED in st.in_keys for _, st in backbone.stages):
        raise ValueError(
            f"{backbone.name} does not read the height map: its builder must pass "
            f"NetIO.hfield_width to its decoder (limb_head_stage(..., hfield_width=...))"
        )
    lookup = GraphLookup(
        table,
        static,
        max_limbs=backbone.max_limbs,
        owner=backbone.name,
        robot_names=robot_names,
        limits=backbone.limits,
    )
    stages: OrderedDict[str, TensorDictModuleBase] = OrderedDict()
    stages["lookup"] = lookup
    stages["input"] = input_stage(critic=role == "td3_critic")
    if hfield_dim:
        stages["hfield"] = hfield_stage(hfield_dim)
    for name, st in backbone.stages:
        stages[name] = st
    stages["output"] = role_output(role, num_actions, ppo_std, ppo_init_std)
    selected = None if keep_intermediates else final_keys(role)
    seq = Chain(stages, selected_out_keys=selected)
    if role == "ppo_actor":
        return probabilistic_actor(seq)
    return seq


def io_for(
    role: str,
    obs_dim: int,
    num_actions: int,
    hfield_dim: int,
    decoder_hidden: Sequence[int] | None = None,
) -> NetIO:
    """The widths of ``role``'s backbone (TD3 critics read obs ‖ action); ``decoder_hidden``
    None: one hidden layer of :data:`DECODER_HIDDEN` with a height map, none without."""
    in_dim = obs_dim + (num_actions if role == "td3_critic" else 0)
    out_dim = num_actions if role in ("td3_actor", "ppo_actor") else 1
    action_dim = num_actions if role == "td3_critic" else 0
    if decoder_hidden is None:
        decoder_hidden = (DECODER_HIDDEN,) if hfield_dim else ()
    hidden = tuple(int(w) for w in decoder_hidden)
    return NetIO(in_dim, out_dim, HFIELD_WIDTH if hfield_dim else 0, action_dim, hidden)


def graph_lookup_of(chain: TensorDictModuleBase) -> GraphLookup:
    """The GraphLookup at the head of a chain built by :func:`assemble` (for ``set_table``)."""
    for m in chain.modules():
        if isinstance(m, GraphLookup):
            return m
    raise ValueError("no GraphLookup in this module")
