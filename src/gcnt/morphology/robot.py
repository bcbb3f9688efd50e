"""A robot as data: its limbs in depth-first pre-order, their parents, joints, motors and types.

Read from MJCF through MuJoCo's own compiler, so that what the policy sees is what the simulator
steps. Every malformed file raises :class:`RobotFileError` naming the file and the culprit.

One loader serves every family. What differs per family is said in one place each: the most
hinges per limb and bodies per robot (``limb_types``), the root joint (UNIMAL and general 3-D
robots: one free joint), the limb types (SMPENV: from body names; UNIMAL and 3-D: from the tree)
and the action slot of each joint (SMPENV and 3-D: joint order; UNIMAL: slot 0 = the hinge about
the limb's x axis, slot 1 = about its y axis, decided from the joint axis as written in the file,
seen in the frame of the limb's capsule).

The family is read from the structure (:func:`_family_of`): a root body on a planar root (slide
x, slide z, hinge y, any order) is a 2-D robot, whose family (walker, cheetah, hopper or humanoid:
SMPENV's task rules) is hinted by the model name or file name and is ``cheetah`` when neither
names one (the family whose rules assume nothing of the robot's posture: no termination); a root
body on one free joint is a 3-D robot: ``unimal`` for UNIMAL files (a ``torso/0`` body or a model
name starting with ``unimal``), else ``mjcf3d``, the general 3-D family. A
``<custom><text name="gcnt_family" data=...>`` entry names the family outright.

A ``mjcf3d`` limb is a body with hinge joints (up to three); a body without joints is welded to
its parent and belongs to its parent's limb (a head on a torso, a hand on a forearm).

Refused, in one line naming the element, for every family: an actuator on a tendon (dm_control's
quadruped drives each leg through fixed tendons; gcnt's policies output one torque per hinge, and
a tendon moves several hinges at once), equality constraints (closed loops), joints other than
hinges on limbs (ball, slide), servos.
"""

from __future__ import annotations

import functools
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from gcnt.files import MiB, read_regular
from gcnt.morphology.graph import WL_BUCKETS, WL_ROUNDS, RobotGraph
from gcnt.morphology.limb_types import (
    FAMILIES,
    MAX_JOINTS_PER_LIMB,
    MAX_LIMBS,
    PLANAR_FAMILIES,
    UnknownLimbError,
    limb_type,
    unimal_limb_types,
)

#: MJCF ``<custom><text name=...>`` entry that names a robot's family explicitly.
FAMILY_TEXT = "gcnt_family"
#: The torso body of every UNIMAL file; a file with it is a UNIMAL robot whatever its model name.
UNIMAL_TORSO = "torso/0"
#: Families whose limbs carry up to two hinges put in action slots by axis (x -> 0, y -> 1).
_SLOT_BY_AXIS = frozenset({"unimal"})
#: Families whose root must be one free joint.
_FREE_ROOT = frozenset({"unimal", "mjcf3d"})
#: Families whose limbs are typed by their place in the tree (proximal, inner, distal).
_TREE_TYPES = frozenset({"unimal", "mjcf3d"})
#: Families in which a body without joints is welded to its parent's limb.
_WELDED_BODIES = frozenset({"mjcf3d"})
#: The catalogue of a robot file loaded by path, by family (others: "smpenv").
_CATALOGUE_OF_FAMILY = {"unimal": "unimal", "mjcf3d": "mjcf3d"}
#: A planar robot whose names hint at no family gets this one (its rules never terminate).
PLANAR_FALLBACK = "cheetah"


class RobotFileError(ValueError):
    """A robot file that cannot be used; the message names the file and the problem."""


