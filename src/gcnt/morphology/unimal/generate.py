"""Random robots of the UNIMAL design space, grown limb by limb as DERL grows them.

Growth (DERL's ``grow_limb``): pick an attachment site uniformly (the torso centre, or the middle
or end of any limb). At a site of a limb on the symmetry plane (or the torso) grow one limb or a
mirrored pair (theta, 360 - theta; theta in {0, 180} and straight down are refused for a pair);
at a site of a paired limb grow the same limb at both mirrored sites, with the same (theta, phi).
A limb may not point like its parent from the parent's middle. Both limbs of a pair share length,
joints, ranges and gears. A growth that breaks symmetry or makes geoms touch is undone.

How many limbs: DERL's initial population draws 2-8 limbs and evolution moves the counts up; the
published training set has 4-10 (mean 8). Random sampling cannot reproduce evolution, so the
target count is drawn from :data:`LIMB_COUNT_WEIGHTS`, tuned so that the statistics of the
generated set land near the published ones (see ``gcnt robots``).
"""

from __future__ import annotations

from dataclasses import replace

from gcnt.morphology.unimal.mjcf import InvalidUnimal, check
from gcnt.morphology.unimal.space import (
    DENSITIES,
    GEARS,
    JOINT_AXES,
    JOINT_RANGES,
    LIMB_HEIGHTS,
    MAX_LIMBS,
    PHIS,
    THETAS,
    Hinge,
    Limb,
    Rng,
    Unimal,
    same_orient,
)

#: Target limb count (besides the torso) and its weight.
LIMB_COUNTS: tuple[int, ...] = (4, 5, 6, 7, 8, 9, 10)
LIMB_COUNT_WEIGHTS: tuple[float, ...] = (1, 1, 2, 3, 4, 6, 7)
#: Weights of a limb's joint axes: x only, y only, both (DERL: uniform).
AXIS_WEIGHTS: tuple[float, ...] = (1, 1, 1.2)
#: Growth attempts before a robot is given up at its current size.
GROW_ATTEMPTS = 50


class GrowthError(ValueError):
    """No valid growth was found in :data:`GROW_ATTEMPTS` attempts."""


def sample_hinges(rng: Rng, axes: str | None = None) -> tuple[Hinge, ...]:
    """Hinges about ``axes`` ("x", "y" or "xy"; drawn when None) with ranges and gears drawn."""
    axes = axes or rng.choice(JOINT_AXES, AXIS_WEIGHTS)
    return tuple(Hinge(a, rng.choice(JOINT_RANGES), rng.choice(GEARS)) for a in axes)


def _sites(u: Unimal) -> list[tuple[int, str]]:
    return [(-1, "torso")] + [(i, s) for i in range(len(u.limbs)) for s in ("mid", "btm")]


def _propose(u: Unimal, rng: Rng, max_limbs: int) -> Unimal | None:
    """One DERL growth proposal (not yet checked for symmetry or contacts), or None."""
    parent, site = rng.choice(_sites(u))
    on_pair = parent >= 0 and u.limbs[parent].mirror >= 0
    if on_pair and u.limbs[parent].mirror < parent:
        parent = u.limbs[parent].mirror  # grow from the lower-numbered side of a pair
    count = 2 if on_pair else rng.choice((1, 2))
    if len(u.limbs) + count > max_limbs:
        return None
    h, theta, phi = rng.choice(LIMB_HEIGHTS), rng.choice(THETAS), rng.choice(PHIS)
    hinges = sample_hinges(rng)
    if count == 2 and not on_pair and theta > 180:
        theta = 360 - theta
    first = Limb(parent, site, h, theta, phi, hinges)
    if parent >= 0 and site == "mid" and same_orient(first, u.limbs[parent]):
        return None
    n = len(u.limbs)
    if count == 1:
        return replace(u, limbs=(*u.limbs, first))
    if on_pair:
        second = replace(first, parent=u.limbs[parent].mirror)
    else:
        if theta in (0, 180) or phi == 180:
            return None
        second = replace(first, theta=360 - theta)
    return replace(u, limbs=(*u.limbs, replace(first, mirror=n + 1), replace(second, mirror=n)))


def grow(u: Unimal, rng: Rng, max_limbs: int = MAX_LIMBS) -> Unimal:
    """``u`` with one limb or pair grown; :class:`GrowthError` if no attempt was valid."""
    for _ in range(GROW_ATTEMPTS):
        new = _propose(u, rng, max_limbs)
        if new is None:
            continue
        try:
            check(new)
        except InvalidUnimal:
            continue
        return new
    raise GrowthError(f"no valid limb could be grown on a {len(u.limbs)}-limb robot")


def generate(seed: int) -> Unimal:
    """A random valid UNIMAL robot, the same for the same seed on every machine."""
    rng = Rng(seed)
    target = rng.choice(LIMB_COUNTS, LIMB_COUNT_WEIGHTS)
    u = Unimal(torso_density=rng.choice(DENSITIES), limb_density=rng.choice(DENSITIES))
    while len(u.limbs) < target:
        try:
            u = grow(u, rng, max_limbs=target)
        except GrowthError:
            if len(u.limbs) >= min(LIMB_COUNTS):
                break
            u = grow(u, rng, max_limbs=MAX_LIMBS)
    return u
