"""The baselines, built from the same stages and decoders as GCNT (none imports GCNT): AMORPHEUS,
SWAT, SMP (SMPENV); MetaMorph, MetaMorph*, ModuMorph (UNIMAL); SR, a plain per-robot MLP."""

from gcnt.nn.baselines.amorpheus import amorpheus_backbone
from gcnt.nn.baselines.metamorph import metamorph_backbone
from gcnt.nn.baselines.mlp import mlp_backbone
from gcnt.nn.baselines.modumorph import modumorph_backbone
from gcnt.nn.baselines.smp import smp_backbone
from gcnt.nn.baselines.swat import swat_backbone

__all__ = [
    "amorpheus_backbone",
    "metamorph_backbone",
    "mlp_backbone",
    "modumorph_backbone",
    "smp_backbone",
    "swat_backbone",
]
