"""TensorDict keys read and written by the policy chains (see the contract in the design notes).

Inputs (from the env or a replay-buffer sample): ``morph_id``, ``limbs/obs`` and, for critics,
``limbs/action``. Static keys (``limbs/mask``, ``limbs/type``, ``limbs/action_mask``, ``graph/*``)
are restored from the robot table by :class:`gcnt.nn.GraphLookup` at the head of every chain.
"""

from __future__ import annotations

MORPH_ID = "morph_id"

# inputs
OBS = ("limbs", "obs")
ACTION = ("limbs", "action")

# static, from the robot table
MASK = ("limbs", "mask")
TYPE = ("limbs", "type")
ACTION_MASK = ("limbs", "action_mask")
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

# outputs
LIMB_Q = ("limbs", "state_action_value")
Q = "state_action_value"
LIMB_VALUE = ("limbs", "state_value")
VALUE = "state_value"
LOC = ("limbs", "loc")
SCALE = ("limbs", "scale")
LOG_PROB = "action_log_prob"
