"""GCNT (Luo et al., IJCAI 2025) as a chain of stages.

::

    limbs/input ─ encoder (Linear F→d, ·√d) ───────────────────────┐
    limbs/type, graph/adj ─ gcn (one-hot → width, 4 residual GCN) ─┤ fusion: + Linear([GCN ‖ WL] → d)
    graph/wl ──────────────────────────────────────────────────────┘
    graph/dist ─ dist_bias (Embedding(clamped hop distance) → one bias per head, every layer or the first)
    → transformer (post-LN encoder layers, bias added to q·k/√d_h, padded keys masked, final LN)
    → head: [output ‖ limbs/input (‖ height-map embedding)] → (64 →) out, per limb

Choices the paper leaves open, made here:

* **Limb encoder**: one Linear(F→d) scaled by √d (``encoder_hidden=()``), the AMORPHEUS/SWAT
  encoder of the codebase GCNT was built on; set ``encoder_hidden`` for a deeper MLP.
* **Transformer**: post-LN with a final LayerNorm, as AMORPHEUS/SWAT (GCNT was implemented on
  SWAT's code); ``norm_first=True`` gives pre-LN.
* **Distance bias**: one zero-initialised embedding table g_φ(d), one value per head
  (``dist_bias="shared"``: eq. 5 has one mapping and no layer index, and the paper's UNIMAL
  parameter count fits one table), added to the attention logits of every layer
  (``dist_bias_layers="all"``, as ModuMorph's code adds its structural biases in every layer
  and Graphormer its shared spatial table) or of the first layer only (``"first"``, as SWAT's
  code adds its relational bias; the ablation ``gcnt_dist_first``). ``dist_bias="per_layer"``
  gives each layer its own table. Hop distances are clamped to ``max_dist``; zero init means
  training starts from the plain Transformer.
* **WL counts** enter raw (counts, not frequencies), as the paper describes.
* **Initial weights** as the code GCNT was built on (:mod:`gcnt.nn.init`): on SMPENV the
  AMORPHEUS/SWAT code's (embedding and last decoder layer U(±0.1), decoder bias 0), on UNIMAL the
  ModuMorph code's (embedding U(±0.1), last decoder layer U(±0.01), bias 0). The fusion
  projection, added to the token embedding, is initialised as the embedding; the GCN keeps
  PyTorch's defaults.
* **The GCN's input** (``gcn_input``): the one-hot limb type (``"types"``, default). The paper
  gives the GCN one-hot limb types, which UNIMAL does not define (its limbs have no names):
  gcnt's UNIMAL types are four purely topological ones (torso, proximal, inner, distal), so the
  structural branch is the same for a robot and every kinematic or dynamic variant of it. The
  registered ablation ``gcnt_gcn_context`` reads the limb context the hypernetworks read
  (``limbs/context``) instead.
* **GCNT+HN** (``hypernet=True``): the encoder and the decoder become ModuMorph's hypernetwork
  layers (per-limb weights generated from ``limbs/context``); the decoder keeps GCNT's input
  [output ‖ limbs/input (‖ height map)]. Everything else is GCNT's.
"""

from __future__ import annotations

from tensordict import TensorDictBase

from gcnt import keys as K
from gcnt.nn.chain import Backbone, NetIO
from gcnt.nn.config import GCNTConfig
from gcnt.nn.init import init_like_original
from gcnt.nn.stages import (
    context_stage,
    context_width,
    distance_bias_stage,
    encoder_of,
    fusion_stage,
    gcn_stage,
    hyper_encoder_stage,
    limb_encoder_stage,
    limb_head_stage,
    transformer_stage,
)


def gcnt_backbone(cfg: GCNTConfig, io: NetIO, table: TensorDictBase) -> Backbone:
    """GCNT's stages from ``limbs/input`` to ``limbs/out`` (WL width read from the table)."""
    stages = []
    static = []
    limits = {}
    embeddings = []  # what the init scheme treats as the token embedding
    hyper = 0
    if cfg.hypernet:
        ctx_dim = context_width(table, "GCNT+HN")
        hyper = cfg.hn_width
        stages.append(("hn_context", context_stage(ctx_dim, (hyper, hyper), K.HN_CONTEXT)))
        stages.append(
            ("encoder", hyper_encoder_stage(hyper, io.in_dim, cfg.d_model, cfg.input_scale))
        )
        static.append(K.CONTEXT)
    else:
        encoder = limb_encoder_stage(io.in_dim, cfg.d_model, cfg.encoder_hidden, cfg.input_scale)
        stages.append(("encoder", encoder))
        embeddings.append(encoder.module)
    if cfg.use_gcn:
        gcn_ctx = 0
        if cfg.gcn_input == "context":
            gcn_ctx = context_width(table, "GCNT with gcn_input='context'")
        gcn = gcn_stage(cfg.num_limb_types, cfg.gcn_width, cfg.gcn_layers, gcn_ctx)
        stages.append(("gcn", gcn))
        static += [K.CONTEXT if gcn_ctx else K.TYPE, K.ADJ]
        if not gcn_ctx:  # one-hot types: ids past num_limb_types have no column
            limits[K.TYPE] = (cfg.num_limb_types, "num_limb_types")
    if cfg.use_wl:
        static.append(K.WL)
    hidden_key = K.EMBED
    if cfg.use_gcn or cfg.use_wl:
        gw = cfg.gcn_width if cfg.use_gcn else 0
        wl_dim = table.get(K.WL).shape[-1] if cfg.use_wl else 0
        fusion = fusion_stage(cfg.d_model, gw, wl_dim)
        stages.append(("fusion", fusion))
        embeddings.append(fusion.module)
        hidden_key = K.HIDDEN
    if cfg.use_dist_bias:
        tables = cfg.layers if cfg.dist_bias == "per_layer" else 1
        stages.append(("dist_bias", distance_bias_stage(cfg.max_dist, cfg.heads, tables)))
        static.append(K.DIST)
    if cfg.dist_bias == "per_layer":
        bias_mode = "per_layer"
    else:
        bias_mode = "first" if cfg.dist_bias_layers == "first" else "shared"
    enc = encoder_of(cfg, bias_mode)
    stages.append(("transformer", transformer_stage(enc, hidden_key, cfg.use_dist_bias)))
    head = limb_head_stage(
        cfg.d_model,
        io.out_dim,
        raw_dim=io.in_dim,
        hfield_width=io.hfield_width,
        hyper_dim=hyper,
        hidden=io.decoder_hidden,
    )
    stages.append(("head", head))
    # the hypernetwork's generated decoder has its own init (HyperLinear)
    init_like_original(cfg.init, embeddings=embeddings, decoder=None if hyper else head.module)
    return Backbone(
        stages,
        tuple(dict.fromkeys(static)),
        name="GCNT+HN" if cfg.hypernet else "GCNT",
        limits=limits,
    )
