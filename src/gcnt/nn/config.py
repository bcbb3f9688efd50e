"""Network configurations: one dataclass per method, with the paper's sizes as presets.

``GCNTConfig.preset("smpenv")`` is the paper's SMPENV setting (appendix table 1: d 128, 3 layers,
2 heads, FF 256, GCN width 16); ``preset("unimal")`` its UNIMAL setting (table 3: 5 layers, FF
1024, GCN width 23). Keyword overrides shrink or change anything
(``GCNTConfig.preset("smpenv", layers=1, d_model=32)`` for a CPU quick start); an unknown field is
a ValueError that names it and suggests close matches.

The PPO policy's standard deviation is not a network field: it belongs to the PPO head
(``make_network(..., ppo_std=..., ppo_init_std=...)``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, ClassVar, Self

from gcnt.morphology import GLOBAL_LIMB_TYPES
from gcnt.suggest import did_you_mean

PRESETS = ("smpenv", "unimal")
#: the init schemes of :mod:`gcnt.nn.init` (kept here so that configs load without torch)
INIT_SCHEMES = ("amorpheus", "metamorph", "torch")


def unknown_name_error(kind: str, name: str, known: list[str] | tuple[str, ...]) -> ValueError:
    """A ValueError naming ``name`` with the closest entries of ``known``."""
    return ValueError(
        f"unknown {kind} {name!r}{did_you_mean(name, known)} (known: {', '.join(sorted(known))})"
    )


@dataclass
class NetConfig:
    """Base of every method's config: presets and checked overrides."""

    #: preset name -> field overrides on top of the dataclass defaults
    PRESETS: ClassVar[dict[str, dict[str, Any]]] = {"smpenv": {}, "unimal": {}}

    @classmethod
    def field_names(cls) -> list[str]:
        return [f.name for f in dataclasses.fields(cls)]

    @classmethod
    def check_overrides(cls, overrides: dict[str, Any]) -> None:
        names = cls.field_names()
        for key in overrides:
            if key not in names:
                raise unknown_name_error(f"{cls.__name__} field", key, names)

    @classmethod
    def preset(cls, name: str = "smpenv", **overrides: Any) -> Self:
        """The paper's sizes for benchmark ``name`` ("smpenv" or "unimal"), with overrides."""
        if name not in cls.PRESETS:
            raise unknown_name_error("preset", name, list(cls.PRESETS))
        cls.check_overrides(overrides)
        return cls(**{**cls.PRESETS[name], **overrides})

    def replace(self, **overrides: Any) -> Self:
        self.check_overrides(overrides)
        return dataclasses.replace(self, **overrides)

    def __post_init__(self) -> None:
        pass


def _positive(cfg: object, *names: str) -> None:
    for n in names:
        v = getattr(cfg, n)
        if not (isinstance(v, int) and v > 0):
            raise ValueError(f"{type(cfg).__name__}.{n} must be a positive int, got {v!r}")


@dataclass
class TransformerConfig(NetConfig):
    """A Transformer over limb tokens (AMORPHEUS; the base of SWAT and GCNT).

    Defaults are AMORPHEUS's: input Linear(F→d)·√d, post-LN encoder layers (ReLU feed-forward),
    a final LayerNorm, dropout 0; decoder input = encoder output ‖ raw limb input.
    """

    d_model: int = 128
    layers: int = 3
    heads: int = 2
    ff: int = 256
    dropout: float = 0.0
    norm_first: bool = False  # False: post-LN (AMORPHEUS, SWAT, GCNT); True: pre-LN (MetaMorph)
    final_norm: bool = True
    input_scale: bool = True  # multiply the input embedding by √d_model
    #: initial weights (:mod:`gcnt.nn.init`): "amorpheus" (the AMORPHEUS/SWAT code: embedding
    #: and last decoder layer U(±0.1), decoder bias 0), "metamorph" (the MetaMorph/ModuMorph
    #: code: embedding U(±0.1), last decoder layer U(±0.01), bias 0) or "torch" (defaults)
    init: str = "amorpheus"

    PRESETS: ClassVar[dict[str, dict[str, Any]]] = {
        "smpenv": {},
        # MetaMorph* backbone sizes on UNIMAL (GCNT appendix table 3), MetaMorph's init
        "unimal": {"layers": 5, "ff": 1024, "init": "metamorph"},
    }

    def __post_init__(self) -> None:
        super().__post_init__()
        _positive(self, "d_model", "layers", "heads", "ff")
        if self.init not in INIT_SCHEMES:
            raise unknown_name_error("init scheme", self.init, list(INIT_SCHEMES))
        if self.d_model % self.heads:
            raise ValueError(
                f"{type(self).__name__}: d_model {self.d_model} is not divisible by heads "
                f"{self.heads}"
            )
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"dropout must be in [0, 1), got {self.dropout}")


