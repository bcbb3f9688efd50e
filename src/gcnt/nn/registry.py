"""Build any method's network for any role by name; register new methods.

>>> actor = make_network("gcnt", "td3_actor", table=table, obs_dim=19, num_actions=1)
>>> critic = make_network("gcnt", "td3_critic", table=table, obs_dim=19, num_actions=1)
>>> pi = make_network("modumorph", "ppo_actor", table=table, obs_dim=52, num_actions=2,
...                   preset="unimal", hfield_dim=1410, ppo_std="fixed", ppo_init_std=0.9)

Names: ``gcnt`` and its ablations ``gcnt_no_gcn``, ``gcnt_no_wl``, ``gcnt_no_dist`` (the same as
``gcnt`` with ``use_gcn=False`` etc.), ``gcnt_hn`` (GCNT+HN), ``amorpheus``, ``swat``, ``smp``,
``metamorph``, ``metamorph_star`` (MetaMorph*), ``modumorph``, ``sr`` (= ``mlp``).
Roles: ``td3_actor``, ``td3_critic``, ``ppo_actor``, ``ppo_critic`` (keys in :mod:`gcnt.nn.heads`);
every method builds for every role. Overrides are fields of the method's config dataclass
(:mod:`gcnt.nn.config`); a preset is "smpenv" or "unimal" (the paper's sizes per benchmark).

A new method is one :func:`register_network` call: a config dataclass (a :class:`NetConfig`
subclass) and a builder ``build(cfg, io, table) -> Backbone`` that returns the stages from
``limbs/input`` to ``limbs/out`` (decoder included; ``io`` is a :class:`NetIO` with the input,
output and height-map widths; ``table`` is the robot table for widths such as WL or context)::

    register_network("toy", ToyConfig, build_toy)
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase

from gcnt.envs.robot_table import robot_table
from gcnt.morphology import Robot
from gcnt.nn.baselines import (
    amorpheus_backbone,
    metamorph_backbone,
    mlp_backbone,
    modumorph_backbone,
    smp_backbone,
    swat_backbone,
)
from gcnt.nn.chain import Backbone, NetIO, assemble, io_for
from gcnt.nn.config import (
    AmorpheusConfig,
    GCNTConfig,
    MetaMorphConfig,
    MLPConfig,
    ModuMorphConfig,
    NetConfig,
    SMPConfig,
    SWATConfig,
    unknown_name_error,
)
from gcnt.nn.gcnt import gcnt_backbone
from gcnt.nn.heads import ROLES, check_ppo_std

#: build(cfg, io, table) -> Backbone
Builder = Callable[[Any, NetIO, TensorDictBase], Backbone]


@dataclass(frozen=True)
class NetworkEntry:
    """One registered method: its config class, its builder, and config fields it fixes."""

    config: type[NetConfig]
    build: Builder
    #: config fields this name fixes (an ablation is an entry with a switch off)
    fixed: Mapping[str, Any] = field(default_factory=dict)
    description: str = ""
    #: its input size is fixed by the padded limb count it was built for (SR's flat MLP): it
    #: cannot run robots with more limbs than the table it was trained on
    fixed_limbs: bool = False
    #: its outputs on a robot's real limbs do not depend on how many padded slots follow them
    #: (no per-slot parameters, no dropout): a batch of one robot may run at the robot's own
    #: size (``td3.trim_padding``; tests/test_td3_trim.py checks every built-in that claims it)
    padding_free: bool = False


NETWORKS: dict[str, NetworkEntry] = {}


def register_network(
    name: str,
    config: type[NetConfig],
    build: Builder,
    *,
    fixed: Mapping[str, Any] | None = None,
    description: str = "",
    replace: bool = False,
    fixed_limbs: bool = False,
    padding_free: bool = False,
) -> NetworkEntry:
    """Make method ``name`` available to :func:`make_network` (``replace`` to redefine one).

    ``config`` is a :class:`NetConfig` subclass (its presets give the sizes); ``build(cfg, io,
    table)`` returns the method's :class:`Backbone`; ``fixed`` are config fields the name fixes.
    """
    if not (isinstance(config, type) and issubclass(config, NetConfig)):
        raise TypeError(f"network {name!r}: config must be a NetConfig subclass, got {config!r}")
    if not callable(build):
        raise TypeError(f"network {name!r}: build must be callable, got {build!r}")
    if name in globals().get("BUILTIN_NETWORKS", ()):
        raise ValueError(
            f"network {name!r} is a built-in method and cannot be replaced; register yours under "
            "a name of its own"
        )
    if name in NETWORKS and not replace:
        raise ValueError(f"network {name!r} is already registered (pass replace=True)")
    fixed = dict(fixed or {})
    config.check_overrides(fixed)
    entry = NetworkEntry(config, build, fixed, description, fixed_limbs, padding_free)
    NETWORKS[name] = entry
    return entry


def unregister_network(name: str) -> None:
    """Remove method ``name`` (for tests that register a toy method; not a built-in one)."""
    if name in BUILTIN_NETWORKS:
        raise ValueError(f"network {name!r} is a built-in method and cannot be removed")
    if name not in NETWORKS:
        raise unknown_name_error("network", name, list(NETWORKS))
    del NETWORKS[name]


register_network("gcnt", GCNTConfig, gcnt_backbone, description="GCNT", padding_free=True)
register_network(
    "gcnt_no_gcn", GCNTConfig, gcnt_backbone, fixed={"use_gcn": False}, padding_free=True
)
register_network(
    "gcnt_no_wl", GCNTConfig, gcnt_backbone, fixed={"use_wl": False}, padding_free=True
)
register_network(
    "gcnt_no_dist",
    GCNTConfig,
    gcnt_backbone,
    fixed={"use_dist_bias": False},
    padding_free=True,
)
register_network(
    "gcnt_dist_first",
    GCNTConfig,
    gcnt_backbone,
    fixed={"dist_bias_layers": "first"},
    description="GCNT, distance bias in the first layer only",
    padding_free=True,
)
register_network(
    "gcnt_hn", GCNTConfig, gcnt_backbone, fixed={"hypernet": True}, description="GCNT+HN"
)
register_network(
    "gcnt_gcn_context",
    GCNTConfig,
    gcnt_backbone,
    fixed={"gcn_input": "context"},
    description="GCNT, GCN on the limb context",
)
register_network(
    "amorpheus", AmorpheusConfig, amorpheus_backbone, description="AMORPHEUS", padding_free=True
)
register_network("swat", SWATConfig, swat_backbone, description="SWAT")
register_network("smp", SMPConfig, smp_backbone, description="SMP", padding_free=True)
register_network("metamorph", MetaMorphConfig, metamorph_backbone, description="MetaMorph")
register_network(
    "metamorph_star",
    MetaMorphConfig,
    metamorph_backbone,
    fixed={"position_embedding": False, "embed_dropout": 0.0},
    description="MetaMorph*",
    padding_free=True,
)
register_network("modumorph", ModuMorphConfig, modumorph_backbone, description="ModuMorph")
register_network(
    "sr", MLPConfig, mlp_backbone, description="SR (one MLP per robot)", fixed_limbs=True
)
register_network(
    "mlp", MLPConfig, mlp_backbone, description="SR (one MLP per robot)", fixed_limbs=True
)
#: the methods gcnt defines: never replaced (a plugin's method has a name of its own, so that its
#: runs are never shown or averaged as a built-in method's)
BUILTIN_NETWORKS = frozenset(NETWORKS)


def make_config(name: str, preset: str = "smpenv", **overrides: Any) -> NetConfig:
    """The config of method ``name`` at ``preset`` sizes with ``overrides``."""
    if name not in NETWORKS:
        raise unknown_name_error("network", name, list(NETWORKS))
    entry = NETWORKS[name]
    for key, value in entry.fixed.items():
        if key in overrides and overrides[key] != value:
            raise ValueError(f"network {name!r} fixes {key}={value}; got {key}={overrides[key]}")
    return entry.config.preset(preset, **{**overrides, **entry.fixed})


def shared_sizes(name: str, kwargs: Mapping[str, Any]) -> dict[str, Any]:
    """What a recipe's shared sizes (``network.kwargs``) give method ``name``: all of them
    where its config has every one; none where its config has none of them and each is a field
    of another method's config (sizes of another family of methods, e.g. the Transformers'
    ``d_model``: the method runs at its preset's sizes); otherwise a ValueError naming the
    override that gives the method sizes of its own."""
    kwargs = dict(kwargs)
    if not kwargs or name not in NETWORKS:
        return kwargs
    config = NETWORKS[name].config
    fields = config.field_names()
    missing = [k for k in kwargs if k not in fields]
    if not missing:
        return kwargs
    elsewhere = {f for entry in NETWORKS.values() for f in entry.config.field_names()}
    if len(missing) == len(kwargs) and all(k in elsewhere for k in missing):
        return {}
    unknown = [k for k in missing if k not in elsewhere]
    if unknown:  # a field of no method: a typo, named with the closest fields
        config.check_overrides({k: None for k in unknown})
    raise ValueError(
        f"network.kwargs sets {', '.join(missing)}, not fields of {config.__name__} (method "
        f"{name!r}; its fields: {', '.join(fields)}): give {name} sizes of its own, e.g. "
        f"network.method_kwargs.{name}={{}} for its preset's"
    )


def make_network(
    name: str,
    role: str,
    *,
    table: TensorDictBase | Sequence[Robot],
    obs_dim: int,
    num_actions: int,
    preset: str = "smpenv",
    keep_intermediates: bool = False,
    robot_names: Sequence[str] | None = None,
    pad_limbs: int | None = None,
    hfield_dim: int = 0,
    decoder_hidden: Sequence[int] | None = None,
    ppo_std: str = "fixed",
    ppo_init_std: float = 0.9,
    **overrides: Any,
) -> TensorDictModuleBase:
    """Build method ``name`` for ``role`` over the robots of ``table``.

    Args:
        name: a key of :data:`NETWORKS`.
        role: one of "td3_actor", "td3_critic", "ppo_actor", "ppo_critic".
        table: the padded robot table (``robot_table(...)``), or a list of Robots (then the table
            is built here, padded to ``pad_limbs`` (default: the largest robot), and the robots'
            names are kept for error messages).
        obs_dim: F, the per-limb observation width; num_actions: A, action slots per limb.
        preset: "smpenv" or "unimal" sizes.
        keep_intermediates: keep intermediate keys (embeddings, GCN output, ...) in the output.
        hfield_dim: width of the root key ``hfield`` (UNIMAL MT / Obstacles: 1410), or 0 for no
            height map. It is encoded by an MLP H → 64 → 64 and joined to every limb's features
            before the decoder: [features ‖ 64] → decoder_hidden → out.
        decoder_hidden: the limb decoder's hidden widths (the world's: UNIMAL MT [64], Obstacles
            [64, 64], FT and Incline none); None: [64] with a height map, none without.
        ppo_std, ppo_init_std: the PPO actor's Gaussian std: "fixed" (not trained) at
            ``ppo_init_std``, or "learned" (a state-independent log-std per action slot starting
            at ``ppo_init_std``). Ignored by the other roles.
        **overrides: config fields (e.g. ``layers=1``, ``use_gcn=False``).

    Returns a ``TensorDictSequential`` starting with a ``GraphLookup`` (named stages:
    ``chain["lookup"]``, ``chain["gcn"]``...), or for ``ppo_actor`` a ``ProbabilisticActor``
    around one. Its in_keys are ``morph_id``, ``limbs/obs`` (+ ``limbs/action`` for td3_critic,
    + ``hfield`` if ``hfield_dim``).
    """
    if role not in ROLES:
        raise unknown_name_error("role", role, ROLES)
    if not (isinstance(hfield_dim, int) and hfield_dim >= 0):
        raise ValueError(f"hfield_dim must be an int >= 0, got {hfield_dim!r}")
    check_ppo_std(ppo_std, ppo_init_std)
    cfg = make_config(name, preset, **overrides)
    if not isinstance(table, TensorDictBase):
        robots = list(table)
        robot_names = robot_names or [r.name for r in robots]
        table = robot_table(robots, pad_limbs, num_actions)
    io = io_for(role, obs_dim, num_actions, hfield_dim, decoder_hidden)
    backbone = NETWORKS[name].build(cfg, io, table)
    return assemble(
        backbone,
        role,
        table,
        num_actions,
        hfield_dim=hfield_dim,
        ppo_std=ppo_std,
        ppo_init_std=ppo_init_std,
        robot_names=robot_names,
        keep_intermediates=keep_intermediates,
    )


def count_parameters(module) -> int:
    """Trainable and frozen parameters of ``module`` (the robot table is buffers: not counted)."""
    return sum(p.numel() for p in module.parameters())