@dataclass(frozen=True, eq=False)
class Robot:
    """One robot morphology. Limb 0 is the torso; ``parents[0] == -1``."""

    name: str
    family: str
    source: str  # file path, or "<string>"
    xml: str = field(repr=False)  # the MJCF text, so a Robot can be rebuilt in another process
    body_names: tuple[str, ...]
    parents: np.ndarray  # int64 [K]
    mj_body_ids: np.ndarray  # int64 [K]   MuJoCo body id of each limb
    joint_names: tuple[tuple[str, ...], ...]  # hinge joints of each limb (torso: none)
    mj_joint_ids: tuple[tuple[int, ...], ...]
    actuator_ids: tuple[tuple[int, ...], ...]  # motor of each joint, same order
    joint_ranges: tuple[np.ndarray, ...]  # [n_joints, 2] radians
    global_types: np.ndarray  # int64 [K]
    family_slots: np.ndarray  # int64 [K]
    #: action slot of each joint of each limb (same order as ``joint_names``); empty: slots
    #: 0, 1, ... in joint order. UNIMAL limbs put their x hinge in slot 0 and y hinge in slot 1.
    joint_slots: tuple[tuple[int, ...], ...] = ()
    #: the robot catalogue the robot came from, e.g. "smpenv" or "unimal" (a file loaded by path:
    #: the catalogue of its family)
    catalogue: str = "smpenv"

    def action_slots(self, limb: int) -> tuple[int, ...]:
        """Action slot of each joint of ``limb``."""
        if self.joint_slots:
            return self.joint_slots[limb]
        return tuple(range(len(self.actuator_ids[limb])))

    @property
    def num_limbs(self) -> int:
        return len(self.body_names)

    @property
    def num_motors(self) -> int:
        return sum(len(a) for a in self.actuator_ids)

    @property
    def max_joints_per_limb(self) -> int:
        return MAX_JOINTS_PER_LIMB[self.family]

    @functools.cached_property
    def graph(self) -> RobotGraph:
        return RobotGraph.from_tree(self.parents, self.global_types, WL_ROUNDS, WL_BUCKETS)

    def compile(self) -> mujoco.MjModel:
        """A fresh MjModel of this robot (each env instance owns its own)."""
        return mujoco.MjModel.from_xml_string(self.xml)

    def __repr__(self) -> str:
        return f"Robot({self.name!r}, family={self.family!r}, limbs={self.num_limbs})"


def _root_kind(model: mujoco.MjModel, body: int) -> str | None:
    """The root body's joints: "free" (one free joint), "planar" (slide x, slide z and hinge y,
    in any order) or None (anything else)."""
    start, num = int(model.body_jntadr[body]), int(model.body_jntnum[body])
    types = [int(model.jnt_type[j]) for j in range(start, start + num)]
    if types == [mujoco.mjtJoint.mjJNT_FREE]:
        return "free"
    found = set()
    for j in range(start, start + num):
        axis = tuple(np.round(np.abs(model.jnt_axis[j]), 6))
        if types[j - start] == mujoco.mjtJoint.mjJNT_SLIDE and axis in ((1, 0, 0), (0, 0, 1)):
            found.add(("slide", axis))
        elif types[j - start] == mujoco.mjtJoint.mjJNT_HINGE and axis == (0, 1, 0):
            found.add(("hinge", axis))
    return "planar" if num == 3 and len(found) == 3 else None


def _family_of(
    model: mujoco.MjModel, root: ET.Element, source: str, body: int, family: str | None
) -> str:
    """The robot family: ``family`` or the file's family tag if given, else from the structure
    of the root body ``body`` with the names as hints (see the module doc)."""
    for el in root.iter("text"):
        if family is None and el.get("name") == FAMILY_TEXT:
            family = el.get("data", "")
    if family is not None:
        if family not in FAMILIES:
            raise RobotFileError(
                f"{source}: unknown robot family {family!r}; known: {', '.join(FAMILIES)}"
            )
        return family
    name = root.get("model", "") or Path(source).stem
    if any(el.get("name") == UNIMAL_TORSO for el in root.iter("body")):
        return "unimal"
    kind = _root_kind(model, body)
    if kind == "free":
        return "unimal" if name.startswith("unimal") else "mjcf3d"
    if kind == "planar":
        hints = f"{name} {Path(source).stem}".lower()
        return next((fam for fam in PLANAR_FAMILIES if fam in hints), PLANAR_FALLBACK)
    for fam in FAMILIES:
        if name.startswith(fam):
            return fam
    start, num = int(model.body_jntadr[body]), int(model.body_jntnum[body])
    joints = [model.joint(j).name or f"#{j}" for j in range(start, start + num)]
    raise RobotFileError(
        f"{source}: cannot tell the robot family of model {name!r}: its root body "
        f"{model.body(body).name!r} has joints {joints}, neither one free joint (a 3-D robot) nor "
        f"slide x, slide z and hinge y (a 2-D robot); start the model name with one of "
        f'{", ".join(FAMILIES)} or add <custom><text name="{FAMILY_TEXT}" data=...>'
    )


