"""The four UNIMAL worlds (FT, Incline, MT, Obstacles) and how a robot is put into one.

===========  =====================================================================  ==========
world        geometry                                                               fall ratio
===========  =====================================================================  ==========
ft           a flat 200 × 200 m floor at z = 0                                      0.5
incline      a 150 × 40 m slab through the origin, pitched 10° rising along +x      0.2
             (local ground z = x·tan 10°); the robot starts pitched with it near
             the low end (x ≈ −72)
mt           a height field over the corridor x ∈ [−3, 107], y ∈ [−20, 20], 0.1 m   0.3
             cells, heights up to 1.2 m, redrawn every episode (``terrain.py``)
obstacles    a flat corridor x ∈ [−3, 97], y ∈ [−20, 20] with 2 m walls around it    0.5
             and up to 50 static 4 m boxes floating 0.1 m above the floor, moved
             every episode (``terrain.py``)
===========  =====================================================================  ==========

An episode ends (terminated) when the torso's height above the local ground is at most
``fall_ratio × (z0 − 0.2)``, z0 being the torso's z in the robot file (its height when its
lowest point is 0.2 m above a flat floor); on MT and Obstacles also when the torso's |y| ≥ 19.

:func:`world_model` compiles a robot file together with its world as MetaMorph assembles an agent
(``envs/modules/agent.py``): of a UNIMAL file it keeps the compile settings, the torso body, the
motors and the sensors, with parent-child contacts filtered (``filterparent`` enabled; MetaMorph's
files say ``disable`` and lose their ``<contact>`` exclusions, as in MetaMorph). The world's
assets and geoms go into the robot's ``<asset>`` and ``<worldbody>`` (geoms of the world body, so
the robot's body, joint and actuator ids do not change), plus a ``track`` camera on the torso and,
where the file (after that) has no light at world level, MetaMorph's light (:data:`WORLD_LIGHT`). This runs
once per sub-env model at env construction; terrain changes later edit the compiled model in
place (no recompiling).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import mujoco

from gcnt.morphology import Robot, RobotFileError

#: Robot files put the torso so that the lowest point is this far above a flat floor.
START_CLEARANCE = 0.2
INCLINE_DEG = 10.0
INCLINE_TAN = math.tan(math.radians(INCLINE_DEG))
INCLINE_COS = math.cos(math.radians(INCLINE_DEG))
#: Where the incline's robot starts along the slab (x of the ground point below its torso).
INCLINE_START_X = -72.0
#: Terrain worlds end the episode when the torso's |y| reaches this.
SIDE_LIMIT = 19.0

# MT: the height field (x along columns, y along rows, 0.1 m between samples)
CELL = 0.1
MT_X = (-3.0, 107.0)
MT_Y = (-20.0, 20.0)
MT_MAX_HEIGHT = 1.2  # the highest terrain (the tallest bump); the height field's elevation size
MT_BASE = 0.1  # thickness of the height field's base box below z = 0
MT_NCOL = round((MT_X[1] - MT_X[0]) / CELL) + 1
MT_NROW = round((MT_Y[1] - MT_Y[0]) / CELL) + 1

# Obstacles: the corridor, its walls and the boxes
OBS_X = (-3.0, 97.0)
OBS_Y = (-20.0, 20.0)
WALL_HALF = 0.5  # walls are 1 m thick ...
WALL_HEIGHT = 2.0  # ... and 2 m high
MAX_BOXES = 50
BOX_HALF_SIDE = (0.5, 1.0)
BOX_HALF_HEIGHT = 2.0
BOX_LIFT = 0.1
BOX_PLACEMENT_TRIES = 10
#: Boxes not used this episode wait here (below the world, contacts off).
BOX_PARK_Z = -50.0


@dataclass(frozen=True)
class World:
    name: str
    fall_ratio: float
    #: the observation carries a height map (``hfield``)
    height_map: bool = False
    #: the episode also ends when |torso y| >= SIDE_LIMIT
    side_limit: bool = False
    #: the model is edited every episode (terrain / boxes)
    edits_model: bool = False
    #: the limb decoder's hidden widths in this world (MetaMorph's and ModuMorph's
    #: ``DECODER_DIMS``: configs/csr.yaml [64], configs/obstacle.yaml [64, 64], default none)
    decoder_hidden: tuple[int, ...] = ()


WORLDS: dict[str, World] = {
    "ft": World("ft", 0.5),
    "incline": World("incline", 0.2),
    "mt": World("mt", 0.3, height_map=True, side_limit=True, edits_model=True, decoder_hidden=(64,)),
    "obstacles": World(
        "obstacles",
        0.5,
        height_map=True,
        side_limit=True,
        edits_model=True,
        decoder_hidden=(64, 64),
    ),
}


def _f(v: float) -> str:
    return f"{v:.6g}"


def _box(name: str, pos, size, material: str = "world_wall") -> ET.Element:
    return ET.Element(
        "geom",
        {
            "name": name,
            "type": "box",
            "pos": " ".join(_f(v) for v in pos),
            "size": " ".join(_f(v) for v in size),
            "material": material,
            "condim": "3",
            "friction": "0.7 0.1 0.1",
        },
    )


def _world_parts(world: str) -> tuple[list[ET.Element], list[ET.Element]]:
    """(assets, worldbody geoms) of ``world``."""
    assets = [
        ET.Element(
            "texture",
            {
                "name": "world_grid",
                "type": "2d",
                "builtin": "checker",
                "width": "512",
                "height": "512",
                "rgb1": ".2 .3 .4",
                "rgb2": ".1 .2 .3",
                "mark": "edge",
                "markrgb": ".3 .4 .5",
            },
        ),  # fmt: skip
        ET.Element(
            "material",
            {
                "name": "world_grid",
                "texture": "world_grid",
                "texrepeat": "1 1",
                "texuniform": "true",
                "reflectance": "0",
            },
        ),  # fmt: skip
        ET.Element("material", {"name": "world_wall", "rgba": ".45 .45 .5 1"}),
        ET.Element("material", {"name": "world_box", "rgba": ".6 .35 .3 1"}),
    ]
    ground = {"condim": "3", "friction": "0.7 0.1 0.1", "material": "world_grid"}
    geoms: list[ET.Element] = []
    if world == "ft":
        geoms.append(ET.Element("geom", {"name": "floor", "type": "plane", "pos": "0 0 0",
                                         "size": "100 100 0.1", **ground}))  # fmt: skip
    elif world == "incline":
        # A 150 x 40 m box slab whose top face passes through the origin, pitched about y.
        half_t = 0.5
        a = math.radians(INCLINE_DEG)
        # top-face centre at the origin: the box centre lies half_t below it along the normal
        pos = (half_t * math.sin(a), 0.0, -half_t * math.cos(a))
        geoms.append(
            ET.Element("geom", {"name": "floor", "type": "box", "size": f"75 20 {half_t}",
                                "pos": " ".join(_f(v) for v in pos),
                                "euler": f"0 {-INCLINE_DEG} 0", **ground})
        )  # fmt: skip
    elif world == "mt":
        size = (
            (MT_X[1] - MT_X[0]) / 2, (MT_Y[1] - MT_Y[0]) / 2, MT_MAX_HEIGHT, MT_BASE
        )  # fmt: skip
        assets.append(
            ET.Element("hfield", {"name": "terrain", "nrow": str(MT_NROW), "ncol": str(MT_NCOL),
                                  "size": " ".join(_f(v) for v in size)})
        )  # fmt: skip
        centre = ((MT_X[0] + MT_X[1]) / 2, (MT_Y[0] + MT_Y[1]) / 2, 0.0)
        geoms.append(
            ET.Element("geom", {"name": "terrain", "type": "hfield", "hfield": "terrain",
                                "pos": " ".join(_f(v) for v in centre), **ground})
        )  # fmt: skip
    elif world == "obstacles":
        x0, x1 = OBS_X
        y0, y1 = OBS_Y
        cx, hx, hy = (x0 + x1) / 2, (x1 - x0) / 2, (y1 - y0) / 2
        geoms.append(ET.Element("geom", {"name": "floor", "type": "plane",
                                         "pos": f"{_f(cx)} 0 0",
                                         "size": f"{_f(hx + 2 * WALL_HALF)} "
                                                 f"{_f(hy + 2 * WALL_HALF)} 0.1",
                                         **ground}))  # fmt: skip
        w, h = WALL_HALF, WALL_HEIGHT / 2
        geoms += [
            _box("wall/back", (x0 - w, 0, h), (w, hy + 2 * w, h)),
            _box("wall/front", (x1 + w, 0, h), (w, hy + 2 * w, h)),
            _box("wall/left", (cx, y1 + w, h), (hx, w, h)),
            _box("wall/right", (cx, y0 - w, h), (hx, w, h)),
        ]
        for i in range(MAX_BOXES):
            g = _box(f"box/{i}", (1000.0 + 3 * i, 0, BOX_PARK_Z), (0.5, 0.5, BOX_HALF_HEIGHT),
                     "world_box")  # fmt: skip
            g.set("contype", "0")
            g.set("conaffinity", "0")
            geoms.append(g)
    else:
        raise ValueError(f"unknown UNIMAL world {world!r} (known: {', '.join(WORLDS)})")
    return assets, geoms


#: the light of a world whose robot file brings none at world level (a general 3-D robot's own
#: lights go with its world): the light UNIMAL's robot files carry, straight down from above
WORLD_LIGHT = {
    "name": "world_light",
    "directional": "true",
    "pos": "0 0 8",
    "dir": "0 0 -1",
    "diffuse": "1 1 1",
    "specular": "0.1 0.1 0.1",
}


def world_xml(robot: Robot, world: str) -> str:
    """The robot's MJCF with ``world`` added (see the module doc)."""
    try:
        root = ET.fromstring(robot.xml)
    except ET.ParseError as e:  # the loader already parsed it; only a hand-made Robot gets here
        raise RobotFileError(f"{robot.source}: not valid XML ({e})") from e
    if robot.family == "unimal":
        _as_metamorph_agent(root, robot)
    assets, geoms = _world_parts(world)
    asset = root.find("asset")
    if asset is None:
        asset = ET.SubElement(root, "asset")
    asset.extend(assets)
    worldbody = root.find("worldbody")
    if worldbody is None:
        raise RobotFileError(f"{robot.source}: robot {robot.name!r} has no <worldbody>")
    for i, g in enumerate(geoms):
        worldbody.insert(i, g)
    if worldbody.find("light") is None:  # the file brings none (or its world was dropped)
        worldbody.insert(0, ET.Element("light", WORLD_LIGHT))
    torso = next((b for b in worldbody.iter("body") if b.get("name") == robot.body_names[0]), None)
    if torso is None:
        raise RobotFileError(
            f"{robot.source}: robot {robot.name!r}: torso body {robot.body_names[0]!r} not found"
        )
    if not any(c.get("name") == "track" for c in root.iter("camera")):
        cam = ET.Element(
            "camera",
            {"name": "track", "mode": "trackcom", "pos": "0 -6 2.5", "xyaxes": "1 0 0 0 0.4 1"},
        )
        torso.insert(0, cam)
    vis = root.find("visual")
    if vis is None:
        vis = ET.SubElement(root, "visual")
    if vis.find("map") is None:
        ET.SubElement(vis, "map", {"zfar": "200"})
    return ET.tostring(root, encoding="unicode")


