"""Limb-type vocabularies.

Two vocabularies exist:

* the *family-level* type, a 4-slot one-hot inside the 19-d SMPENV limb observation (torso, then
  the 1st, 2nd and 3rd segment of a chain), as in SMP/AMORPHEUS/SWAT;
* the *global* limb-type id, one vocabulary shared by all families; GCNT's GCN and WL modules use
  it, so that a thigh is a thigh whichever robot it belongs to.

SMPENV types are derived from body names, family by family, so that a robot file a user writes by
hand (with the family's naming convention) gets the same types as the generated ones. A limb whose
name says nothing (``toe``, ``b3``, a new segment) is typed by its place in the tree instead: its
segment position along its chain from the torso (1st: thigh, 2nd: shin, 3rd and beyond: foot), so
that a new morphology is never refused for its names. UNIMAL limbs
have no anatomical names (``limb/3``), so their type is their place in the body tree
(:func:`unimal_limb_types`): *proximal* (attached to the torso), *inner* (deeper, with children)
or *distal* (deeper, a leaf). Hip-like, knee-like and foot-like roles, the closest UNIMAL analogue
of thigh/shin/foot, read from the tree alone, so every mutation that keeps the topology keeps the
types.
"""

from __future__ import annotations

import re

#: Global limb-type vocabulary shared by every family. Append only: ids are stored in checkpoints.
GLOBAL_LIMB_TYPES: tuple[str, ...] = (
    "torso",
    "thigh",
    "shin",
    "foot",
    "upper_arm",
    "lower_arm",
    # id 6: a placeholder from before UNIMAL robots were read structurally; no robot gets it now,
    # kept so that no id after it shifts.
    "unimal_limb",
    "unimal_proximal",
    "unimal_inner",
    "unimal_distal",
)
GLOBAL_TYPE_ID: dict[str, int] = {name: i for i, name in enumerate(GLOBAL_LIMB_TYPES)}

#: Number of slots of the family-level one-hot in the SMPENV observation.
FAMILY_TYPE_SLOTS = 4

#: Most bodies (torso included) a robot of the family may have; families not listed: no limit.
MAX_LIMBS: dict[str, int] = {"unimal": 12}

#: Families and the most hinge joints one of their limbs may carry.
MAX_JOINTS_PER_LIMB: dict[str, int] = {
    "walker": 1,
    "cheetah": 1,
    "hopper": 1,
    "humanoid": 1,
    "unimal": 2,
    # general 3-D robots: any free-floating tree of bodies, up to three hinges per limb
    "mjcf3d": 3,
}
FAMILIES: tuple[str, ...] = tuple(MAX_JOINTS_PER_LIMB)
#: Families of 2-D robots on a planar root (slide x, slide z, hinge y).
PLANAR_FAMILIES: tuple[str, ...] = ("walker", "cheetah", "hopper", "humanoid")

# (regex on the body name, global type, family-level slot); first match wins.
_RULES: dict[str, tuple[tuple[str, str, int], ...]] = {
    # walker limbs are left1/left2/left3, right1/... : segment k of a leg
    "walker": ((r"1$", "thigh", 1), (r"2$", "shin", 2), (r"3$", "foot", 3)),
    "cheetah": ((r"thigh$", "thigh", 1), (r"shin$", "shin", 2), (r"foot$", "foot", 3)),
    # hopper: lower_leg counts as leg (spec); leg is the shin of the chain
    "hopper": ((r"thigh$", "thigh", 1), (r"leg$", "shin", 2), (r"foot$", "foot", 3)),
    # humanoid: 4 real types; the family slot is the segment position in its chain
    # (thigh/upper arm 1st, shin/lower arm 2nd), see README "Deviations".
    "humanoid": (
        (r"thigh$", "thigh", 1),
        (r"shin$", "shin", 2),
        (r"upper_arm$", "upper_arm", 1),
        (r"lower_arm$", "lower_arm", 2),
    ),
}


#: global type of the 1st, 2nd and 3rd-or-deeper segment of a chain from the torso
_BY_SEGMENT: tuple[str, ...] = ("thigh", "shin", "foot")


class UnknownLimbError(ValueError):
    """A body name matches no limb type of its family (and no segment position was given)."""


def limb_type(
    family: str, body_name: str, is_root: bool, segment: int | None = None
) -> tuple[int, int]:
    """Return ``(global_type_id, family_slot)`` of a body of ``family``: from its name, or, when
    the name matches no rule of the family, from ``segment`` (its depth below the torso, >= 1)."""
    if is_root:
        return GLOBAL_TYPE_ID["torso"], 0
    if family not in _RULES:
        raise ValueError(f"unknown robot family {family!r}; known: {', '.join(FAMILIES)}")
    for pattern, gtype, slot in _RULES[family]:
        if re.search(pattern, body_name):
            return GLOBAL_TYPE_ID[gtype], slot
    if segment is not None and segment >= 1:
        k = min(segment, len(_BY_SEGMENT))
        return GLOBAL_TYPE_ID[_BY_SEGMENT[k - 1]], k
    raise UnknownLimbError(
        f"body {body_name!r} matches no limb type of family {family!r} "
        f"(expected names ending in: {', '.join(p for p, _, _ in _RULES[family])})"
    )


def unimal_limb_types(parents: list[int] | tuple[int, ...]) -> list[tuple[int, int]]:
    """``(global_type_id, family_slot)`` of every body of a UNIMAL tree (pre-order parents).

    Torso 0; proximal (child of the torso) slot 1; inner (deeper, has children) slot 2; distal
    (deeper, a leaf) slot 3.
    """
    has_kids = {p for p in parents if p >= 0}
    out: list[tuple[int, int]] = []
    for i, p in enumerate(parents):
        if p < 0:
            out.append((GLOBAL_TYPE_ID["torso"], 0))
        elif p == 0:
            out.append((GLOBAL_TYPE_ID["unimal_proximal"], 1))
        elif i in has_kids:
            out.append((GLOBAL_TYPE_ID["unimal_inner"], 2))
        else:
            out.append((GLOBAL_TYPE_ID["unimal_distal"], 3))
    return out