def load_robot(path: str | Path, catalogue: str | None = None, family: str | None = None) -> Robot:
    """Read a robot from an MJCF file (``catalogue``, ``family``: see :func:`robot_from_xml`)."""
    path = Path(path)
    text = _read_text(path, str(path))
    return robot_from_xml(
        text,
        source=str(path),
        name=path.stem,
        catalogue=catalogue,
        folder=path.parent,
        family=family,
    )


#: the largest robot file read: MJCF robots are kilobytes (a humanoid with meshes referenced,
#: not inlined, is under 100 KiB)
MAX_ROBOT_FILE_BYTES = 16 * MiB


def _read_text(path: Path, source: str) -> str:
    what = "a robot file is MJCF XML" + (f" ({source})" if source != str(path) else "")
    data = read_regular(path, MAX_ROBOT_FILE_BYTES, what, RobotFileError)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise RobotFileError(f"{source}: not a text file (a robot file is MJCF XML)") from None


#: attributes of <compiler> that prefix relative asset file names, by asset tag
_ASSET_DIRS = {"texture": ("texturedir", "assetdir")}
_DEFAULT_ASSET_DIRS = ("meshdir", "assetdir")


def _inside(folder: Path, name: str, what: str, source: str) -> Path:
    """``folder/name``, refused if ``name`` is absolute or leads out of ``folder``."""
    if Path(name).is_absolute():
        raise RobotFileError(
            f"{source}: {what} {name!r} is an absolute path; a robot file may only use files in "
            f"its own folder ({folder})"
        )
    path = (folder / name).resolve()
    if not path.is_relative_to(folder.resolve()):
        raise RobotFileError(
            f"{source}: {what} {name!r} leads out of the robot's folder ({folder})"
        )
    return path


def _resolve_files(root: ET.Element, folder: Path | None, source: str, depth: int = 0) -> bool:
    """Inline every ``<include>`` and make asset file names absolute, both resolved against the
    robot file's ``folder`` (not the current directory) and refused if they leave it. True if
    the tree changed."""
    includes = [(p, c) for p in root.iter() for c in p if c.tag == "include"]
    compiler = root.find("compiler")
    assets = [el for el in root.iter() if el.tag != "include" and el.get("file")]
    if not includes and not assets:
        return False
    if folder is None:
        raise RobotFileError(
            f"{source}: <include> and asset files need the robot file's folder; load it from its "
            "file"
        )
    if depth > 8:
        raise RobotFileError(f"{source}: <include> files nest too deep (a cycle?)")
    for parent, inc in includes:
        name = inc.get("file") or ""
        path = _inside(folder, name, "<include> file", source)
        try:
            inner = ET.fromstring(_read_text(path, f"{source}: <include> {name!r}"))
        except ET.ParseError as e:
            raise RobotFileError(f"{source}: <include> {name!r} is not valid XML ({e})") from None
        if inner.tag != "mujoco":
            raise RobotFileError(f"{source}: <include> {name!r} must have a <mujoco> root")
        _resolve_files(inner, folder, source, depth + 1)
        at = list(parent).index(inc)
        parent.remove(inc)
        for k, el in enumerate(list(inner)):
            parent.insert(at + k, el)
    for el in assets:
        dirs = _ASSET_DIRS.get(el.tag, _DEFAULT_ASSET_DIRS)
        prefix = next(
            (compiler.get(d) for d in dirs if compiler is not None and compiler.get(d)), ""
        )
        name = str(Path(prefix) / el.get("file")) if prefix else el.get("file")
        el.set("file", str(_inside(folder, name, f"{el.tag} file", source)))
    return True


#: (array, element kind, only where this boolean array is set) checked for NaN and infinity
_FINITE_FIELDS = (
    ("body_pos", "body", None),
    ("body_quat", "body", None),
    ("body_ipos", "body", None),
    ("body_iquat", "body", None),
    ("body_mass", "body", None),
    ("body_inertia", "body", None),
    ("geom_size", "geom", None),
    ("geom_pos", "geom", None),
    ("geom_quat", "geom", None),
    ("geom_friction", "geom", None),
    ("jnt_pos", "joint", None),
    ("jnt_axis", "joint", None),
    ("jnt_range", "joint", "jnt_limited"),
    ("jnt_stiffness", "joint", None),
    ("dof_damping", "dof", None),
    ("dof_armature", "dof", None),
    ("dof_frictionloss", "dof", None),
    ("actuator_gear", "actuator", None),
    ("actuator_gainprm", "actuator", None),
    ("actuator_ctrlrange", "actuator", "actuator_ctrllimited"),
)