def _as_metamorph_agent(root: ET.Element, robot: Robot) -> None:
    """Keep of a UNIMAL file what MetaMorph's agent assembly keeps (``envs/modules/agent.py``,
    ``create_agent_xml``): the file's compile settings, its torso body, motors and sensors, with
    parent-child contacts filtered (``filterparent`` enabled whatever the file says). The file's
    other world-level elements go; so does its ``<contact>`` section where the file turns
    ``filterparent`` off (MetaMorph's and DERL's files, whose exclusions MetaMorph drops). gcnt's
    generated files turn it on themselves and keep their exclusions (their mirrored pairs)."""
    option = root.find("option")
    if option is None:
        option = ET.SubElement(root, "option")
    flag = option.find("flag")
    if flag is None:
        flag = ET.SubElement(option, "flag")
    if flag.get("filterparent") == "disable":
        for contact in root.findall("contact"):
            root.remove(contact)
    flag.set("filterparent", "enable")
    worldbody = root.find("worldbody")
    if worldbody is not None:
        for child in list(worldbody):
            if not (child.tag == "body" and child.get("name") == robot.body_names[0]):
                worldbody.remove(child)


def world_model(robot: Robot, world: str) -> mujoco.MjModel:
    """The MjModel of ``robot`` inside ``world`` (robot ids unchanged; see the module doc)."""
    text = world_xml(robot, world)
    try:
        model = mujoco.MjModel.from_xml_string(text)
    except ValueError as e:
        raise RobotFileError(
            f"{robot.source}: robot {robot.name!r} does not compile inside the {world!r} world: {e}"
        ) from e
    if model.nbody != len(robot.body_names) + 1 or model.nu != robot.num_motors:
        raise RobotFileError(
            f"{robot.source}: robot {robot.name!r}: the {world!r} world changed its body or motor "
            "count (the robot file must hold one robot and no other bodies)"
        )
    return model


class TerrainsByModel:
    """Which terrain each sub-env's model stands on, for a featuriser that reads height maps.

    Each sub-env's task rules own its terrain (they redraw it per episode); :meth:`recording`
    wraps a rules factory so that the first rules built for a model register their terrain, and
    the featuriser looks it up by model (:meth:`terrain_of`). The first registration wins: rules
    built later for the same model (e.g. ``gcnt bench-env``'s raw loop) must not take the env's
    terrain away. A robot pool swaps sub-envs' models: :meth:`keep` forgets the others.
    """

    def __init__(self) -> None:
        self.by_model: dict[int, object] = {}

    def recording(self, make_rules):
        def rules(robot: Robot, model: mujoco.MjModel, dt: float):
            rl = make_rules(robot, model, dt)
            if rl.terrain is not None:
                self.by_model.setdefault(id(model), rl.terrain)
            return rl

        return rules

    def terrain_of(self, model: mujoco.MjModel) -> object:
        return self.by_model[id(model)]

    def keep(self, models) -> None:
        live = {id(m) for m in models}
        for key in [key for key in self.by_model if key not in live]:
            del self.by_model[key]