@dataclass
class AmorpheusConfig(TransformerConfig):
    """AMORPHEUS (Kurin et al. 2021): the plain Transformer, no positional information."""


@dataclass
class SWATConfig(TransformerConfig):
    """SWAT (Hong et al. 2022): AMORPHEUS + traversal position embeddings + a relational bias
    Linear(3→heads) of [PPR, normalised Laplacian, hop distance / N] in the first layer."""

    #: widths of the pre/in/post-order embeddings; default: d_model split in three, the last
    #: part taking the remainder ((42, 42, 44) at d_model 128, as in SWAT)
    traversal_widths: tuple[int, int, int] | None = None
    #: size of each traversal-position table: the most limbs a robot may have
    max_limbs: int = 32

    PRESETS: ClassVar[dict[str, dict[str, Any]]] = TransformerConfig.PRESETS

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.traversal_widths is None:
            third = self.d_model // 3
            self.traversal_widths = (third, third, self.d_model - 2 * third)
        self.traversal_widths = tuple(self.traversal_widths)  # type: ignore[assignment]
        if len(self.traversal_widths) != 3 or sum(self.traversal_widths) != self.d_model:
            raise ValueError(
                f"SWATConfig.traversal_widths {self.traversal_widths} must be 3 widths summing to "
                f"d_model={self.d_model}"
            )
        _positive(self, "max_limbs")


@dataclass
class GCNTConfig(TransformerConfig):
    """GCNT: limb encoder + residual GCN + WL counts + distance-biased Transformer (see gcnt.py).

    Ablation switches remove the module and its parameters: ``use_gcn``, ``use_wl``,
    ``use_dist_bias``.
    """

    gcn_width: int = 16
    gcn_layers: int = 4
    num_limb_types: int = len(GLOBAL_LIMB_TYPES)
    #: hop distances are clamped to this before the bias lookup (table of max_dist + 1 rows)
    max_dist: int = 15
    #: "shared": one bias table g_φ(d) (the paper's eq. 5 has one mapping and no layer index,
    #: and its parameter counts fit one table; default); "per_layer": one table per layer
    dist_bias: str = "shared"
    #: which layers add the shared table to their attention logits: "all" (default: as the
    #: UNIMAL codebase GCNT was built on adds its structural attention biases in every layer
    #: (ModuMorph's ``TransformerEncoderLayerResidual``), and as Graphormer, whose spatial
    #: encoding eq. 5 resembles, shares one table across all layers) or "first" (as SWAT's
    #: ``RepeatTransformerEncoder``, the SMPENV codebase, adds its relational bias in the first
    #: layer only; the registered ablation ``gcnt_dist_first``)
    dist_bias_layers: str = "all"
    #: hidden widths of the limb-observation MLP; () = one Linear(F→d) (scaled by √d if
    #: input_scale), the SWAT/AMORPHEUS encoder GCNT was built on
    encoder_hidden: tuple[int, ...] = ()
    use_gcn: bool = True
    #: what the GCN reads per limb: "types" (the one-hot limb type; default) or "context" (the
    #: static limb context ``limbs/context`` the hypernetworks read; the registered ablation
    #: ``gcnt_gcn_context``)
    gcn_input: str = "types"
    use_wl: bool = True
    use_dist_bias: bool = True
    #: GCNT+HN: per-limb encoder and decoder weights generated by a hypernetwork from the limb's
    #: static context ``limbs/context`` (as ModuMorph's), instead of shared Linear layers
    hypernet: bool = False
    #: width of the hypernetwork's context MLP C → hn_width → hn_width (default: d_model)
    hn_width: int | None = None

    PRESETS: ClassVar[dict[str, dict[str, Any]]] = {
        "smpenv": {},  # appendix table 1
        # appendix table 3; on UNIMAL GCNT sits on MetaMorph*'s backbone (pre-LN, no final LN)
        "unimal": {
            "layers": 5,
            "ff": 1024,
            "gcn_width": 23,
            "norm_first": True,
            "final_norm": False,
            "init": "metamorph",
        },
    }

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.hn_width is None:
            self.hn_width = self.d_model
        _positive(self, "gcn_width", "gcn_layers", "num_limb_types", "max_dist", "hn_width")
        if self.gcn_input not in ("types", "context"):
            raise ValueError(f"gcn_input must be 'types' or 'context', got {self.gcn_input!r}")
        if self.dist_bias not in ("per_layer", "shared"):
            raise ValueError(f"dist_bias must be 'per_layer' or 'shared', got {self.dist_bias!r}")
        if self.dist_bias_layers not in ("all", "first"):
            raise ValueError(
                f"dist_bias_layers must be 'all' or 'first', got {self.dist_bias_layers!r}"
            )
        if self.dist_bias == "per_layer" and self.dist_bias_layers == "first":
            raise ValueError(
                "dist_bias_layers='first' uses one shared table: it needs dist_bias='shared', "
                "not 'per_layer'"
            )
        self.encoder_hidden = tuple(self.encoder_hidden)


