"""The 32 SMPENV robots, built as MJCF with dm_control's ``mjcf`` module.

Four families: walker, cheetah (gym's half-cheetah), humanoid_2d and hopper. Each family has one
full robot, described below as a tree of :class:`_Body` records whose numbers are those of the
original SMP robot files; every variant is that tree with whole limb subtrees
removed, nothing else changed. The hoppers are three separate trees (3, 4 and 5 bodies).

Geometry is written as MuJoCo compiles it: capsules that the originals describe by their end points
are written with ``fromto`` where that reproduces the tables exactly (walker, hopper) and with
explicit ``size``/``pos``/``quat`` where the originals' rounded numbers are the facts (humanoid,
cheetah). Angles are radians. Masses follow from the geoms at density 1000.

The generated text is deterministic: every element that could otherwise get a generated name is
named, there are no assets, and floats are printed with a fixed precision.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, replace
from pathlib import Path

from dm_control import mjcf

from gcnt.files import write_text
from gcnt.suggest import did_you_mean

#: Digits used when printing floats into the XML (every number in the tables has at most 7).
_PRECISION = 10

Vec = tuple[float, ...]


@dataclass(frozen=True)
class _Geom:
    name: str
    type: str
    size: Vec
    pos: Vec | None = None
    quat: Vec | None = None
    fromto: Vec | None = None
    friction: Vec | None = None  # None: the family's default


@dataclass(frozen=True)
class _Joint:
    """A limb's hinge and its motor."""

    name: str
    axis: Vec
    range: Vec
    gear: float
    pos: Vec = (0.0, 0.0, 0.0)
    stiffness: float = 0.0
    damping: float = 0.0
    armature: float = 0.0


@dataclass(frozen=True)
class _RootJoint:
    name: str
    type: str  # "slide" or "hinge"
    axis: Vec
    pos: Vec = (0.0, 0.0, 0.0)
    ref: float = 0.0
    armature: float = 0.0


@dataclass(frozen=True)
class _Body:
    name: str
    pos: Vec
    geoms: tuple[_Geom, ...]
    joint: _Joint | None = None  # None only for the torso
    children: tuple[_Body, ...] = ()

    def without(self, removed: set[str]) -> _Body:
        """This tree with the subtrees rooted at the bodies named in ``removed`` cut off."""
        kept = tuple(c.without(removed) for c in self.children if c.name not in removed)
        return replace(self, children=kept)

    def names(self) -> list[str]:
        out = [self.name]
        for c in self.children:
            out.extend(c.names())
        return out


@dataclass(frozen=True)
class _Family:
    """Settings shared by every robot of a family."""

    name: str  # the family name that gcnt.morphology uses ("humanoid" for humanoid_2d)
    timestep: float
    integrator: str
    floor_size: float  # half-extent of the floor plane, metres
    floor_friction: Vec
    geom_friction: Vec
    geom_contype: int
    geom_conaffinity: int
    geom_condim: int
    geom_solimp: Vec
    joint_solimplimit: Vec
    root_joints: tuple[_RootJoint, ...]
    geom_margin: float = 0.0
    geom_solref: Vec = (0.02, 1.0)
    joint_solreflimit: Vec = (0.02, 1.0)
    camera_distance: float = 4.0


_Z = (0.0, 0.0, 0.0)
_AXIS_X = (1.0, 0.0, 0.0)
_AXIS_Y = (0.0, 1.0, 0.0)
_AXIS_Z = (0.0, 0.0, 1.0)
_AXIS_NEG_Y = (0.0, -1.0, 0.0)
_DEFAULT_SOLIMP = (0.9, 0.95, 0.001, 0.5, 2.0)


