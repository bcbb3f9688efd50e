"""DERL's mutation operators on UNIMAL genotypes, and the zero-shot variant sets built from them.

Operators (each returns a new valid robot that differs from its input):

* ``grow_limb``: grow one limb or mirrored pair (as the generator does);
* ``delete_limb``: remove one leaf group (a leaf limb, or a pair of leaves);
* ``limb_length``: redraw h of one group (the only change to the robot's rest geometry);
* ``joint_angle``, ``dof``, ``gear``: redraw joint ranges / joint axes (with their ranges and
  gears) / gears of every group with probability 1/2, else of one group;
* ``density``: redraw both the torso and the limb density;
* ``armature``, ``damping`` (not DERL operators; for the dynamics variants): set the joints'
  armature / damping, scope as ``gear``, to a value of :data:`ARMATURES` / :data:`DAMPINGS`.

All but ``grow_limb``, ``delete_limb`` and ``dof`` keep the topology and the joints (the body tree,
each limb's hinges and so its action slots).

Variant sets (per training robot; no public code builds them, these follow the paper's two kinds):
dynamics = one variant each by ``armature``, ``damping``, ``gear``, ``density``; kinematics = two by
``limb_length`` and two by ``joint_angle``. A variant is named ``<robot>-<operator><k>`` and drawn
from a stream seeded by that name, so it is the same everywhere.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

from gcnt.morphology.unimal.generate import GrowthError, grow, sample_hinges
from gcnt.morphology.unimal.mjcf import InvalidUnimal, check
from gcnt.morphology.unimal.space import (
    DENSITIES,
    GEARS,
    JOINT_RANGES,
    LIMB_HEIGHTS,
    Hinge,
    Limb,
    Rng,
    Unimal,
)

ARMATURES: tuple[float, ...] = (0.1, 0.25, 0.5, 2.0, 3.0)
DAMPINGS: tuple[float, ...] = (0.1, 0.25, 0.5, 2.0, 3.0)
#: Draws before an operator gives up finding a valid, different robot.
TRIES = 50

Operator = Callable[[Unimal, Rng], Unimal]


class MutationError(ValueError):
    """An operator found no valid change (e.g. ``delete_limb`` on a one-group robot)."""


def _scope(u: Unimal, rng: Rng) -> list[tuple[int, ...]]:
    groups = u.groups()
    return groups if rng.coin() else [rng.choice(groups)]


def _map_hinges(u: Unimal, groups: list[tuple[int, ...]], fn: Callable[[Limb], tuple[Hinge, ...]]):
    new: dict[int, Limb] = {}
    for group in groups:
        hinges = fn(u.limbs[group[0]])  # one draw per group: a pair stays mirrored
        for i in group:
            new[i] = replace(u.limbs[i], hinges=hinges)
    return u.replace_limbs(new)


def _redraw(field: str, values: tuple) -> Operator:
    """The operator that redraws hinge attribute ``field`` from ``values`` (scope: _scope)."""

    def op(u: Unimal, rng: Rng) -> Unimal:
        return _map_hinges(
            u,
            _scope(u, rng),
            lambda lb: tuple(replace(h, **{field: rng.choice(values)}) for h in lb.hinges),
        )

    return op


_joint_angle = _redraw("range", JOINT_RANGES)
_gear = _redraw("gear", GEARS)
_armature = _redraw("armature", ARMATURES)
_damping = _redraw("damping", DAMPINGS)


def _dof(u: Unimal, rng: Rng) -> Unimal:
    return _map_hinges(u, _scope(u, rng), lambda lb: sample_hinges(rng))


def _density(u: Unimal, rng: Rng) -> Unimal:
    return replace(u, torso_density=rng.choice(DENSITIES), limb_density=rng.choice(DENSITIES))


def _limb_length(u: Unimal, rng: Rng) -> Unimal:
    group = rng.choice(u.groups())
    h = rng.choice(LIMB_HEIGHTS)
    return u.replace_limbs({i: replace(u.limbs[i], h=h) for i in group})


def _grow_limb(u: Unimal, rng: Rng) -> Unimal:
    try:
        return grow(u, rng)
    except GrowthError as e:
        raise MutationError(str(e)) from e


def _delete_limb(u: Unimal, rng: Rng) -> Unimal:
    leaves = [g for g in u.groups() if not any(u.children(i) for i in g)]
    if len(u.groups()) < 2 or not leaves:
        raise MutationError("delete_limb needs a leaf group and at least one other group")
    gone = set(rng.choice(leaves))
    keep = [i for i in range(len(u.limbs)) if i not in gone]
    new_index = {old: new for new, old in enumerate(keep)}
    new_index[-1] = -1
    limbs = tuple(
        replace(
            u.limbs[i],
            parent=new_index[u.limbs[i].parent],
            mirror=new_index[u.limbs[i].mirror] if u.limbs[i].mirror >= 0 else -1,
        )
        for i in keep
    )
    return replace(u, limbs=limbs)


OPERATORS: dict[str, Operator] = {
    "grow_limb": _grow_limb,
    "delete_limb": _delete_limb,
    "limb_length": _limb_length,
    "joint_angle": _joint_angle,
    "dof": _dof,
    "density": _density,
    "gear": _gear,
    "armature": _armature,
    "damping": _damping,
}
#: Operators that keep the body tree and every limb's hinges.
TOPOLOGY_KEEPING = ("limb_length", "joint_angle", "density", "gear", "armature", "damping")


def mutate(u: Unimal, op: str, rng: Rng) -> Unimal:
    """``u`` changed by operator ``op``: valid (symmetric, contact-free) and different from ``u``."""
    if op not in OPERATORS:
        from gcnt.suggest import did_you_mean

        raise ValueError(f"unknown mutation {op!r}{did_you_mean(op, OPERATORS)}")
    for _ in range(TRIES):
        try:
            new = OPERATORS[op](u, rng)
        except MutationError:
            continue
        if new == u:
            continue
        try:
            check(new)
        except InvalidUnimal:
            continue
        return replace(new, notes=(*u.notes, op))
    raise MutationError(f"{op}: no valid change found in {TRIES} draws")


#: Variant kinds: split suffix -> the variants of one training robot as (name suffix, operator).
VARIANTS: dict[str, tuple[tuple[str, str], ...]] = {
    "dynamics": (
        ("armature1", "armature"), ("damping1", "damping"), ("gear1", "gear"),
        ("density1", "density"),
    ),
    "kinematics": (
        ("length1", "limb_length"), ("length2", "limb_length"), ("range1", "joint_angle"),
        ("range2", "joint_angle"),
    ),
}  # fmt: skip


def variant_names(robot: str, kind: str) -> list[str]:
    return [f"{robot}-{suffix}" for suffix, _ in VARIANTS[kind]]


def variant_operator(suffix: str) -> str | None:
    """The operator of a variant name suffix (``gear1`` -> ``gear``), or None."""
    for pairs in VARIANTS.values():
        for s, op in pairs:
            if s == suffix:
                return op
    return None


def make_variant(u: Unimal, variant_name: str) -> Unimal:
    """The variant ``<robot>-<suffix>`` of ``u`` (deterministic in the name)."""
    suffix = variant_name.rpartition("-")[2]
    op = variant_operator(suffix)
    if op is None:
        raise ValueError(f"{variant_name!r} names no variant kind")
    return mutate(u, op, Rng(variant_name))
