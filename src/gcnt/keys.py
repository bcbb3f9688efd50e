"""The TensorDict contract: every key that envs, replay buffers, networks and losses share.

An env (:class:`gcnt.envs.base.BatchedMujocoEnv`) emits per step, batch [N], limbs padded to K,
A action slots per limb::

    morph_id            [N]        int64    index into the run's robot table
    limbs/obs           [N,K,F]    float32  the featuriser's per-limb observation
    limbs/mask          [N,K]      bool     real limb
    limbs/type          [N,K]      int64    global limb-type id
    limbs/action_mask   [N,K,A]    bool     a motor drives this slot
    limbs/context       [N,K,C]    float32  static limb description, only if the featuriser
                                            declares one (UNIMAL), scaled to [-1, 1]
    graph/adj           [N,K,K]    bool
    graph/dist          [N,K,K]    uint8    hop distance, clamped
    graph/wl            [N,W]      float32  Weisfeiler-Lehman colour counts
    <root outputs>      [N,D]      float32  those the featuriser declares (``hfield`` [N, 1410]
                                            on UNIMAL's MT and Obstacles)
    reward, done, terminated, truncated   [N,1]

and reads the action ``limbs/action`` [N,K,A] in [-1, 1]: slot ``a`` of limb ``l`` drives the
motor of the joint that ``Robot.action_slots(l)`` puts in slot ``a``.

The policy chains read ``morph_id``, ``limbs/obs`` (critics also ``limbs/action``) and the root
outputs; the static keys (mask, type, action mask, context, ``graph/*``) are restored from the
robot table by :class:`gcnt.nn.GraphLookup` at the head of every chain, so replay buffers store
only the per-step keys. The names below are the only place these strings are written.
"""

from __future__ import annotations

MORPH_ID = "morph_id"

# step outputs
REWARD = "reward"
DONE = "done"
TERMINATED = "terminated"
TRUNCATED = "truncated"
NEXT = "next"

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
