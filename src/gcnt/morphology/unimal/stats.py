"""Statistics of a robot set (limbs, DoF, depth, mass), next to the published UNIMAL training set."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from gcnt.morphology.robot import Robot

#: MetaMorph's 100 training robots (evolved by DERL): (min, mean, max); None where not published.
PUBLISHED: dict[str, tuple[float, float | None, float]] = {
    "limbs": (4, 8, 10),
    "dof": (5, 11, 15),
    "depth": (2, None, 5),
    "mass": (12, None, 41),
}


def robot_stats(robot: Robot) -> dict[str, float]:
    """Limbs (besides the torso), DoF (motors), depth (limbs on the longest chain), mass (kg)."""
    depth = np.zeros(robot.num_limbs, dtype=np.int64)
    for i, p in enumerate(robot.parents):
        depth[i] = 0 if p < 0 else depth[p] + 1
    model = robot.compile()
    root = int(robot.mj_body_ids[0])
    return {
        "limbs": robot.num_limbs - 1,
        "dof": robot.num_motors,
        "depth": int(depth.max()),
        "mass": float(model.body_subtreemass[root]),
    }


def set_stats(robots: Sequence[Robot]) -> dict[str, tuple[float, float, float]]:
    """(min, mean, max) of every statistic over ``robots``."""
    rows = [robot_stats(r) for r in robots]
    return {
        k: (min(r[k] for r in rows), float(np.mean([r[k] for r in rows])), max(r[k] for r in rows))
        for k in PUBLISHED
    }
