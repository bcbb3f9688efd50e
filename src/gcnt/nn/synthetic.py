"""Synthetic robots for tests, parameter counts and benchmarks of the networks: any tree, written
as a walker-family MJCF (limb names end in the segment number 1/2/3 by depth, one hinge and one
motor per limb) and read back through ``gcnt.morphology.robot_from_xml``."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from gcnt.morphology import Robot, robot_from_xml


def tree_mjcf(parents: Sequence[int], name: str = "walker_synthetic") -> str:
    """Walker-family MJCF of the tree ``parents`` (``parents[0] == -1``, parents before children).

    ``name`` must start with a family name ("walker...").
    """
    parents = [int(p) for p in parents]
    if not parents or parents[0] != -1 or any(not 0 <= p < i for i, p in enumerate(parents) if i):
        raise ValueError(f"not a tree in parent-first order: {parents}")
    kids: dict[int, list[int]] = {}
    for i, p in enumerate(parents[1:], start=1):
        kids.setdefault(p, []).append(i)
    depth = [0] * len(parents)
    for i in range(1, len(parents)):
        depth[i] = depth[parents[i]] + 1

    def body(i: int, indent: str) -> str:
        inner = indent + "  "
        if i == 0:
            head = (
                f'{indent}<body name="torso" pos="0 0 1.5">\n'
                f'{inner}<joint name="rootx" type="slide" axis="1 0 0"/>\n'
                f'{inner}<joint name="rootz" type="slide" axis="0 0 1"/>\n'
                f'{inner}<joint name="rooty" type="hinge" axis="0 1 0"/>\n'
                f'{inner}<geom type="capsule" fromto="0 0 0 0 0 -0.3" size="0.07"/>\n'
            )
        else:
            seg = (depth[i] - 1) % 3 + 1
            head = (
                f'{indent}<body name="limb{i}_{seg}" pos="0.05 0 -0.3">\n'
                f'{inner}<joint name="joint{i}" type="hinge" axis="0 -1 0" range="-60 60"/>\n'
                f'{inner}<geom type="capsule" fromto="0 0 0 0 0 -0.3" size="0.05"/>\n'
            )
        return head + "".join(body(c, inner) for c in kids.get(i, [])) + f"{indent}</body>\n"

    motors = "".join(
        f'    <motor joint="joint{i}" gear="100" ctrlrange="-1 1"/>\n'
        for i in range(1, len(parents))
    )
    return (
        f'<mujoco model="{name}">\n'
        '  <compiler angle="degree"/>\n'
        "  <worldbody>\n"
        '    <geom name="floor" type="plane" size="20 20 0.1"/>\n'
        f"{body(0, '    ')}"
        "  </worldbody>\n"
        f"  <actuator>\n{motors}  </actuator>\n"
        "</mujoco>\n"
    )


def tree_robot(parents: Sequence[int], name: str = "walker_synthetic") -> Robot:
    """A Robot with the tree ``parents`` (limbs are re-read in depth-first pre-order)."""
    return robot_from_xml(tree_mjcf(parents, name), name=name)


def random_parents(num_limbs: int, rng: np.random.Generator) -> list[int]:
    """A random tree on ``num_limbs`` limbs, every parent before its child."""
    return [-1] + [int(rng.integers(0, i)) for i in range(1, num_limbs)]


def random_robots(sizes: Sequence[int], seed: int = 0) -> list[Robot]:
    """One random walker-family tree robot per size."""
    rng = np.random.default_rng(seed)
    return [
        tree_robot(random_parents(n, rng), name=f"walker_random_{i}_{n}")
        for i, n in enumerate(sizes)
    ]


def smpenv_like_robots() -> list[Robot]:
    """The CWHH++ training robots (read from the robot files shipped with gcnt; a missing or
    broken file is an error, never silently replaced)."""
    from gcnt.morphology.catalogues import resolve_robots

    return resolve_robots(["CWHH++:train"])