def _planar_root(x: str, z: str, y: str, slide_pos: Vec, hinge_pos: Vec, ref_z: float,
                 armature: float = 0.0) -> tuple[_RootJoint, ...]:  # fmt: skip
    """The three unactuated root joints: slide x, slide z, hinge y."""
    return (
        _RootJoint(x, "slide", _AXIS_X, slide_pos, 0.0, armature),
        _RootJoint(z, "slide", _AXIS_Z, slide_pos, ref_z, armature),
        _RootJoint(y, "hinge", _AXIS_Y, hinge_pos, 0.0, armature),
    )


# ------------------------------------------------------------------------------------- walker
# Two legs of three segments under a vertical torso; each segment is 0.8 times the one above it
# (length 0.6 -> 0.48 -> 0.384, radius 0.07 -> 0.056 -> 0.0448); the third segment is a foot
# pointing forward. The original names the right leg's first two geoms after their bodies.

_WALKER = _Family(
    name="walker",
    timestep=0.002,
    integrator="RK4",
    floor_size=40.0,
    floor_friction=(0.7, 0.1, 0.1),
    geom_friction=(0.9, 0.1, 0.1),
    geom_contype=1,
    geom_conaffinity=0,
    geom_condim=3,
    geom_solimp=_DEFAULT_SOLIMP,
    joint_solimplimit=_DEFAULT_SOLIMP,
    root_joints=_planar_root("rootx", "rootz", "rooty", (0.0, 0.0, -1.6), (0.0, 0.0, -0.35), 1.25),
)


def _walker_leg(side: str, geom_names: tuple[str, str, str]) -> _Body:
    def joint(i: int) -> _Joint:
        return _Joint(
            f"{side}{i}_joint", _AXIS_NEG_Y, (-1.309, 1.309), 100.0, damping=0.1, armature=0.01
        )

    foot = _Body(
        f"{side}3",
        (0.0, 0.0, -0.384),
        (_Geom(geom_names[2], "capsule", (0.06,), fromto=(0.0, 0.0, 0.0, 0.2, 0.0, 0.0)),),
        joint(3),
    )
    shin = _Body(
        f"{side}2",
        (0.0, 0.0, -0.48),
        (_Geom(geom_names[1], "capsule", (0.0448,), fromto=(0.0, 0.0, 0.0, 0.0, 0.0, -0.384)),),
        joint(2),
        (foot,),
    )
    return _Body(
        f"{side}1",
        (0.0, 0.0, -0.6),
        (_Geom(geom_names[0], "capsule", (0.056,), fromto=(0.0, 0.0, 0.0, 0.0, 0.0, -0.48)),),
        joint(1),
        (shin,),
    )


def _walker_full() -> _Body:
    torso_geom = _Geom("torso_geom", "capsule", (0.07,), fromto=(0.0, 0.0, 0.0, 0.0, 0.0, -0.6))
    return _Body(
        "torso",
        (0.0, 0.0, 1.6),
        (torso_geom,),
        None,
        (
            _walker_leg("left", ("left1_geom", "left2_geom", "left3_geom")),
            _walker_leg("right", ("right1", "right2", "right3_geom")),
        ),
    )


# ------------------------------------------------------------------------------------ cheetah
# Gym's half-cheetah: a horizontal torso with a head, a back and a front leg of thigh, shin and
# foot. Geom axes are tilted about y; quats are the compiled values.

_CHEETAH = _Family(
    name="cheetah",
    timestep=0.01,
    integrator="Euler",
    floor_size=40.0,
    floor_friction=(0.4, 0.1, 0.1),
    geom_friction=(0.4, 0.1, 0.1),
    geom_contype=1,
    geom_conaffinity=0,
    geom_condim=3,
    geom_solimp=(0.0, 0.8, 0.01, 0.5, 2.0),
    joint_solimplimit=(0.0, 0.8, 0.03, 0.5, 2.0),
    root_joints=_planar_root("rootx", "rootz", "rooty", _Z, _Z, 0.0),
    camera_distance=3.0,
)

_CHEETAH_R = 0.046


