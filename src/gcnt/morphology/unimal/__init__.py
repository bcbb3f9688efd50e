"""UNIMAL robots: the DERL symmetric design space, a generator, mutations, the checked-in set.

Modules: ``space`` (numbers and the genotype), ``mjcf`` (the file layout and the validity check),
``generate`` (random growth), ``mutate`` (DERL's operators and the variant sets), ``catalogue``
(the checked-in robots, their splits and the catalogue record), ``stats`` (set statistics),
``imported`` (the paper's evolved robots: MetaMorph's published files as a catalogue,
``gcnt import-unimal``).
"""

from gcnt.morphology.unimal.generate import generate
from gcnt.morphology.unimal.mjcf import InvalidUnimal, build_mjcf
from gcnt.morphology.unimal.mutate import OPERATORS, MutationError, make_variant, mutate
from gcnt.morphology.unimal.space import Hinge, Limb, Rng, Unimal

__all__ = [
    "OPERATORS",
    "Hinge",
    "InvalidUnimal",
    "Limb",
    "MutationError",
    "Rng",
    "Unimal",
    "build_mjcf",
    "generate",
    "make_variant",
    "mutate",
]
