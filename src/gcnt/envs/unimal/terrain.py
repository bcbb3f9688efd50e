"""Per-episode worlds of MT and Obstacles, drawn from the episode's random generator and written
into the compiled model in place (no recompiling).

MT (``draw_mt``): heights in metres on the 0.1 m grid of ``worlds.MT_*`` (rows along y, columns
along x): a 6 m flat start (x ∈ [−3, 3]), then repeatedly a flat of 2, 4 or 6 m and one obstacle
until the corridor ends at x = 107 (an obstacle that does not fit is dropped, the flat is cut):

* bump: half a sine along x, peak U(0.6, 1.2) m, 8 or 16 m long;
* stairs: 8 equal units of height 0, .2, .4, .6, .6, .4, .2, 0 m, 24 or 32 m long;
* rugged strip: bands along x, 1.0–1.9 m wide (10–19 rows), each a triangle wave along x
  (10 or 15 half-periods over the strip) between 0 and 2 m, clipped at 0.2 or 0.3 m; 8 or 16 m
  long.

Obstacles (``draw_boxes``): up to 50 boxes with half-sides l, w ~ U(0.5, 1.0) m, centres
x ∈ [3 + l, 91 − l), y ∈ [−20 + w, 20 − w], none overlapping another's footprint; a box that
fails 10 placements is dropped. They are 4 m tall and float 0.1 m above the floor.

:class:`MTTerrain` and :class:`ObstacleField` hold one sub-env's world: ``redraw(rng)`` edits the
model (height field data, box geoms), ``grid`` is the height map's lookup table (see
``hfield.py``), ``ground(x, y)`` the local ground height for the fall test, and ``sync_render``
copies the edits into a renderer's model copy.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from gcnt.envs.unimal import worlds as W

FLAT_START = 6.0
FLAT_LENGTHS = (2.0, 4.0, 6.0)
OBSTACLE_TYPES = ("bump", "stairs", "rugged")
BUMP_LENGTHS = (8.0, 16.0)
BUMP_PEAK = (0.6, 1.2)
STAIR_LENGTHS = (24.0, 32.0)
STAIR_HEIGHTS = (0.0, 0.2, 0.4, 0.6, 0.6, 0.4, 0.2, 0.0)
RUGGED_LENGTHS = (8.0, 16.0)
RUGGED_BAND_ROWS = (10, 19)  # band width in rows (0.1 m), inclusive
RUGGED_HALF_PERIODS = (10, 15)
RUGGED_CLIP = (0.2, 0.3)
#: map values outside the world and on walls (metres, before subtracting the torso's ground)
OUTSIDE = -10.0
WALL = 4.0


def _cells(metres: float) -> int:
    return round(metres / W.CELL)


def _triangle(n: int, half_periods: int) -> np.ndarray:
    """n samples of a triangle wave in [0, 2] starting at 0, over ``half_periods`` half-periods
    (a symmetric sawtooth over [0, half_periods·π], plus 1)."""
    u = (np.linspace(0.0, half_periods * np.pi, n) / (2 * np.pi)) % 1.0
    return np.where(u < 0.5, 4.0 * u - 1.0, 3.0 - 4.0 * u) + 1.0


def draw_mt(rng: np.random.Generator, out: np.ndarray | None = None) -> np.ndarray:
    """One MT terrain: heights [MT_NROW, MT_NCOL] in metres (written into ``out`` if given)."""
    nrow, ncol = W.MT_NROW, W.MT_NCOL
    h = np.zeros((nrow, ncol)) if out is None else out
    h[...] = 0.0
    end = _cells(FLAT_START)  # first column after the start flat
    last = ncol - 1  # the corridor's last sample
    while end < last:
        end = min(end + _cells(FLAT_LENGTHS[rng.integers(3)]), last)
        kind = OBSTACLE_TYPES[rng.integers(3)]
        if kind == "bump":
            n = _cells(BUMP_LENGTHS[rng.integers(2)])
            peak = rng.uniform(*BUMP_PEAK)
            seg = np.broadcast_to(peak * np.sin(np.linspace(0.0, np.pi, n)), (nrow, n))
        elif kind == "stairs":
            n = _cells(STAIR_LENGTHS[rng.integers(2)])
            unit = n // len(STAIR_HEIGHTS)
            seg = np.broadcast_to(np.repeat(STAIR_HEIGHTS, unit), (nrow, n))
        else:
            n = _cells(RUGGED_LENGTHS[rng.integers(2)])
            seg = np.empty((nrow, n))
            waves = [_triangle(n, f) for f in RUGGED_HALF_PERIODS]
            row = 0
            while row < nrow:
                width = int(rng.integers(RUGGED_BAND_ROWS[0], RUGGED_BAND_ROWS[1] + 1))
                wave = waves[rng.integers(2)]
                clip = RUGGED_CLIP[rng.integers(2)]
                np.minimum(wave, clip, out=seg[row : row + width])
                row += width
        if end + n > last:
            break  # the obstacle does not fit before the corridor's end
        h[:, end : end + n] = seg
        end += n
    return h


def draw_boxes(rng: np.random.Generator) -> np.ndarray:
    """Obstacle boxes [n, 4]: centre x, centre y, half-side x, half-side y (n <= 50).

    Box i gets its half-sides, then up to ``BOX_PLACEMENT_TRIES`` candidate centres; the first
    candidate whose footprint overlaps no box placed before it is taken, else the box is dropped.
    All random numbers are drawn up front (three generator calls). The overlap tests are plain
    Python floats: about 50 x 25 comparisons that mostly stop at the first try, five times faster
    than a numpy call per box at these sizes.
    """
    m, tries = W.MAX_BOXES, W.BOX_PLACEMENT_TRIES
    lo, hi = W.BOX_HALF_SIDE
    x_lo, x_hi = W.OBS_X[0] + 6.0, W.OBS_X[1] - 6.0  # centres in [3 + l, 91 - l)
    half = rng.uniform(lo, hi, (m, 2))
    u = rng.random((m, tries, 2))
    # candidate centres, x in [x_lo + hx, x_hi - hx), y within the walls
    cx = x_lo + half[:, :1] + u[..., 0] * (x_hi - x_lo - 2 * half[:, :1])
    cy = W.OBS_Y[0] + half[:, 1:] + u[..., 1] * (W.OBS_Y[1] - W.OBS_Y[0] - 2 * half[:, 1:])
    placed: list[tuple[float, float, float, float]] = []
    for (hx, hy), xs, ys in zip(half.tolist(), cx.tolist(), cy.tolist(), strict=True):
        for x, y in zip(xs, ys, strict=True):
            for px, py, pl, pw in placed:
                if abs(px - x) < pl + hx and abs(py - y) < pw + hy:
                    break  # overlaps a placed box: next candidate
            else:
                placed.append((x, y, hx, hy))
                break
    return np.array(placed, dtype=np.float64).reshape(len(placed), 4)


class MTTerrain:
    """One sub-env's MT height field: the model's ``hfield_data`` is the terrain (heights divided
    by the field's elevation size), and the height map reads it directly."""

    def __init__(self, model: mujoco.MjModel):
        hid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_HFIELD, "terrain")
        if hid < 0:
            raise ValueError("the MT model has no height field named 'terrain'")
        self.hfield_id = hid
        self.model = model
        adr = int(model.hfield_adr[hid])
        nrow, ncol = int(model.hfield_nrow[hid]), int(model.hfield_ncol[hid])
        self.data = model.hfield_data[adr : adr + nrow * ncol].reshape(nrow, ncol)
        self.scale = float(model.hfield_size[hid, 2])
        #: the height map's lookup table (metres): the height field's vertices plus a border of
        #: OUTSIDE; its vertex (0, 0) lies at ``origin``
        self.grid = np.full((nrow + 2, ncol + 2), OUTSIDE, np.float32)
        self.grid[1:-1, 1:-1] = self.data * self.scale
        self.origin = (W.MT_X[0] - W.CELL, W.MT_Y[0] - W.CELL)

    def redraw(self, rng: np.random.Generator) -> None:
        h = draw_mt(rng, self.grid[1:-1, 1:-1])  # float32 metres, in the lookup table
        np.multiply(h, 1.0 / self.scale, out=self.data)

    def ground(self, x: float, y: float) -> float:
        """Terrain height at the sample nearest (x, y); 0 outside the corridor."""
        c = round((x - W.MT_X[0]) / W.CELL)
        r = round((y - W.MT_Y[0]) / W.CELL)
        if 0 <= r < self.data.shape[0] and 0 <= c < self.data.shape[1]:
            return max(0.0, float(self.data[r, c]) * self.scale)
        return 0.0

    def sync_render(self, model: mujoco.MjModel, renderer) -> None:
        hid, adr = self.hfield_id, int(self.model.hfield_adr[self.hfield_id])
        n = self.data.size
        model.hfield_data[adr : adr + n] = self.model.hfield_data[adr : adr + n]
        if renderer is not None:
            ctx = getattr(renderer, "_mjr_context", None)
            if ctx is not None:
                mujoco.mjr_uploadHField(model, ctx, hid)


