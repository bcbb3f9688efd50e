"""Network configurations: one dataclass per method, with the paper's sizes as presets.

``GCNTConfig.preset("smpenv")`` is appendix table 1 (d 128, 3 layers, 2 heads, FF 256, GCN width
16); ``preset("unimal")`` is table 3 (5 layers, FF 1024, GCN width 23). Keyword overrides shrink or
change anything (``GCNTConfig.preset("smpenv", layers=1, d_model=32)`` for a CPU quick start); an
unknown field is a ValueError that names it and suggests close matches.
"""

from __future__ import annotations

import dataclasses
import difflib
from dataclasses import dataclass, field
from typing import Any, ClassVar, Self

from gcnt.morphology import GLOBAL_LIMB_TYPES

PRESETS = ("smpenv", "unimal")


def unknown_name_error(kind: str, name: str, known: list[str] | tuple[str, ...]) -> ValueError:
    """A ValueError naming ``name`` with the closest entries of ``known``."""
    close = difflib.get_close_matches(name, list(known), n=3, cutoff=0.5)
    hint = f"; did you mean {' or '.join(repr(c) for c in close)}?" if close else ""
    return ValueError(f"unknown {kind} {name!r}{hint} (known: {', '.join(sorted(known))})")


@dataclass
class NetConfig:
    """Fields every method has: the PPO policy's standard deviation."""

    #: PPO Gaussian std: "fixed" (MetaMorph: 0.9, not trained) or "learned" (a state-independent
    #: log-std parameter per action slot, initialised to ``ppo_init_std``).
    ppo_std: str = "fixed"
    ppo_init_std: float = 0.9

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
        if self.ppo_std not in ("fixed", "learned"):
            raise ValueError(f"ppo_std must be 'fixed' or 'learned', got {self.ppo_std!r}")
        if not self.ppo_init_std > 0:
            raise ValueError(f"ppo_init_std must be > 0, got {self.ppo_init_std}")


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

    PRESETS: ClassVar[dict[str, dict[str, Any]]] = {
        "smpenv": {},
        # MetaMorph* backbone sizes on UNIMAL (GCNT appendix table 3)
        "unimal": {"layers": 5, "ff": 1024},
    }

    def __post_init__(self) -> None:
        super().__post_init__()
        _positive(self, "d_model", "layers", "heads", "ff")
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
    #: "per_layer": one bias table per layer (default); "shared": one table for all layers
    dist_bias: str = "per_layer"
    #: hidden widths of the limb-observation MLP; () = one Linear(F→d) (scaled by √d if
    #: input_scale), the SWAT/AMORPHEUS encoder GCNT was built on
    encoder_hidden: tuple[int, ...] = ()
    use_gcn: bool = True
    use_wl: bool = True
    use_dist_bias: bool = True

    PRESETS: ClassVar[dict[str, dict[str, Any]]] = {
        "smpenv": {},  # appendix table 1
        "unimal": {"layers": 5, "ff": 1024, "gcn_width": 23},  # appendix table 3
    }

    def __post_init__(self) -> None:
        super().__post_init__()
        _positive(self, "gcn_width", "gcn_layers", "num_limb_types", "max_dist")
        if self.dist_bias not in ("per_layer", "shared"):
            raise ValueError(f"dist_bias must be 'per_layer' or 'shared', got {self.dist_bias!r}")
        self.encoder_hidden = tuple(self.encoder_hidden)


@dataclass
class SMPConfig(NetConfig):
    """SMP (Huang et al. 2020): bottom-up then top-down message passing on the limb tree."""

    msg_dim: int = 32
    hidden: int = 64
    #: L2-normalise messages (as the SMP code does)
    normalize_messages: bool = True

    def __post_init__(self) -> None:
        super().__post_init__()
        _positive(self, "msg_dim", "hidden")


@dataclass
class MLPConfig(NetConfig):
    """One MLP over the flattened padded limb inputs of one robot (SR reference runs)."""

    hidden: tuple[int, ...] = field(default=(256, 256, 256))

    def __post_init__(self) -> None:
        super().__post_init__()
        self.hidden = tuple(self.hidden)