def _cheetah_segment(
    name: str,
    body_pos: Vec,
    half_len: float,
    geom_pos: Vec,
    geom_quat: Vec,
    rng: Vec,
    stiffness: float,
    damping: float,
    gear: float,
    child: _Body | None = None,
) -> _Body:
    geom = _Geom(name, "capsule", (_CHEETAH_R, half_len), pos=geom_pos, quat=geom_quat)
    joint = _Joint(name, _AXIS_Y, rng, gear, stiffness=stiffness, damping=damping, armature=0.1)
    return _Body(name, body_pos, (geom,), joint, (child,) if child else ())


def _cheetah_full() -> _Body:
    seg = _cheetah_segment
    back = seg(
        "bthigh", (-0.5, 0.0, 0.0), 0.145, (0.1, 0.0, -0.13), (-0.32329, 0.0, -0.9462999, 0.0),
        (-0.52, 1.05), 240.0, 6.0, 120.0,
        seg(
            "bshin", (0.16, 0.0, -0.25), 0.15, (-0.14, 0.0, -0.07), (0.5276198, 0.0, -0.8494806, 0.0),
            (-0.785, 0.785), 180.0, 4.5, 90.0,
            seg(
                "bfoot", (-0.28, 0.0, -0.14), 0.094, (0.03, 0.0, -0.097), (0.9909014, 0.0, -0.13459, 0.0),
                (-0.4, 0.785), 120.0, 3.0, 60.0,
            ),
        ),
    )  # fmt: skip
    front = seg(
        "fthigh", (0.5, 0.0, 0.0), 0.133, (-0.07, 0.0, -0.12), (0.9663899, 0.0, 0.257081, 0.0),
        (-1.0, 0.7), 180.0, 4.5, 120.0,
        seg(
            "fshin", (-0.14, 0.0, -0.24), 0.106, (0.065, 0.0, -0.09), (0.9553365, 0.0, -0.2955202, 0.0),
            (-1.2, 0.87), 120.0, 3.0, 60.0,
            seg(
                "ffoot", (0.13, 0.0, -0.18), 0.07, (0.045, 0.0, -0.07), (0.9553365, 0.0, -0.2955202, 0.0),
                (-0.5, 0.5), 60.0, 1.5, 30.0,
            ),
        ),
    )  # fmt: skip
    torso_geoms = (
        _Geom("torso", "capsule", (_CHEETAH_R, 0.5), pos=_Z, quat=(0.7071068, 0.0, -0.7071068, 0.0)),
        _Geom("head", "capsule", (_CHEETAH_R, 0.15), pos=(0.6, 0.0, 0.1),
              quat=(0.9068702, 0.0, 0.4214101, 0.0)),
    )  # fmt: skip
    return _Body("torso", (0.0, 0.0, 0.7), torso_geoms, None, (back, front))


# -------------------------------------------------------------------------------- humanoid_2d
# The 2-d humanoid: a torso (chest, head, waist, butt) with two legs (thigh, shin with a foot
# sphere) and two arms (upper arm, lower arm with a hand sphere). Its root hinge sits 1.1 m above
# the torso frame, and the left and right joints differ slightly, as in the original.

_HUMANOID = _Family(
    name="humanoid",
    timestep=0.002,
    integrator="RK4",
    floor_size=20.0,
    floor_friction=(0.7, 0.1, 0.1),
    geom_friction=(0.7, 0.1, 0.1),
    geom_contype=1,
    geom_conaffinity=0,
    geom_condim=3,
    geom_solimp=_DEFAULT_SOLIMP,
    joint_solimplimit=_DEFAULT_SOLIMP,
    root_joints=_planar_root(
        "abdomen_x", "abdomen_z", "abdomen_y", _Z, (0.0, 0.0, 1.1), 1.25, armature=0.02
    ),
)

_Q_X90 = (0.7071068, 0.7071068, 0.0, 0.0)  # capsule axis along y


