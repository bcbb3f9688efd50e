"""The height map of MT and Obstacles: 47 × 30 = 1410 terrain heights around the torso.

Samples sit at fixed offsets from the torso in its heading frame: forward (30 values, columns)
−10, −6, −5, −3, −2, −1, 0, 1, …, 13, 15, 16, 17, 18, 20, 22, 24, 28, 32, 40 cells of 0.1 m
(−1 m to +4 m, denser near the robot), lateral (47 values, rows) the same spacing on both sides
to ±4 m, row 0 at +4 m (left). The offsets are turned by the torso's yaw (the heading of its x
axis projected on the ground), added to the torso's (x, y), and each sample reads the world's
height at the grid vertex nearest to it (the height field's own 0.1 m vertices on MT). Values are
metres minus the height at the vertex under the torso; outside the world the table holds
``OUTSIDE`` (−10) and on walls ``WALL`` (4) before that subtraction, as in the original
MetaMorph code. Flattened row-major: index = row × 30 + column.

Index arithmetic runs on all sub-envs at once ([n, 1410] arrays); only the final table lookup is
one ``np.take`` per sub-env (each has its own terrain).
"""

from __future__ import annotations

import numpy as np

from gcnt.envs.unimal import worlds as W
from gcnt.envs.unimal.terrain import OUTSIDE

_NEAR = [*range(14), 15, 16, 17, 18, 20, 22, 24, 28, 32, 40]
#: forward offsets in cells (columns)
FORWARD_CELLS = np.array([-10, -6, -5, -3, -2, -1, *_NEAR])
#: lateral offsets in cells (rows, row 0 at +4 m)
LATERAL_CELLS = np.array([*_NEAR[::-1], *(-c for c in _NEAR[1:])])
ROWS, COLS = len(LATERAL_CELLS), len(FORWARD_CELLS)
HFIELD_DIM = ROWS * COLS
#: index of the sample at the torso (lateral 0, forward 0)
CENTRE = int(np.nonzero(LATERAL_CELLS == 0)[0][0]) * COLS + int(
    np.nonzero(FORWARD_CELLS == 0)[0][0]
)

assert (ROWS, COLS, HFIELD_DIM) == (47, 30, 1410)

_FWD = np.tile(FORWARD_CELLS * W.CELL, ROWS)  # [1410] metres along the heading
_LAT = np.repeat(LATERAL_CELLS * W.CELL, COLS)  # [1410] metres to the left


def sample_points(xy: np.ndarray, heading: np.ndarray) -> np.ndarray:
    """World (x, y) of the samples: ``xy`` [n, 2] torso positions, ``heading`` [n, 2] unit
    (cos yaw, sin yaw). Returns [n, 1410, 2]."""
    c, s = heading[:, :1], heading[:, 1:2]
    px = xy[:, :1] + c * _FWD - s * _LAT
    py = xy[:, 1:2] + s * _FWD + c * _LAT
    return np.stack([px, py], axis=-1)


def heading_from_quat(q: np.ndarray) -> np.ndarray:
    """(cos yaw, sin yaw) [n, 2] of the x axis of world quaternions ``q`` [n, 4] (w, x, y, z)
    projected on the ground; (1, 0) if that axis points straight up or down."""
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    hx = 1.0 - 2.0 * (y * y + z * z)
    hy = 2.0 * (x * y + w * z)
    norm = np.hypot(hx, hy)
    ok = norm > 1e-9
    out = np.zeros((len(q), 2))
    out[:, 0] = np.where(ok, hx / np.where(ok, norm, 1.0), 1.0)
    out[:, 1] = np.where(ok, hy / np.where(ok, norm, 1.0), 0.0)
    return out


def height_map(
    xy: np.ndarray,
    heading: np.ndarray,
    grids: list[np.ndarray],
    scales: np.ndarray,
    origin: tuple[float, float],
) -> np.ndarray:
    """Height maps float32 [n, 1410] of n sub-envs.

    ``grids``: each sub-env's lookup table [nrow, ncol] (rows along y from ``origin[1]``, columns
    along x from ``origin[0]``, 0.1 m apart; all of one shape), ``scales`` [n]: metres per table
    unit.
    """
    n = len(grids)
    out = np.empty((n, HFIELD_DIM), np.float32)
    if n == 0:
        return out
    nrow, ncol = grids[0].shape
    p = sample_points(xy, heading)
    col = np.rint((p[..., 0] - origin[0]) * (1.0 / W.CELL)).astype(np.int64)
    row = np.rint((p[..., 1] - origin[1]) * (1.0 / W.CELL)).astype(np.int64)
    inside = (col >= 0) & (col < ncol) & (row >= 0) & (row < nrow)
    np.clip(col, 0, ncol - 1, out=col)
    np.clip(row, 0, nrow - 1, out=row)
    flat = row * ncol + col
    vals = np.empty((n, HFIELD_DIM))
    for j, g in enumerate(grids):
        vals[j] = g.reshape(-1).take(flat[j])
    vals *= scales[:, None]
    vals[~inside] = OUTSIDE
    vals -= vals[:, CENTRE : CENTRE + 1]
    out[:] = vals
    return out
