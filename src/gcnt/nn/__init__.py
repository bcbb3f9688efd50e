"""GCNT and the baselines as chains of TensorDictModules (one stage each).

Start with :func:`make_network`; add a method with :func:`register_network`. The stages live in
:mod:`gcnt.nn.stages`, the shared layers in :mod:`gcnt.nn.layers`, role outputs in
:mod:`gcnt.nn.heads`, the one masked mean over limbs in :mod:`gcnt.nn.masking`.
"""

from gcnt.nn.chain import Backbone, NetIO, assemble, graph_lookup_of
from gcnt.nn.config import (
    AmorpheusConfig,
    GCNTConfig,
    MetaMorphConfig,
    MLPConfig,
    ModuMorphConfig,
    NetConfig,
    SMPConfig,
    SWATConfig,
    TransformerConfig,
)
from gcnt.nn.distributions import MaskedNormal
from gcnt.nn.graph_lookup import GraphLookup
from gcnt.nn.heads import ROLES
from gcnt.nn.layers import EncoderLayer, TransformerEncoder
from gcnt.nn.masking import limb_mean
from gcnt.nn.registry import (
    NETWORKS,
    NetworkEntry,
    count_parameters,
    make_config,
    make_network,
    register_network,
    unregister_network,
)

__all__ = [
    "NETWORKS",
    "ROLES",
    "AmorpheusConfig",
    "Backbone",
    "EncoderLayer",
    "GCNTConfig",
    "GraphLookup",
    "MLPConfig",
    "MaskedNormal",
    "MetaMorphConfig",
    "ModuMorphConfig",
    "NetConfig",
    "NetIO",
    "NetworkEntry",
    "SMPConfig",
    "SWATConfig",
    "TransformerConfig",
    "TransformerEncoder",
    "assemble",
    "count_parameters",
    "graph_lookup_of",
    "limb_mean",
    "make_config",
    "make_network",
    "register_network",
    "unregister_network",
]
