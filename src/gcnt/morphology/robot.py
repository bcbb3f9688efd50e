"""A robot as data: its limbs in depth-first pre-order, their parents, joints, motors and types.

Read from MJCF through MuJoCo's own compiler, so that what the policy sees is what the simulator
steps. Every malformed file raises :class:`RobotFileError` naming the file and the culprit.
"""

from __future__ import annotations

import functools
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from gcnt.morphology.graph import WL_BUCKETS, WL_ROUNDS, RobotGraph
from gcnt.morphology.limb_types import FAMILIES, MAX_JOINTS_PER_LIMB, UnknownLimbError, limb_type

#: MJCF ``<custom><text name=...>`` entry that names a robot's family explicitly.
FAMILY_TEXT = "gcnt_family"


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
    #: the robot catalogue (benchmark) the robot belongs to, e.g. "smpenv" or "unimal"
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


def _family_of(model: mujoco.MjModel, root: ET.Element, source: str) -> str:
    for el in root.iter("text"):
        if el.get("name") == FAMILY_TEXT:
            fam = el.get("data", "")
            if fam not in FAMILIES:
                raise RobotFileError(
                    f"{source}: unknown robot family {fam!r}; known: {', '.join(FAMILIES)}"
                )
            return fam
    name = root.get("model", "") or Path(source).stem
    for fam in FAMILIES:
        if name.startswith(fam):
            return fam
    raise RobotFileError(
        f"{source}: cannot tell the robot family of model {name!r}; start the model name with "
        f'one of {", ".join(FAMILIES)} or add <custom><text name="{FAMILY_TEXT}" data=...>'
    )


def load_robot(path: str | Path) -> Robot:
    """Read a robot from an MJCF file."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as e:
        raise RobotFileError(f"{path}: cannot read robot file ({e.strerror})") from e
    return robot_from_xml(text, source=str(path), name=path.stem)


def robot_from_xml(text: str, source: str = "<string>", name: str | None = None) -> Robot:
    """Read a robot from MJCF text. ``name`` defaults to the model attribute."""
    try:
        root = ET.fromstring(text)
    except ET.ParseError as e:
        raise RobotFileError(f"{source}: not valid XML ({e})") from e
    try:
        model = mujoco.MjModel.from_xml_string(text)
    except ValueError as e:
        raise RobotFileError(f"{source}: MuJoCo cannot compile it: {e}") from e
    name = name or root.get("model") or "robot"
    family = _family_of(model, root, source)

    roots = [b for b in range(1, model.nbody) if model.body_parentid[b] == 0]
    if len(roots) != 1:
        names = [model.body(b).name for b in roots]
        raise RobotFileError(
            f"{source}: expected exactly one root body under worldbody, found {len(roots)}: {names}"
        )
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
    index = {b: i for i, b in enumerate(order)}
    parents = np.array(
        [-1] + [index[int(model.body_parentid[b])] for b in order[1:]], dtype=np.int64
    )

    motor_of: dict[int, int] = {}
    for a in range(model.nu):
        if model.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT:
            motor_of[int(model.actuator_trnid[a, 0])] = a

    max_j = MAX_JOINTS_PER_LIMB[family]
    body_names, jnames, jids, aids, ranges, gtypes, slots = [], [], [], [], [], [], []
    for i, b in enumerate(order):
        bname = model.body(b).name
        body_names.append(bname)
        start, num = int(model.body_jntadr[b]), int(model.body_jntnum[b])
        hinges = [
            j for j in range(start, start + num) if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE
        ]
        if i == 0:
            hinges = []  # the torso's root joints are unactuated
        else:
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
                        f"{source}: joint {model.joint(j).name!r} of limb {bname!r} has no motor"
                    )
        jnames.append(tuple(model.joint(j).name for j in hinges))
        jids.append(tuple(hinges))
        aids.append(tuple(motor_of[j] for j in hinges))
        ranges.append(
            np.array([model.jnt_range[j] for j in hinges], dtype=np.float64).reshape(-1, 2)
        )
        try:
            g, s = limb_type(family, bname, is_root=i == 0)
        except UnknownLimbError as e:
            raise RobotFileError(f"{source}: {e}") from e
        gtypes.append(g)
        slots.append(s)

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
    )