def _check_finite(model: mujoco.MjModel, source: str) -> None:
    """NaN or infinite numbers compile, then blow the physics up: name the element instead."""
    for field_name, kind, limited in _FINITE_FIELDS:
        values = np.asarray(getattr(model, field_name))
        if values.size == 0:
            continue
        bad = ~np.isfinite(values.reshape(len(values), -1)).all(axis=1)
        if limited is not None:
            bad &= np.asarray(getattr(model, limited)).astype(bool).reshape(-1)
        if not bad.any():
            continue
        i = int(np.nonzero(bad)[0][0])
        if kind == "dof":
            kind, i = "joint", int(model.dof_jntid[i])
        name = getattr(model, kind)(i).name or f"#{i}"
        raise RobotFileError(
            f"{source}: {kind} {name!r} has a non-finite {field_name.split('_', 1)[1]} "
            f"({values[i].tolist()})"
        )
    if not (np.isfinite(model.opt.timestep) and np.isfinite(model.opt.gravity).all()):
        raise RobotFileError(f"{source}: <option> has a non-finite timestep or gravity")


def _check_motor_kind(model: mujoco.MjModel, a: int, source: str) -> None:
    """A motor is what MuJoCo compiles from <motor> or a <general> without bias: force = gear x
    control. Servos read the policy's output as a target position or velocity."""
    gain, bias = int(model.actuator_gaintype[a]), int(model.actuator_biastype[a])
    dyn = int(model.actuator_dyntype[a])
    if (
        gain != mujoco.mjtGain.mjGAIN_FIXED
        or bias != mujoco.mjtBias.mjBIAS_NONE
        or dyn == mujoco.mjtDyn.mjDYN_INTEGRATOR
    ):
        raise RobotFileError(
            f"{source}: actuator {model.actuator(a).name or f'#{a}'!r} is a servo (a position, "
            "velocity or biased actuator), not a motor; gcnt's policies output motor torques: "
            "write it as <motor> or as <general> without bias"
        )


def _check_motors(root: ET.Element, source: str) -> None:
    joints = {el.get("name") for el in root.iter("joint")}
    actuator = root.find("actuator")
    for el in actuator if actuator is not None else ():
        target = el.get("joint")
        if el.get("tendon") is not None:
            # a tendon moves several hinges at once; one action per hinge cannot express it
            tendon = el.get("tendon")
            coupled = [
                j.get("joint")
                for t in root.iter()
                if t.tag in ("fixed", "spatial") and t.get("name") == tendon
                for j in t.iter("joint")
            ]
            couples = f" (it couples joints {', '.join(coupled)})" if coupled else ""
            raise RobotFileError(
                f"{source}: {el.tag} {el.get('name', '(unnamed)')!r} drives tendon {tendon!r}"
                f"{couples}; gcnt's policies output one torque per hinge: give each hinge its "
                "own motor"
            )
        if target is None:
            raise RobotFileError(
                f"{source}: {el.tag} {el.get('name', '(unnamed)')!r} has no joint; every motor "
                "must drive one limb hinge"
            )
        if target not in joints:
            raise RobotFileError(
                f"{source}: {el.tag} {el.get('name', '(unnamed)')!r} drives joint {target!r}, "
                "which the file does not define"
            )


def _check_root(model: mujoco.MjModel, body: int, family: str, source: str) -> None:
    if family not in _FREE_ROOT:
        return
    start, num = int(model.body_jntadr[body]), int(model.body_jntnum[body])
    types = [int(model.jnt_type[j]) for j in range(start, start + num)]
    if types != [mujoco.mjtJoint.mjJNT_FREE]:
        raise RobotFileError(
            f"{source}: root body {model.body(body).name!r} has no free root joint (found "
            f"{num} joint(s) of other types); a {family} robot's torso moves freely"
        )