def _humanoid_leg(side: str, sign: float, hip_armature: float, knee_stiffness: float) -> _Body:
    """``sign`` is -1 for the right side (negative y), +1 for the left."""
    shin = _Body(
        f"{side}_shin",
        (0.0, -0.01 * sign, -0.403),
        (
            _Geom(f"{side}_shin1", "capsule", (0.049, 0.15), pos=(0.0, 0.0, -0.15), quat=None),
            _Geom(f"{side}_foot", "sphere", (0.075,), pos=(0.0, 0.0, -0.35)),
        ),
        _Joint(
            f"{side}_knee", _AXIS_NEG_Y, (-2.79253, -0.0349066), 100.0, pos=(0.0, 0.0, 0.02),
            stiffness=knee_stiffness, damping=1.0, armature=0.006,
        ),
    )  # fmt: skip
    return _Body(
        f"{side}_thigh",
        (0.0, 0.1 * sign, -0.465),
        (
            _Geom(f"{side}_thigh1", "capsule", (0.06, 0.170074), pos=(0.0, -0.005 * sign, -0.17),
                  quat=(0.9998919, -0.0147011 * sign, 0.0, 0.0)),
        ),
        _Joint(
            f"{side}_hip_y", _AXIS_Y, (-1.91986, 0.349066), 150.0,
            stiffness=20.0, damping=5.0, armature=hip_armature,
        ),
        (shin,),
    )  # fmt: skip


def _humanoid_arm(side: str, sign: float, shoulder_range: Vec) -> _Body:
    lower = _Body(
        f"{side}_lower_arm",
        (0.18, 0.18 * sign, -0.18),
        (
            _Geom(f"{side}_larm", "capsule", (0.031, 0.138564), pos=(0.09, -0.09 * sign, 0.09),
                  quat=(0.459701, -0.627963 * sign, -0.627963, 0.0)),
            _Geom(f"{side}_hand", "sphere", (0.04,), pos=(0.18, -0.18 * sign, 0.18)),
        ),
        _Joint(f"{side}_elbow", _AXIS_NEG_Y, (-1.5708, 0.872665), 12.5, damping=1.0,
               armature=0.0028),
    )  # fmt: skip
    return _Body(
        f"{side}_upper_arm",
        (0.0, 0.17 * sign, 0.06),
        (
            _Geom(f"{side}_uarm1", "capsule", (0.04, 0.138564), pos=(0.08, 0.08 * sign, -0.08),
                  quat=(0.8880736, 0.3250579 * sign, -0.3250579, 0.0)),
        ),
        _Joint(f"{side}_shoulder1", _AXIS_NEG_Y, shoulder_range, 12.5, stiffness=1.0,
               damping=1.0, armature=0.006),
        (lower,),
    )  # fmt: skip


def _humanoid_full() -> _Body:
    torso_geoms = (
        _Geom("torso1", "capsule", (0.07, 0.07), pos=_Z, quat=_Q_X90),
        _Geom("head", "sphere", (0.09,), pos=(0.0, 0.0, 0.19)),
        _Geom("uwaist", "capsule", (0.06, 0.06), pos=(-0.01, 0.0, -0.12), quat=_Q_X90),
        _Geom("lwaist", "capsule", (0.06, 0.06), pos=(-0.01, 0.0, -0.26), quat=_Q_X90),
        _Geom("butt", "capsule", (0.09, 0.07), pos=(-0.02, 0.0, -0.425), quat=_Q_X90),
    )
    return _Body(
        "torso",
        (0.0, 0.0, 1.4),
        torso_geoms,
        None,
        (
            _humanoid_leg("right", -1.0, hip_armature=0.008, knee_stiffness=0.0),
            _humanoid_leg("left", 1.0, hip_armature=0.01, knee_stiffness=1.0),
            _humanoid_arm("right", -1.0, (-1.48353, 1.0472)),
            _humanoid_arm("left", 1.0, (-1.0472, 1.48353)),
        ),
    )


