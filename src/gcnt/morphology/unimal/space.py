"""The DERL symmetric UNIMAL design space: its numbers, and a robot as a genotype.

A robot is a sphere torso (radius 0.1, free root joint) and up to 10 capsule limbs (radius 0.05).
Every limb hangs from an attachment site of its parent: the torso centre, or the middle or end of
a limb. A limb points along (theta, phi) in degrees, theta about z from +x, phi from +z; its body
origin is the site plus the parent's radius along that direction; its capsule runs from the
origin to ``r + h`` along it, and its hinges sit at ``-r`` along it. All numbers are rounded to
the centimetre as the original generator does, so mirrored limbs mirror exactly.

Limbs come alone (on the symmetry plane) or as a mirrored pair (``mirror`` names the partner);
both limbs of a pair share their length, joints and gears, so that the robot stays bilaterally
symmetric. Mutations act on a *group*: a single limb or a pair.
"""

from __future__ import annotations

import math
import random
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import TypeVar

TORSO_RADIUS = 0.1
LIMB_RADIUS = 0.05
LIMB_HEIGHTS: tuple[float, ...] = (0.2, 0.3, 0.4)
THETAS: tuple[int, ...] = (0, 45, 90, 135, 180, 225, 270, 315)
PHIS: tuple[int, ...] = (90, 135, 180)
JOINT_RANGES: tuple[tuple[int, int], ...] = (
    (-30, 0), (0, 30), (-30, 30), (-45, 45), (-45, 0), (0, 45), (-60, 0), (0, 60), (-60, 60),
    (-90, 0), (0, 90), (-60, 30), (-30, 60),
)  # fmt: skip
GEARS: tuple[int, ...] = (150, 200, 250, 300)
JOINT_AXES: tuple[str, ...] = ("x", "y", "xy")
DENSITIES: tuple[int, ...] = (500, 600, 700, 800, 900, 1000)
#: Most limbs besides the torso.
MAX_LIMBS = 10
#: Height of the robot's lowest point above the floor in its file.
FLOOR_OFFSET = 0.2
#: Joint defaults of the design space (every hinge; variants may override armature/damping).
JOINT_DAMPING = 1.0
JOINT_STIFFNESS = 1.0
JOINT_ARMATURE = 1.0

Vec3 = tuple[float, float, float]
T = TypeVar("T")


class Rng:
    """Draws from ``random.Random.random`` only: the one stream Python keeps identical across
    versions, so that a seed gives the same robot everywhere."""

    def __init__(self, seed: int | str) -> None:
        self._r = random.Random(seed)

    def uniform(self) -> float:
        return self._r.random()

    def choice(self, items: Sequence[T], weights: Sequence[float] | None = None) -> T:
        if weights is None:
            return items[min(int(self._r.random() * len(items)), len(items) - 1)]
        u = self._r.random() * sum(weights)
        for item, w in zip(items, weights, strict=True):
            if u < w:
                return item
            u -= w
        return items[-1]

    def coin(self, p: float = 0.5) -> bool:
        return self._r.random() < p


def sph(r: float, theta: float, phi: float) -> Vec3:
    """The point at distance ``r`` along (theta, phi) (degrees), rounded to the centimetre."""
    t, p = math.radians(theta), math.radians(phi)
    xyz = (r * math.sin(p) * math.cos(t), r * math.sin(p) * math.sin(t), r * math.cos(p))
    return tuple(round(c, 2) + 0.0 for c in xyz)  # type: ignore[return-value]  # +0.0: no -0


def add(a: Vec3, b: Vec3) -> Vec3:
    return tuple(round(x + y, 4) + 0.0 for x, y in zip(a, b, strict=True))  # type: ignore[return-value]


@dataclass(frozen=True)
class Hinge:
    """One hinge of a limb and its motor. ``armature``/``damping`` None: the joint defaults."""

    axis: str  # "x" or "y": the limb's local axis it turns about
    range: tuple[int, int]  # degrees
    gear: int
    armature: float | None = None
    damping: float | None = None


@dataclass(frozen=True)
class Limb:
    parent: int  # index of the parent limb; -1: the torso
    site: str  # "torso", "mid" or "btm" (the parent's end)
    h: float
    theta: int
    phi: int
    hinges: tuple[Hinge, ...]
    mirror: int = -1  # index of the mirrored partner; -1: a limb on the symmetry plane

    @property
    def length(self) -> float:
        """Capsule length between its two end points (r + h)."""
        return LIMB_RADIUS + self.h


@dataclass(frozen=True)
class Unimal:
    """A UNIMAL genotype. Limb ``i`` is ``limb/i`` in the file; parents come before children."""

    limbs: tuple[Limb, ...] = ()
    torso_density: int = 1000
    limb_density: int = 1000
    notes: tuple[str, ...] = field(default=(), compare=False)  # how it was made (not in the file)

    @property
    def num_dof(self) -> int:
        return sum(len(limb.hinges) for limb in self.limbs)

    def children(self, i: int) -> list[int]:
        return [j for j, limb in enumerate(self.limbs) if limb.parent == i]

    def groups(self) -> list[tuple[int, ...]]:
        """Symmetric groups in limb order: ``(i,)`` or ``(i, mirror)``."""
        out: list[tuple[int, ...]] = []
        for i, limb in enumerate(self.limbs):
            if limb.mirror < 0:
                out.append((i,))
            elif limb.mirror > i:
                out.append((i, limb.mirror))
        return out

    def depth(self) -> int:
        """Limbs on the longest torso-to-leaf chain (0 for a bare torso)."""
        d = [0] * len(self.limbs)
        for i, limb in enumerate(self.limbs):
            d[i] = 1 + (d[limb.parent] if limb.parent >= 0 else 0)
        return max(d, default=0)

    def replace_limbs(self, new: dict[int, Limb]) -> Unimal:
        """This robot with limbs ``new[i]`` in place of limb ``i``."""
        return replace(self, limbs=tuple(new.get(i, limb) for i, limb in enumerate(self.limbs)))


def parent_radius(u: Unimal, limb: Limb) -> float:
    return TORSO_RADIUS if limb.parent < 0 else LIMB_RADIUS


def site_pos(u: Unimal, parent: int, site: str) -> Vec3:
    """Position of an attachment site in its parent's frame."""
    if parent < 0:
        return (0.0, 0.0, 0.0)
    p = u.limbs[parent]
    along = LIMB_RADIUS + (p.h / 2 if site == "mid" else p.h)
    return sph(along, p.theta, p.phi)


def body_pos(u: Unimal, i: int) -> Vec3:
    """Position of limb ``i``'s body origin in its parent's frame."""
    limb = u.limbs[i]
    base = site_pos(u, limb.parent, limb.site)
    return add(base, sph(parent_radius(u, limb), limb.theta, limb.phi))


def same_orient(a: Limb, b: Limb) -> bool:
    """Two limbs point the same way (straight down counts as one way whatever theta)."""
    return (a.theta, a.phi) == (b.theta, b.phi) or a.phi == b.phi == 180
