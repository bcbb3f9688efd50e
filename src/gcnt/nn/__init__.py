"""GCNT and the baselines as chains of TensorDictModules (one stage each).

Start with :func:`make_network`; the stages live in :mod:`gcnt.nn.stages`, the shared Transformer
layer in :mod:`gcnt.nn.layers`, role outputs in :mod:`gcnt.nn.heads`.
"""

from gcnt.nn.chain import Backbone, assemble, graph_lookup_of
from gcnt.nn.config import (
    AmorpheusConfig,
    GCNTConfig,
    MLPConfig,
    NetConfig,
    SMPConfig,
    SWATConfig,
    TransformerConfig,
)
from gcnt.nn.distributions import MaskedNormal
from gcnt.nn.graph_lookup import GraphLookup
from gcnt.nn.heads import ROLES
from gcnt.nn.layers import EncoderLayer, TransformerEncoder
from gcnt.nn.registry import (
    NETWORKS,
    count_parameters,
    make_config,
    make_network,
    make_td3_critics,
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
    "NetConfig",
    "SMPConfig",
    "SWATConfig",
    "TransformerConfig",
    "TransformerEncoder",
    "assemble",
    "count_parameters",
    "graph_lookup_of",
    "make_config",
    "make_network",
    "make_td3_critics",
]