# ------------------------------------------------------------------------------------- hopper
# Gym's hopper (hopper_4: torso, thigh, leg, foot); hopper_3 has no leg, hopper_5 an extra
# lower_leg and a torso 0.5 m higher. As in gym, the foot's body frame sits at ground level
# (0.13 m forward of the ankle) and its joint and geom are placed relative to that frame.

_HOPPER_FRICTION = (0.9, 0.005, 0.0001)


def _hopper_family(torso_z: float) -> _Family:
    return _Family(
        name="hopper",
        timestep=0.002,
        integrator="RK4",
        floor_size=20.0,
        floor_friction=(1.0, 0.005, 0.0001),
        geom_friction=_HOPPER_FRICTION,
        geom_contype=1,
        geom_conaffinity=1,
        geom_condim=1,
        geom_solimp=(0.8, 0.8, 0.01, 0.5, 2.0),
        geom_margin=0.001,
        joint_solimplimit=_DEFAULT_SOLIMP,
        root_joints=_planar_root("rootx", "rootz", "rooty", (0.0, 0.0, -torso_z), _Z, torso_z),
    )


def _hopper_joint(name: str, rng: Vec, pos: Vec = _Z) -> _Joint:
    return _Joint(name, _AXIS_NEG_Y, rng, 200.0, pos=pos, damping=1.0, armature=1.0)


def _hopper(shank_segments: int) -> tuple[_Family, _Body]:
    """A hopper with 0 (hopper_3), 1 (hopper_4) or 2 (hopper_5) 0.5 m shank segments."""
    knee_range = (-2.61799, 0.0)
    # The ankle is 0.1 m above the foot frame below a shank, at the thigh's lower end (0.6 m
    # above the foot frame) without one.
    ankle_z = 0.1 if shank_segments else 0.6
    foot = _Body(
        "foot",
        (0.13, 0.0, -0.35 if shank_segments else -1.05),
        (
            _Geom("foot_geom", "capsule", (0.06,), friction=(2.0, 0.005, 0.0001),
                  fromto=(-0.26, 0.0, ankle_z, 0.13, 0.0, ankle_z)),
        ),
        _hopper_joint("foot_joint", (-0.785398, 0.785398), (-0.13, 0.0, ankle_z)),
    )  # fmt: skip
    chain = foot
    for name in ("leg", "lower_leg")[:shank_segments][::-1]:
        chain = _Body(
            name,
            (0.0, 0.0, -0.5 if name == "lower_leg" else -0.7),
            (_Geom(f"{name}_geom", "capsule", (0.04,), fromto=(0.0, 0.0, 0.25, 0.0, 0.0, -0.25)),),
            _hopper_joint(f"{name}_joint", knee_range, (0.0, 0.0, 0.25)),
            (chain,),
        )
    thigh = _Body(
        "thigh",
        (0.0, 0.0, -0.2),
        (_Geom("thigh_geom", "capsule", (0.05,), fromto=(0.0, 0.0, 0.0, 0.0, 0.0, -0.45)),),
        _hopper_joint("thigh_joint", knee_range),
        (chain,),
    )
    torso_z = 1.25 + 0.5 * max(shank_segments - 1, 0)
    torso = _Body(
        "torso",
        (0.0, 0.0, torso_z),
        (_Geom("torso_geom", "capsule", (0.05,), fromto=(0.0, 0.0, 0.2, 0.0, 0.0, -0.2)),),
        None,
        (thigh,),
    )
    return _hopper_family(torso_z), torso


# ----------------------------------------------------------------------------------- variants

_WALKER_LEGS = (("left1", "left2", "left3"), ("right1", "right2", "right3"))
_CHEETAH_LEGS = (("bthigh", "bshin", "bfoot"), ("fthigh", "fshin", "ffoot"))


