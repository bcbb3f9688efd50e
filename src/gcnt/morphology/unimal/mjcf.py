"""A UNIMAL genotype as MJCF in the original UNIMAL file layout, and its validity check.

Layout (as the DERL/MetaMorph files): ``torso/0`` with a free ``root`` joint, limbs ``limb/i``
with hinges ``limbx/i`` / ``limby/i`` whose axes are written as vectors (the x and y axes of the
limb capsule's frame, 4 decimals), motors named after their joints, growth / bottom / touch sites,
torso sensors, and ``<contact><exclude>`` for the sibling pairs that touch at rest. Joint defaults
damping 1, stiffness 1, armature 1, limited, solimplimit 0 .99 .01; timestep 0.005 with Euler;
geoms condim 3, friction .7 .1 .1; parent-child contacts filtered. Angles in degrees.

A robot is valid when it is bilaterally symmetric (centre of mass at y = 0) and no two of its
geoms touch at rest other than a mirrored pair grown at one site (MuJoCo ``mj_forward``).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

import mujoco
import numpy as np

from gcnt.morphology.unimal.space import (
    FLOOR_OFFSET,
    JOINT_ARMATURE,
    JOINT_DAMPING,
    JOINT_STIFFNESS,
    LIMB_RADIUS,
    TORSO_RADIUS,
    Limb,
    Unimal,
    Vec3,
    add,
    body_pos,
    sph,
)

#: Tolerance on the centre of mass's y (float64 sums of exactly mirrored numbers).
SYMMETRY_TOL = 1e-9


class InvalidUnimal(ValueError):
    """A genotype that breaks symmetry or touches itself at rest; the message says which."""


def _f(v: float) -> str:
    s = f"{round(float(v), 4):.4f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def _v(vals: Iterable[float]) -> str:
    return " ".join(_f(v) for v in vals)


def capsule_axes(d: Vec3) -> tuple[np.ndarray, np.ndarray]:
    """x and y axes of the frame MuJoCo gives a capsule written ``fromto="0 0 0 d"``.

    Its z axis runs from ``d`` back to the origin, reached from the body's z by the minimal
    rotation (half a turn about x when they are opposite).
    """
    z = -np.asarray(d, dtype=np.float64) / np.linalg.norm(d)
    k = np.cross([0.0, 0.0, 1.0], z)
    s = float(np.linalg.norm(k))
    if s < 1e-10:
        flip = 1.0 if z[2] > 0 else -1.0  # opposite: half a turn about x
        return np.array([1.0, 0.0, 0.0]), np.array([0.0, flip, 0.0])
    k /= s
    a = math.atan2(s, float(z[2]))

    def rot(v: np.ndarray) -> np.ndarray:
        return v * math.cos(a) + np.cross(k, v) * math.sin(a) + k * (k @ v) * (1 - math.cos(a))

    return rot(np.array([1.0, 0.0, 0.0])), rot(np.array([0.0, 1.0, 0.0]))


def _world_positions(u: Unimal) -> list[Vec3]:
    out: list[Vec3] = []
    for i, limb in enumerate(u.limbs):
        base = (0.0, 0.0, 0.0) if limb.parent < 0 else out[limb.parent]
        out.append(add(base, body_pos(u, i)))
    return out


def torso_height(u: Unimal) -> float:
    """Torso z that puts the robot's lowest point ``FLOOR_OFFSET`` above the floor."""
    lowest = -TORSO_RADIUS
    for limb, pos in zip(u.limbs, _world_positions(u), strict=True):
        tip = sph(2 * LIMB_RADIUS + limb.h, limb.theta, limb.phi)
        lowest = min(lowest, pos[2] + tip[2])
    return round(-lowest + FLOOR_OFFSET, 2)


_HEAD = """<mujoco model="unimal">
  <compiler angle="degree"/>
  <size njmax="1000" nconmax="200"/>
  <option timestep="0.005" integrator="Euler">
    <flag filterparent="enable"/>
  </option>
  <default>
    <motor ctrlrange="-1 1" ctrllimited="true"/>
    <default class="normal_joint">
      <joint type="hinge" damping="{damping}" stiffness="{stiffness}" armature="{armature}" \
limited="true" solimplimit="0 0.99 0.01"/>
    </default>
    <default class="free">
      <joint limited="false" damping="0" armature="0" stiffness="0"/>
    </default>
    <default class="growth_site">
      <site size="1e-6 1e-6 1e-6"/>
    </default>
    <default class="mirror_growth_site">
      <site size="1e-6 1e-6 1e-6"/>
    </default>
    <default class="btm_pos_site">
      <site size="1e-6 1e-6 1e-6"/>
    </default>
    <default class="imu_vel">
      <site type="box" size="0.05" rgba="1 0 0 0"/>
    </default>
    <default class="touch_site">
      <site group="3" rgba="0 0 1 .3"/>
    </default>
    <geom type="capsule" condim="3" friction="0.7 0.1 0.1" material="self"/>
  </default>
  <asset>
    <material name="self" rgba=".7 .5 .3 1"/>
  </asset>
  <worldbody>
    <light diffuse="1 1 1" directional="true" pos="0 0 8" specular="0.1 0.1 0.1" dir="0 0 -1"/>
"""


