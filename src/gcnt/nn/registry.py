"""Build any method's network for any role by name.

>>> actor = make_network("gcnt", "td3_actor", table=table, obs_dim=19, num_actions=1)
>>> critics = make_td3_critics("gcnt", table=table, obs_dim=19, num_actions=1)  # twin, independent
>>> loss = TD3Loss(actor, critics, num_qvalue_nets=2, bounds=(-1, 1), deactivate_vmap=True)

Names: ``gcnt``, ``gcnt_no_gcn``, ``gcnt_no_wl``, ``gcnt_no_dist`` (ablations; the same as
``gcnt`` with ``use_gcn=False`` etc.), ``amorpheus``, ``swat``, ``smp``, ``mlp``.
Roles: ``td3_actor``, ``td3_critic``, ``ppo_actor``, ``ppo_critic`` (keys in :mod:`gcnt.nn.heads`).
Overrides are fields of the method's config dataclass (:mod:`gcnt.nn.config`); a preset is
"smpenv" (paper appendix table 1) or "unimal" (table 3).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase

from gcnt.envs.robot_table import robot_table
from gcnt.morphology import Robot
from gcnt.nn import keys as K
from gcnt.nn.baselines import amorpheus_backbone, mlp_backbone, smp_backbone, swat_backbone
from gcnt.nn.chain import Backbone, assemble
from gcnt.nn.config import (
    AmorpheusConfig,
    GCNTConfig,
    MLPConfig,
    NetConfig,
    SMPConfig,
    SWATConfig,
    unknown_name_error,
)
from gcnt.nn.gcnt import gcnt_backbone
from gcnt.nn.heads import ROLES, head_out_dim

#: name -> (config class, fixed overrides)
NETWORKS: dict[str, tuple[type[NetConfig], dict[str, Any]]] = {
    "gcnt": (GCNTConfig, {}),
    "gcnt_no_gcn": (GCNTConfig, {"use_gcn": False}),
    "gcnt_no_wl": (GCNTConfig, {"use_wl": False}),
    "gcnt_no_dist": (GCNTConfig, {"use_dist_bias": False}),
    "amorpheus": (AmorpheusConfig, {}),
    "swat": (SWATConfig, {}),
    "smp": (SMPConfig, {}),
    "mlp": (MLPConfig, {}),
}


def make_config(name: str, preset: str = "smpenv", **overrides: Any) -> NetConfig:
    """The config of method ``name`` at ``preset`` sizes with ``overrides``."""
    if name not in NETWORKS:
        raise unknown_name_error("network", name, list(NETWORKS))
    cls, fixed = NETWORKS[name]
    for key, value in fixed.items():
        if key in overrides and overrides[key] != value:
            raise ValueError(f"network {name!r} fixes {key}={value}; got {key}={overrides[key]}")
    return cls.preset(preset, **{**overrides, **fixed})


def _backbone(name: str, cfg: NetConfig, in_dim: int, out_dim: int, table) -> Backbone:
    if isinstance(cfg, GCNTConfig):
        return gcnt_backbone(cfg, in_dim, out_dim, table.get(K.WL).shape[-1])
    if isinstance(cfg, SWATConfig):
        return swat_backbone(cfg, in_dim, out_dim)
    if isinstance(cfg, AmorpheusConfig):
        return amorpheus_backbone(cfg, in_dim, out_dim)
    if isinstance(cfg, SMPConfig):
        return smp_backbone(cfg, in_dim, out_dim)
    if isinstance(cfg, MLPConfig):
        return mlp_backbone(cfg, in_dim, out_dim, table.get(K.MASK).shape[-1])
    raise ValueError(f"no backbone for {name!r}")  # pragma: no cover


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
    **overrides: Any,
) -> TensorDictModuleBase:
    """Build method ``name`` for ``role`` over the robots of ``table``.

    Args:
        name: a key of :data:`NETWORKS`.
        role: one of "td3_actor", "td3_critic", "ppo_actor", "ppo_critic".
        table: the padded robot table (``robot_table(...)``), or a list of Robots (then the table
            is built here, padded to ``pad_limbs`` (default: the largest robot), and the robots' names are kept for
            error messages).
        obs_dim: F, the per-limb observation width; num_actions: A, action slots per limb.
        preset: "smpenv" or "unimal" sizes.
        keep_intermediates: keep intermediate keys (embeddings, GCN output, ...) in the output.
        **overrides: config fields (e.g. ``layers=1``, ``use_gcn=False``, ``ppo_std="learned"``).

    Returns a ``TensorDictSequential`` starting with a ``GraphLookup`` (named stages:
    ``chain["lookup"]``, ``chain["gcn"]``...), or for ``ppo_actor`` a ``ProbabilisticActor``
    around one. Its in_keys are ``morph_id``, ``limbs/obs`` (+ ``limbs/action`` for td3_critic).
    """
    if role not in ROLES:
        raise unknown_name_error("role", role, ROLES)
    cfg = make_config(name, preset, **overrides)
    if not isinstance(table, TensorDictBase):
        robots = list(table)
        robot_names = robot_names or [r.name for r in robots]
        table = robot_table(robots, pad_limbs, num_actions)
    in_dim = obs_dim + (num_actions if role == "td3_critic" else 0)
    backbone = _backbone(name, cfg, in_dim, head_out_dim(role, num_actions), table)
    return assemble(
        backbone,
        role,
        table,
        num_actions,
        ppo_std=cfg.ppo_std,
        ppo_init_std=cfg.ppo_init_std,
        robot_names=robot_names,
        keep_intermediates=keep_intermediates,
    )


def make_td3_critics(name: str, *, num: int = 2, **kwargs: Any) -> list[TensorDictModuleBase]:
    """``num`` independently initialised TD3 critics, for ``TD3Loss(actor, critics, ...)``.

    Given a single qvalue network, TD3Loss makes the twins itself by expanding its parameters and
    re-drawing every tensor uniformly between its min and max (LayerNorm weights stay 1, but no
    layer keeps its own init scheme); passing a list uses these modules' own initialisations.
    """
    return [make_network(name, "td3_critic", **kwargs) for _ in range(num)]


def count_parameters(module) -> int:
    return sum(p.numel() for p in module.parameters())