def _cut_chains(chains: Iterable[tuple[str, ...]], kept: Iterable[int]) -> frozenset[str]:
    """Bodies to remove so that only the first ``k`` segments of each chain remain."""
    return frozenset(chain[k] for chain, k in zip(chains, kept, strict=True) if k < len(chain))


# robot name -> (family key, removed subtree roots); segments kept per leg in the comments
_VARIANTS: dict[str, tuple[str, frozenset[str]]] = {
    **{
        f"walker_{n}_main": ("walker", _cut_chains(_WALKER_LEGS, kept))
        for n, kept in {2: (1, 0), 3: (1, 1), 4: (2, 1), 5: (2, 2), 6: (3, 2), 7: (3, 3)}.items()
    },
    **{
        f"cheetah_{suffix}": ("cheetah", _cut_chains(_CHEETAH_LEGS, kept))
        for suffix, kept in {  # (back, front)
            "2_back": (1, 0),
            "2_front": (0, 1),
            "3_back": (2, 0),
            "3_front": (0, 2),
            "3_balanced": (1, 1),
            "4_allback": (3, 0),
            "4_allfront": (0, 3),
            "4_back": (2, 1),
            "4_front": (1, 2),
            "5_back": (3, 1),
            "5_balanced": (2, 2),
            "5_front": (1, 3),
            "6_back": (3, 2),
            "6_front": (2, 3),
            "7_full": (3, 3),
        }.items()
    },
    # humanoid_2d: the name says which part is removed
    **{
        f"humanoid_2d_{suffix}": ("humanoid_2d", frozenset(removed))
        for suffix, removed in {
            "7_left_arm": {"left_upper_arm"},
            "7_right_arm": {"right_upper_arm"},
            "7_lower_arms": {"left_lower_arm", "right_lower_arm"},
            "7_left_leg": {"left_thigh"},
            "7_right_leg": {"right_thigh"},
            "8_left_knee": {"left_shin"},
            "8_right_knee": {"right_shin"},
            "9_full": set(),
        }.items()
    },
    "hopper_3": ("hopper_3", frozenset()),
    "hopper_4": ("hopper_4", frozenset()),
    "hopper_5": ("hopper_5", frozenset()),
}

#: The 32 SMPENV robot names.
SMPENV_ROBOTS: tuple[str, ...] = tuple(_VARIANTS)

#: The robots with every limb of their family; the others are these with subtrees removed.
SMPENV_FULL_ROBOTS: dict[str, str] = {
    "walker": "walker_7_main",
    "cheetah": "cheetah_7_full",
    "humanoid_2d": "humanoid_2d_9_full",
    "hopper_3": "hopper_3",
    "hopper_4": "hopper_4",
    "hopper_5": "hopper_5",
}


def _full_robot(key: str) -> tuple[_Family, _Body]:
    if key == "walker":
        return _WALKER, _walker_full()
    if key == "cheetah":
        return _CHEETAH, _cheetah_full()
    if key == "humanoid_2d":
        return _HUMANOID, _humanoid_full()
    return _hopper(int(key.removeprefix("hopper_")) - 3)


def full_robot_of(name: str) -> str:
    """The name of the full robot that the SMPENV robot ``name`` is cut from."""
    return SMPENV_FULL_ROBOTS[_variant(name)[0]]


def _variant(name: str) -> tuple[str, frozenset[str]]:
    try:
        return _VARIANTS[name]
    except KeyError:
        raise ValueError(
            f"unknown SMPENV robot {name!r}{did_you_mean(name, SMPENV_ROBOTS)} "
            f"(known: {', '.join(SMPENV_ROBOTS)})"
        ) from None


# -------------------------------------------------------------------------------------- MJCF


