"""TensorDict keys read and written by the policy chains.

Inputs (from the env or a replay-buffer sample): ``morph_id``, ``limbs/obs``, for critics
``limbs/action``, and on height-map worlds the root key ``hfield`` [*B, 1410]. Static keys
(``limbs/mask``, ``limbs/type``, ``limbs/action_mask``, ``limbs/context``, ``graph/*``) are
restored from the robot table by :class:`gcnt.nn.GraphLookup` at the head of every chain.
"""

from __future__ import annotations

MORPH_ID = "morph_id"

# inputs
OBS = ("limbs", "obs")
ACTION = ("limbs", "action")
HFIELD = "hfield"  # height map around the torso [*B, H] (UNIMAL MT and Obstacles)

# static, from the robot table
MASK = ("limbs", "mask")
TYPE = ("limbs", "type")
ACTION_MASK = ("limbs", "action_mask")
CONTEXT = ("limbs", "context")  # static limb description [R, K, C], scaled to [-1, 1] (UNIMAL)
ADJ = ("graph", "adj")
DIST = ("graph", "dist")
WL = ("graph", "wl")
PARENT = ("graph", "parent")
TRAVERSAL = ("graph", "traversal")
PPR = ("graph", "ppr")
LAPLACIAN = ("graph", "laplacian")

# intermediates (dropped from the output unless a chain is built with keep_intermediates=True)
INPUT = ("limbs", "input")  # obs (actor) or obs ‖ masked action (critic), zero on padding
EMBED = ("limbs", "embed")  # limb-observation embedding [.., K, d]
GCN = ("limbs", "gcn")  # GCN output [.., K, g]
HIDDEN = ("limbs", "hidden")  # embedding with morphology/position information added
ATTN_BIAS = ("graph", "attn_bias")  # additive attention bias [.., L, H, K, K]
FEATURES = ("limbs", "features")  # backbone output [.., K, d]
OUT = ("limbs", "out")  # per-limb head output [.., K, out_dim]
HFIELD_EMBED = "hfield_embed"  # encoded height map [.., 64], joined to every limb's features
HN_CONTEXT = ("limbs", "hn_context")  # hypernetwork context embedding [.., K, 128]
ATTN_CONTEXT = ("limbs", "attn_context")  # context embedding for fixed attention [.., K, 128]

# outputs
LIMB_Q = ("limbs", "state_action_value")
Q = "state_action_value"
LIMB_VALUE = ("limbs", "state_value")
VALUE = "state_value"
LOC = ("limbs", "loc")
SCALE = ("limbs", "scale")
LOG_PROB = "action_log_prob"