def _check_tree(model: mujoco.MjModel, source: str) -> None:
    """Equality constraints close loops (or tie joints together): a limb tree cannot say so."""
    if model.neq:
        kind = mujoco.mjtEq(int(model.eq_type[0])).name.removeprefix("mjEQ_").lower()
        raise RobotFileError(
            f"{source}: equality constraint {model.eq(0).name or '#0'!r} ({kind}) closes a loop "
            "or couples joints; gcnt reads trees of bodies without constraints"
        )


def _slots_by_axis(
    model: mujoco.MjModel, body: int, hinges: list[int], source: str
) -> tuple[int, ...]:
    """Slot 0 for the hinge about the limb's x axis, 1 for its y axis (the capsule's frame)."""
    bname = model.body(body).name
    if int(model.body_geomnum[body]) == 0:
        raise RobotFileError(f"{source}: limb {bname!r} has no geom to define its frame")
    geom = int(model.body_geomadr[body])
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, model.geom_quat[geom])
    slots = []
    for j in hinges:
        local = rot.reshape(3, 3).T @ model.jnt_axis[j]  # the axis in the limb's frame
        k = int(np.argmax(np.abs(local)))
        if k == 2:
            raise RobotFileError(
                f"{source}: joint {model.joint(j).name!r} of limb {bname!r} turns about the "
                "limb's own long axis; UNIMAL hinges turn about its x or y axis"
            )
        slots.append(k)
    if len(set(slots)) != len(slots):
        raise RobotFileError(
            f"{source}: both hinges of limb {bname!r} turn about its "
            f"{'xy'[slots[0]]} axis; a UNIMAL limb has at most one hinge per axis"
        )
    return tuple(slots)