def _add_body(parent: mjcf.Element, body: _Body, fam: _Family, motors: list[_Joint]) -> None:
    el = parent.add("body", name=body.name, pos=body.pos)
    if body.joint is None:  # the torso: planar root joints, tracking camera and light
        for rj in fam.root_joints:
            el.add(
                "joint", name=rj.name, type=rj.type, axis=rj.axis, pos=rj.pos, ref=rj.ref,
                armature=rj.armature, stiffness=0.0, damping=0.0, limited=False,
            )  # fmt: skip
        d = fam.camera_distance
        el.add("camera", name="track", mode="trackcom", pos=(0.0, -d, 0.0),
               xyaxes=(1.0, 0.0, 0.0, 0.0, 0.0, 1.0))  # fmt: skip
        el.add("light", name="light", mode="trackcom", pos=(0.0, 0.0, 4.0),
               dir=(0.0, 0.0, -1.0))  # fmt: skip
    else:
        j = body.joint
        el.add(
            "joint", name=j.name, type="hinge", axis=j.axis, pos=j.pos, range=j.range,
            limited=True, ref=0.0, stiffness=j.stiffness, damping=j.damping, armature=j.armature,
        )  # fmt: skip
        motors.append(j)
    for g in body.geoms:
        attrs: dict[str, object] = {"name": g.name, "type": g.type, "size": g.size}
        for key in ("fromto", "pos", "quat", "friction"):
            if getattr(g, key) is not None:
                attrs[key] = getattr(g, key)
        el.add("geom", **attrs)
    for child in body.children:
        _add_body(el, child, fam, motors)


def _model(name: str, fam: _Family, torso: _Body) -> mjcf.RootElement:
    root = mjcf.RootElement(model=name)
    root.compiler.angle = "radian"
    root.compiler.inertiafromgeom = True
    root.option.timestep = fam.timestep
    root.option.integrator = fam.integrator
    root.default.geom.set_attributes(
        density=1000.0,
        friction=fam.geom_friction,
        contype=fam.geom_contype,
        conaffinity=fam.geom_conaffinity,
        condim=fam.geom_condim,
        solref=fam.geom_solref,
        solimp=fam.geom_solimp,
        margin=fam.geom_margin,
        rgba=(0.8, 0.6, 0.4, 1.0),
    )
    root.default.joint.set_attributes(
        solreflimit=fam.joint_solreflimit, solimplimit=fam.joint_solimplimit
    )
    root.default.motor.set_attributes(ctrllimited=True, ctrlrange=(-1.0, 1.0))
    root.custom.add("text", name="gcnt_family", data=fam.name)
    root.visual.headlight.set_attributes(ambient=(0.4, 0.4, 0.4), diffuse=(0.6, 0.6, 0.6))
    root.worldbody.add(
        "geom", name="floor", type="plane", size=(fam.floor_size, fam.floor_size, 0.1),
        friction=fam.floor_friction, contype=1, conaffinity=1, condim=3,
        rgba=(0.55, 0.6, 0.65, 1.0),
    )  # fmt: skip
    motors: list[_Joint] = []
    _add_body(root.worldbody, torso, fam, motors)
    for j in motors:
        root.actuator.add("motor", name=j.name, joint=j.name, gear=(j.gear,))
    return root


def build_mjcf(name: str) -> str:
    """The MJCF text of the SMPENV robot ``name`` (deterministic)."""
    key, removed = _variant(name)
    fam, torso = _full_robot(key)
    text = _model(name, fam, torso.without(set(removed))).to_xml_string(precision=_PRECISION)
    return text if text.endswith("\n") else text + "\n"


def body_names(name: str) -> list[str]:
    """The bodies of SMPENV robot ``name`` in depth-first pre-order, torso first."""
    key, removed = _variant(name)
    return _full_robot(key)[1].without(set(removed)).names()


def write_all(out_dir: Path) -> list[Path]:
    """Write ``<out_dir>/<name>.xml`` for all 32 robots; return the paths."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for name in SMPENV_ROBOTS:
        path = out_dir / f"{name}.xml"
        write_text(path, build_mjcf(name))
        paths.append(path)
    return paths