class ObstacleField:
    """One sub-env's Obstacles boxes (geoms ``box/i`` of the world body, moved in place) and the
    height map's lookup table: floor 0, box tops, walls ``WALL``, ``OUTSIDE`` beyond the walls."""

    def __init__(self, model: mujoco.MjModel):
        self.model = model
        self.geoms = np.array(
            [
                mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, f"box/{i}")
                for i in range(W.MAX_BOXES)
            ]
        )
        if (self.geoms < 0).any():
            raise ValueError(f"the Obstacles model lacks {W.MAX_BOXES} geoms named 'box/i'")
        self.contype = int(model.geom_contype[model.geom_bodyid == 0][0])
        self.conaffinity = int(model.geom_conaffinity[model.geom_bodyid == 0][0])
        self.park_pos = model.geom_pos[self.geoms].copy()
        self.boxes = np.zeros((0, 4))
        # Lookup table (metres): floor, walls, and a border of OUTSIDE beyond the walls.
        w2 = 2 * W.WALL_HALF
        self.origin = (W.OBS_X[0] - w2 - W.CELL, W.OBS_Y[0] - w2 - W.CELL)
        ncol = round((W.OBS_X[1] - W.OBS_X[0] + 2 * w2) / W.CELL) + 3
        nrow = round((W.OBS_Y[1] - W.OBS_Y[0] + 2 * w2) / W.CELL) + 3
        self._floor = np.full((nrow, ncol), OUTSIDE, np.float32)
        self._floor[1:-1, 1:-1] = WALL
        k = round(w2 / W.CELL) + 1  # border and wall cells on each side
        self._floor[k:-k, k:-k] = 0.0
        self.grid = self._floor.copy()
        self.top = 2 * W.BOX_HALF_HEIGHT + W.BOX_LIFT
        # the lookup-table cells the current boxes cover, (r0, r1, c0, c1) inclusive: a redraw
        # restores only these to the floor instead of copying the whole table
        self._covered: list[tuple[int, int, int, int]] = []

    def redraw(self, rng: np.random.Generator) -> None:
        self.place(draw_boxes(rng))

    def place(self, boxes: np.ndarray) -> None:
        """Put boxes [n, 4] (centre x, centre y, half-side x, half-side y) into the model and the
        height map's lookup table; the other box geoms are parked without contacts."""
        m, g = self.model, self.geoms
        n = len(boxes)
        if n > len(g):
            raise ValueError(f"{n} boxes; the Obstacles model holds at most {len(g)}")
        self.boxes = np.array(boxes, dtype=np.float64).reshape(n, 4)
        boxes = self.boxes
        m.geom_pos[g] = self.park_pos
        m.geom_contype[g] = 0
        m.geom_conaffinity[g] = 0
        used = g[:n]
        m.geom_pos[used, 0] = boxes[:, 0]
        m.geom_pos[used, 1] = boxes[:, 1]
        m.geom_pos[used, 2] = W.BOX_LIFT + W.BOX_HALF_HEIGHT
        m.geom_size[g, 0:2] = 0.5
        m.geom_size[used, 0] = boxes[:, 2]
        m.geom_size[used, 1] = boxes[:, 3]
        m.geom_contype[used] = self.contype
        m.geom_conaffinity[used] = self.conaffinity
        # bounding sphere and box of the resized geoms (used by collision detection)
        m.geom_rbound[g] = np.linalg.norm(m.geom_size[g], axis=1)
        m.geom_aabb[g, 3:6] = m.geom_size[g]
        m.geom_aabb[g, 0:3] = 0.0
        # height-map lookup: vertices inside a box's footprint see its top
        grid, floor = self.grid, self._floor
        for r0, r1, c0, c1 in self._covered:
            grid[r0 : r1 + 1, c0 : c1 + 1] = floor[r0 : r1 + 1, c0 : c1 + 1]
        self._covered = []
        x0, y0 = self.origin
        inv, top = 1.0 / W.CELL, self.top
        for x, y, lx, ly in boxes.tolist():
            c0 = max(0, math.ceil((x - lx - x0) * inv - 1e-9))
            c1 = math.floor((x + lx - x0) * inv + 1e-9)
            r0 = max(0, math.ceil((y - ly - y0) * inv - 1e-9))
            r1 = math.floor((y + ly - y0) * inv + 1e-9)
            grid[r0 : r1 + 1, c0 : c1 + 1] = top
            self._covered.append((r0, r1, c0, c1))

    def ground(self, x: float, y: float) -> float:
        return 0.0

    def sync_render(self, model: mujoco.MjModel, renderer) -> None:
        g, src = self.geoms, self.model
        model.geom_pos[g] = src.geom_pos[g]
        model.geom_size[g] = src.geom_size[g]
        model.geom_rbound[g] = src.geom_rbound[g]
        model.geom_aabb[g] = src.geom_aabb[g]
        model.geom_contype[g] = src.geom_contype[g]
        model.geom_conaffinity[g] = src.geom_conaffinity[g]