@dataclass
class MetaMorphConfig(TransformerConfig):
    """MetaMorph (Gupta et al. 2022): token = Linear(F→d)·√d + a learned embedding of the limb's
    depth-first index, then dropout; pre-LN encoder layers, no final LayerNorm; decoder from the
    encoder output only (no raw-input residual). Init: embedding weight U(±0.1), last decoder
    layer weight U(±0.01) and bias 0. MetaMorph* (Xiong et al. 2023) is the same without the
    position embedding and without embedding dropout."""

    norm_first: bool = True
    final_norm: bool = False
    #: learned embedding of the limb slot (depth-first pre-order index); False: MetaMorph*
    position_embedding: bool = True
    #: dropout on the token embedding (after the position embedding is added)
    embed_dropout: float = 0.1
    #: rows of the position table: the most limbs a robot may have (UNIMAL pads to 12)
    max_limbs: int = 12
    init: str = "metamorph"

    PRESETS: ClassVar[dict[str, dict[str, Any]]] = {
        "smpenv": {},
        "unimal": {"layers": 5, "ff": 1024},
    }

    def __post_init__(self) -> None:
        super().__post_init__()
        _positive(self, "max_limbs")
        if not 0.0 <= self.embed_dropout < 1.0:
            raise ValueError(f"embed_dropout must be in [0, 1), got {self.embed_dropout}")


@dataclass
class ModuMorphConfig(TransformerConfig):
    """ModuMorph (Xiong et al. 2023): per-limb encoder and decoder weights generated by a
    hypernetwork from the limb's static context (``limbs/context``) through an MLP
    C → hn_width → hn_width; "fixed attention": Q and K from a context embedding MLP
    C → 128 → 128 → 128 (ReLU after each layer; LayerNorm per encoder layer), V from the token
    stream; pre-LN, no final
    LayerNorm, no position embedding, no dropout. The widths follow ``d_model`` (128 in the
    paper) unless given."""

    norm_first: bool = True
    final_norm: bool = False
    #: default: d_model
    hn_width: int | None = None
    #: False: a plain pre-LN self-attention encoder instead of fixed attention
    fixed_attention: bool = True
    #: widths of the context embedding MLP that feeds Q and K (the last one must be d_model;
    #: default: three layers of d_model)
    attn_context_widths: tuple[int, ...] | None = None

    PRESETS: ClassVar[dict[str, dict[str, Any]]] = TransformerConfig.PRESETS

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.hn_width is None:
            self.hn_width = self.d_model
        if self.attn_context_widths is None:
            self.attn_context_widths = (self.d_model,) * 3
        _positive(self, "hn_width")
        self.attn_context_widths = tuple(self.attn_context_widths)
        if self.fixed_attention:
            if not self.norm_first:
                raise ValueError("ModuMorphConfig: fixed attention is pre-LN (norm_first=True)")
            if not self.attn_context_widths or self.attn_context_widths[-1] != self.d_model:
                raise ValueError(
                    f"ModuMorphConfig.attn_context_widths {self.attn_context_widths} must end "
                    f"with d_model={self.d_model}"
                )


@dataclass
class SMPConfig(NetConfig):
    """SMP (Huang et al. 2020): bottom-up then top-down message passing on the limb tree, at the
    original code's sizes (message 32, bottom-up width 64, 400 → 300 output and message MLPs)."""

    msg_dim: int = 32
    #: width of the bottom-up module's hidden layers
    hidden: int = 64
    #: hidden widths of the top-down MLPs (down-message, action or Q), the original's MLPBase
    head_hidden: tuple[int, ...] = (400, 300)
    #: L2-normalise messages (as the SMP code does)
    normalize_messages: bool = True

    def __post_init__(self) -> None:
        super().__post_init__()
        _positive(self, "msg_dim", "hidden")
        self.head_hidden = tuple(self.head_hidden)


@dataclass
class MLPConfig(NetConfig):
    """One MLP over the flattened padded limb inputs of one robot (the SR-fair / SR-top
    single-robot references): K·F → hidden… (ReLU) → K·out."""

    hidden: tuple[int, ...] = field(default=(256, 256, 256))

    def __post_init__(self) -> None:
        super().__post_init__()
        self.hidden = tuple(self.hidden)
