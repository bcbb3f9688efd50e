"""The SMPENV baselines, built from the same stages and heads as GCNT: AMORPHEUS, SWAT, SMP and a
plain per-robot MLP."""

from gcnt.nn.baselines.amorpheus import amorpheus_backbone
from gcnt.nn.baselines.mlp import mlp_backbone
from gcnt.nn.baselines.smp import smp_backbone
from gcnt.nn.baselines.swat import swat_backbone

__all__ = ["amorpheus_backbone", "mlp_backbone", "smp_backbone", "swat_backbone"]