def robot_from_xml(
    text: str,
    source: str = "<string>",
    name: str | None = None,
    catalogue: str | None = None,
    folder: Path | None = None,
    family: str | None = None,
) -> Robot:
    """Read a robot from MJCF text. ``name`` defaults to the model attribute; ``catalogue`` to
    the catalogue of the robot's family ("unimal" for UNIMAL robots, "mjcf3d" for other 3-D
    robots, else "smpenv"); ``folder`` is the robot file's folder, against which ``<include>``
    and asset files resolve (files outside it are refused); ``family`` reads the file as that
    family whatever its structure and names say (e.g. a UNIMAL file as a general 3-D robot)."""
    try:
        root = ET.fromstring(text)
    except ET.ParseError as e:
        raise RobotFileError(f"{source}: not valid XML ({e})") from e
    if _resolve_files(root, folder, source):
        text = ET.tostring(root, encoding="unicode")  # self-contained: compiles anywhere
    _check_motors(root, source)
    try:
        model = mujoco.MjModel.from_xml_string(text)
    except ValueError as e:
        detail = "; ".join(line.strip() for line in str(e).splitlines() if line.strip())
        raise RobotFileError(f"{source}: MuJoCo cannot compile it: {detail}") from None
    _check_finite(model, source)
    name = name or root.get("model") or "robot"
    roots = [b for b in range(1, model.nbody) if model.body_parentid[b] == 0]
    if len(roots) != 1:
        names = [model.body(b).name for b in roots]
        raise RobotFileError(
            f"{source}: expected exactly one root body under worldbody, found {len(roots)}: {names}"
        )
    family = _family_of(model, root, source, roots[0], family)
    _check_root(model, roots[0], family, source)
    _check_tree(model, source)
    # Depth-first pre-order from the root; children in file order.
    kids: dict[int, list[int]] = {}
    for b in range(1, model.nbody):
        kids.setdefault(int(model.body_parentid[b]), []).append(b)
    order: list[int] = []
    stack = [roots[0]]
    while stack:
        b = stack.pop()
        order.append(b)
        stack.extend(reversed(kids.get(b, [])))
    if family in _WELDED_BODIES:
        # a body without joints is welded to its parent: its parent's limb
        limb_of = {order[0]: order[0]}
        for b in order[1:]:
            welded = int(model.body_jntnum[b]) == 0
            limb_of[b] = limb_of[int(model.body_parentid[b])] if welded else b
        order = [b for b in order if limb_of[b] == b]
        parent_of = {b: limb_of[int(model.body_parentid[b])] for b in order[1:]}
    else:
        parent_of = {b: int(model.body_parentid[b]) for b in order[1:]}
    index = {b: i for i, b in enumerate(order)}
    parents = np.array([-1] + [index[parent_of[b]] for b in order[1:]], dtype=np.int64)
    max_limbs = MAX_LIMBS.get(family)
    if max_limbs is not None and len(order) > max_limbs:
        raise RobotFileError(
            f"{source}: {len(order)} bodies (torso included); a {family} robot may have at most "
            f"{max_limbs}"
        )
    by_tree = unimal_limb_types(parents.tolist()) if family in _TREE_TYPES else None
    depth = [0] * len(order)  # segment position along the chain from the torso
    for i in range(1, len(order)):
        depth[i] = depth[int(parents[i])] + 1

    motor_of: dict[int, int] = {}
    for a in range(model.nu):
        if model.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT:
            _check_motor_kind(model, a, source)
            motor_of[int(model.actuator_trnid[a, 0])] = a

    max_j = MAX_JOINTS_PER_LIMB[family]
    body_names, jnames, jids, aids, ranges, gtypes, slots = [], [], [], [], [], [], []
    action_slots: list[tuple[int, ...]] = []
    for i, b in enumerate(order):
        bname = model.body(b).name or f"body#{b}"
        body_names.append(bname)
        start, num = int(model.body_jntadr[b]), int(model.body_jntnum[b])
        hinges = [
            j for j in range(start, start + num) if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE
        ]
        if i == 0:
            hinges = []  # the torso's root joints are unactuated
        else:
            other = [j for j in range(start, start + num) if j not in hinges]
            if other:
                kind = mujoco.mjtJoint(int(model.jnt_type[other[0]])).name
                kind = kind.removeprefix("mjJNT_").lower()
                raise RobotFileError(
                    f"{source}: limb {bname!r} has {kind} joint "
                    f"{model.joint(other[0]).name or f'#{other[0]}'!r} that is not a hinge; limbs "
                    "move only about hinges"
                )
            if not hinges:
                raise RobotFileError(f"{source}: limb {bname!r} has no hinge joint")
            if len(hinges) > max_j:
                raise RobotFileError(
                    f"{source}: limb {bname!r} has {len(hinges)} joints; family {family!r} "
                    f"allows at most {max_j}"
                )
            for j in hinges:
                if j not in motor_of:
                    raise RobotFileError(
                        f"{source}: joint {model.joint(j).name or f'#{j}'!r} of limb {bname!r} "
                        "has no motor"
                    )
        jnames.append(tuple(model.joint(j).name for j in hinges))
        jids.append(tuple(hinges))
        aids.append(tuple(motor_of[j] for j in hinges))
        ranges.append(
            np.array([model.jnt_range[j] for j in hinges], dtype=np.float64).reshape(-1, 2)
        )
        if family in _SLOT_BY_AXIS:
            action_slots.append(_slots_by_axis(model, b, hinges, source) if hinges else ())
        if by_tree is not None:
            g, s = by_tree[i]
        else:
            try:
                g, s = limb_type(family, bname, is_root=i == 0, segment=depth[i])
            except UnknownLimbError as e:
                raise RobotFileError(f"{source}: {e}") from e
        gtypes.append(g)
        slots.append(s)
    used = {a for limb in aids for a in limb}
    for a in range(model.nu):
        if a not in used:
            target = "no joint"
            if model.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT:
                target = f"joint {model.joint(int(model.actuator_trnid[a, 0])).name!r}"
            raise RobotFileError(
                f"{source}: motor {model.actuator(a).name!r} drives {target}, not a limb hinge; "
                "every motor must drive one limb hinge"
            )

    return Robot(
        name=name,
        family=family,
        source=source,
        xml=text,
        body_names=tuple(body_names),
        parents=parents,
        mj_body_ids=np.array(order, dtype=np.int64),
        joint_names=tuple(jnames),
        mj_joint_ids=tuple(jids),
        actuator_ids=tuple(aids),
        joint_ranges=tuple(ranges),
        global_types=np.array(gtypes, dtype=np.int64),
        family_slots=np.array(slots, dtype=np.int64),
        joint_slots=tuple(action_slots),
        catalogue=catalogue or _CATALOGUE_OF_FAMILY.get(family, "smpenv"),
    )