def _limb_lines(u: Unimal, i: int, indent: str) -> list[str]:
    limb: Limb = u.limbs[i]
    r, h, t, p = LIMB_RADIUS, limb.h, limb.theta, limb.phi
    tip = sph(r + h, t, p)
    ax = dict(zip("xy", capsule_axes(tip), strict=True))
    site_class = "growth_site" if limb.mirror < 0 else "mirror_growth_site"
    lines = [f'{indent}<body name="limb/{i}" pos="{_v(body_pos(u, i))}">']
    jpos = _v(sph(r, t + 180, 180 - p))
    for hg in limb.hinges:
        extra = ""
        if hg.armature is not None:
            extra += f' armature="{_f(hg.armature)}"'
        if hg.damping is not None:
            extra += f' damping="{_f(hg.damping)}"'
        lines.append(
            f'{indent}  <joint name="limb{hg.axis}/{i}" type="hinge" class="normal_joint" '
            f'range="{hg.range[0]} {hg.range[1]}" pos="{jpos}" axis="{_v(ax[hg.axis])}"{extra}/>'
        )
    fromto = _v((0.0, 0.0, 0.0, *tip))
    lines += [
        f'{indent}  <geom name="limb/{i}" type="capsule" fromto="{fromto}" size="{_f(r)}" '
        f'density="{u.limb_density}"/>',
        f'{indent}  <site name="limb/mid/{i}" class="{site_class}" pos="{_v(sph(r + h / 2, t, p))}"/>',
        f'{indent}  <site name="limb/btm/{i}" class="{site_class}" pos="{_v(tip)}"/>',
        f'{indent}  <site name="limb/btm_pos/{i}" class="btm_pos_site" '
        f'pos="{_v(sph(2 * r + h, t, p))}"/>',
        f'{indent}  <site name="limb/touch/{i}" class="touch_site" size="{_f(r + 0.01)}" '
        f'fromto="{fromto}" type="capsule"/>',
    ]
    for c in u.children(i):
        lines += _limb_lines(u, c, indent + "  ")
    lines.append(f"{indent}</body>")
    return lines


def to_mjcf(u: Unimal, excludes: Sequence[tuple[int, int]] = ()) -> str:
    """The MJCF text of ``u`` (deterministic); ``excludes`` are limb pairs whose contact is off."""
    head = _HEAD.format(
        damping=_f(JOINT_DAMPING), stiffness=_f(JOINT_STIFFNESS), armature=_f(JOINT_ARMATURE)
    )
    r = TORSO_RADIUS
    lines = [
        f'    <body name="torso/0" pos="0 0 {_f(torso_height(u))}">',
        '      <joint name="root" type="free" class="free"/>',
        '      <site name="root" class="imu_vel"/>',
        f'      <geom name="torso/0" type="sphere" size="{_f(r)}" condim="3" '
        f'density="{u.torso_density}"/>',
        '      <camera name="side" pos="0 -7 2" xyaxes="1 0 0 0 1 2" mode="trackcom"/>',
        '      <site name="torso/0" class="growth_site" pos="0 0 0"/>',
        f'      <site name="torso/btm_pos/0" class="btm_pos_site" pos="0 0 {_f(-r)}"/>',
        f'      <site name="torso/touch/0" class="touch_site" size="{_f(r + 0.01)}"/>',
    ]
    for c in u.children(-1):
        lines += _limb_lines(u, c, "      ")
    lines += ["    </body>", "  </worldbody>", "  <actuator>"]
    for i, limb in enumerate(u.limbs):
        for hg in limb.hinges:
            name = f"limb{hg.axis}/{i}"
            lines.append(f'    <motor name="{name}" joint="{name}" gear="{hg.gear}"/>')
    lines += [
        "  </actuator>",
        "  <sensor>",
        '    <accelerometer name="torso_accel" site="root"/>',
        '    <gyro name="torso_gyro" site="root"/>',
        '    <velocimeter name="torso_vel" site="root"/>',
        '    <subtreeangmom name="unimal_am" body="torso/0"/>',
        '    <touch name="torso/0" site="torso/touch/0"/>',
    ]
    lines += [f'    <touch name="limb/{i}" site="limb/touch/{i}"/>' for i in range(len(u.limbs))]
    lines.append("  </sensor>")
    if excludes:
        lines.append("  <contact>")
        lines += [f'    <exclude body1="limb/{a}" body2="limb/{b}"/>' for a, b in excludes]
        lines.append("  </contact>")
    lines.append("</mujoco>")
    return head + "\n".join(lines) + "\n"


def _sibling_pairs(u: Unimal) -> set[tuple[int, int]]:
    """Mirrored pairs grown together at one site: the only limbs allowed to touch at rest."""
    return {
        (i, limb.mirror)
        for i, limb in enumerate(u.limbs)
        if limb.mirror > i
        and (limb.parent, limb.site) == (u.limbs[limb.mirror].parent, u.limbs[limb.mirror].site)
    }


def rest_state(text: str) -> tuple[mujoco.MjModel, mujoco.MjData]:
    model = mujoco.MjModel.from_xml_string(text)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    return model, data


def check(u: Unimal) -> list[tuple[int, int]]:
    """The sibling pairs that touch at rest; :class:`InvalidUnimal` if ``u`` is not valid."""
    model, data = rest_state(to_mjcf(u))
    com_y = float(data.subtree_com[1, 1])
    if abs(com_y) > SYMMETRY_TOL:
        raise InvalidUnimal(f"not bilaterally symmetric: centre of mass y = {com_y:.3g}")
    allowed = _sibling_pairs(u)
    touching: set[tuple[int, int]] = set()
    for c in data.contact[: data.ncon]:
        names = sorted(model.geom(int(g)).name for g in (c.geom1, c.geom2))
        ids = tuple(sorted(int(n.split("/")[1]) if n.startswith("limb/") else -1 for n in names))
        if ids not in allowed:
            raise InvalidUnimal(f"geoms {names[0]!r} and {names[1]!r} touch at rest")
        touching.add(ids)  # type: ignore[arg-type]
    return sorted(touching)


def build_mjcf(u: Unimal) -> str:
    """The file of a valid ``u``, with its touching sibling pairs excluded."""
    return to_mjcf(u, check(u))
