"""The world of a general 3-D robot: the robot file's body tree inside one of UNIMAL's worlds.

A robot file brings its own floor, lights and cameras; here they are dropped (every child of
``<worldbody>`` but the robot's root body), and the UNIMAL world (``gcnt.envs.unimal.worlds``: a
flat floor, MT's height field or Obstacles' corridor) is put around the robot's bodies, which keep
their ids; the world's geoms get MuJoCo's built-in contact settings wherever the world builder
sets none, whatever ``<default>`` the robot file declares. Two settings are made the same for every robot, so that one policy sees one control
period and one action scale:

* the physics timestep is :data:`TIMESTEP` (0.005 s; with the frame skip of 4, a control period
  of 0.02 s, as UNIMAL's), whatever the file's ``<option timestep>``;
* each motor's control range is mapped onto the policy's [−1, 1]: action a drives the motor as
  control ``mid + a·half`` of its range [lo, hi] would (``half = (hi − lo)/2``, ``mid = (hi +
  lo)/2``), done by scaling the motor's gain by ``half`` and adding the constant ``gain·mid`` as
  its bias. A motor without a control range takes the action itself as its control.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import replace

import mujoco
import numpy as np

from gcnt.envs.unimal.worlds import world_xml
from gcnt.morphology import Robot, RobotFileError

TIMESTEP = 0.005


def robot_only_xml(robot: Robot) -> str:
    """The robot's MJCF without its own world: every child of ``<worldbody>`` except the robot's
    root body (floor and other geoms, sites, lights, cameras) is removed."""
    try:
        root = ET.fromstring(robot.xml)
    except ET.ParseError as e:  # the loader already parsed it; only a hand-made Robot gets here
        raise RobotFileError(f"{robot.source}: not valid XML ({e})") from e
    worldbody = root.find("worldbody")
    if worldbody is None:
        raise RobotFileError(f"{robot.source}: robot {robot.name!r} has no <worldbody>")
    for child in list(worldbody):
        if child.tag != "body":
            worldbody.remove(child)
    return ET.tostring(root, encoding="unicode")


def scale_controls(model: mujoco.MjModel) -> None:
    """Map every limited motor's control range onto [−1, 1] in place (see the module doc)."""
    limited = model.actuator_ctrllimited.astype(bool)
    if not limited.any():
        return
    lo, hi = model.actuator_ctrlrange[limited, 0], model.actuator_ctrlrange[limited, 1]
    half, mid = (hi - lo) / 2.0, (hi + lo) / 2.0
    gain = model.actuator_gainprm[limited, 0].copy()
    model.actuator_gainprm[limited, 0] = gain * half
    ids = np.nonzero(limited)[0]
    offset = ids[mid != 0.0]
    model.actuator_biastype[offset] = mujoco.mjtBias.mjBIAS_AFFINE
    model.actuator_biasprm[offset, :3] = 0.0
    model.actuator_biasprm[offset, 0] = (gain * mid)[mid != 0.0]
    model.actuator_ctrlrange[limited] = (-1.0, 1.0)


#: MuJoCo's built-in contact settings of a geom, written onto the world's geoms so that a robot
#: file's ``<default><geom .../>`` (gymnasium's ant: ``conaffinity="0"``, which would let it fall
#: through a floor that inherits it) does not reach them
_WORLD_GEOM_CONTACT = {
    "contype": "1",
    "conaffinity": "1",
    "condim": "3",
    "group": "0",
    "priority": "0",
    "friction": "1 0.005 0.0001",
    "solmix": "1",
    "solref": "0.02 1",
    "solimp": "0.9 0.95 0.001 0.5 2",
    "margin": "0",
    "gap": "0",
}


def _pin_world_geoms(text: str) -> str:
    """``text`` with every world-body geom's contact settings explicit (the world builder's own
    values kept, MuJoCo's built-in defaults for the rest)."""
    root = ET.fromstring(text)
    worldbody = root.find("worldbody")
    for geom in worldbody.findall("geom") if worldbody is not None else ():
        for key, value in _WORLD_GEOM_CONTACT.items():
            geom.set(key, geom.get(key, value))
    return ET.tostring(root, encoding="unicode")


def world_model(robot: Robot, world: str) -> mujoco.MjModel:
    """The MjModel of ``robot``'s body tree inside the UNIMAL ``world`` (see the module doc)."""
    bare = replace(robot, xml=robot_only_xml(robot))
    text = _pin_world_geoms(world_xml(bare, world))
    try:
        model = mujoco.MjModel.from_xml_string(text)
    except ValueError as e:
        detail = "; ".join(line.strip() for line in str(e).splitlines() if line.strip())
        raise RobotFileError(
            f"{robot.source}: robot {robot.name!r} does not compile inside the {world!r} world: "
            f"{detail}"
        ) from None
    if model.nu != robot.num_motors:
        raise RobotFileError(
            f"{robot.source}: robot {robot.name!r}: the {world!r} world changed its motor count"
        )
    model.opt.timestep = TIMESTEP
    scale_controls(model)
    return model
