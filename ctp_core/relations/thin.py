"""Thin parts of the ground: the bars a thing hangs on and the openings a thing goes in through, with their rims.

Found from the ground's samples alone (normalised frame, +Y up), once per pair where something reads them
(``parts.thin_parts``), and named in the registry (``parts.PARTS``) and in the run's report:

- an **opening** is a basin of the ground seen from above. The ground's *height map* (the highest sample over each
  cell of a grid ``CELL`` sample spacings wide) is filled as water fills it from all round (``water_level``: water
  flows to the four neighbouring cells only, so a rim drawn corner to corner holds it). Each area the water stands
  in (joined across a handle over it, ``JOIN_CELLS``) is an opening where it is deep for its width (``DEEP``: a
  mug, a bucket, a crate's slot; not a dish or a tray) and the ground has a floor under most of it
  (``OWN_FLOOR``: a frame round nothing holds no water). Its **rim** is where the water would spill: its level.
- a **bar** is a run of up-facing samples over a thin part with room under it: a rail, a rod, a peg, a hanger's
  hook. Each such sample's thickness is the depth of the ground under it down to its underside (the highest
  down-facing sample in its column); the samples whose part is thin join where they are near and about as thick,
  and a run of them is a bar where it is about as wide as it is thick (``ROUND``: a rod, not a board or a plate's
  top edge), long for its thickness (``LONG``) and has room under it (``ROOM`` times its thickness).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

CELL = 1.5  # height-map cell, in sample spacings
GRID = 1024  # cells per side at most, of the height map and of a crest's widest disc: a few specks scattered over a
# wide box (their samples far apart for its size) would otherwise ask for billions of cells
MIN_DEPTH = 2.0  # an opening's water, at its deepest, at least this many sample spacings deep (not a sampling dent)
DEEP = 0.25  # an opening: at least this deep for its width (a mug, a bucket; a tray or a plate is a surface)
OWN_FLOOR = 0.5  # an opening: the ground's samples under at least this share of its cells
JOIN_CELLS = 2  # an opening's areas this many cells apart are one (a bucket's handle over its middle)
MIN_CELLS = 4  # an opening covers at least this many cells
UP = 0.5  # a bar's samples face within 60 degrees of up (a rod's upper third); its underside's, of down
JOIN = 2.0  # a bar's samples: this many sample spacings apart belong to one ...
SAME = 1.5  # ... where their thicknesses are within this ratio (a handle's arch and the basket's wall it meets
# are two parts)
SHARE = 0.1  # a thin part matters at the ground's scale: a bar at least this share of the ground's largest side
# long, an opening this share of it wide and of the ground's height deep (a knot hole in a shell is no opening)
ROUND = 2.0  # a bar is no thicker than this many times its width (a plate's top edge is far thicker than wide) and
# no wider than this many times its thickness (a board, a table's top, a slat), the samples' spacing aside: its
# width the widest disc inside its samples seen from above (``inscribed``; a frame of rails is as wide as a rail)
LONG = 2.0  # a bar: at least this many times as long as it is thick and wide
ROOM = 2.0  # a bar: free under it for at least this many times its thickness (a loop passes under it)
MIN_BAR = 3  # a bar: at least this many samples


@dataclass(frozen=True)
class Opening:
    """One opening (normalised frame): where it is, how wide and deep, and its rim."""

    middle: np.ndarray  # (2,) x, z: the middle of its cells' extent
    half: float  # half its width: the radius of the largest disc inside it
    reach: float  # how far from its middle it reaches at most (the farthest corner of its cells)
    rim: float  # the height the water spills at (its rim's)
    depth: float  # from the rim down to its floor's lowest point

    def describe(self, unit: float, floor: float) -> tuple[str, str]:
        """Its reason and its rim's, in target file units (``unit`` per normalised unit) over ``floor``."""
        at = f"{(self.rim - floor) * unit:.3g} above the bottom"
        return (f"an opening: {2 * self.half * unit:.3g} across, {self.depth * unit:.3g} deep, its rim {at}",
                f"a rim: round the opening {2 * self.half * unit:.3g} across, {at}")


@dataclass(frozen=True)
class Bar:
    """One bar (normalised frame)."""

    points: np.ndarray  # (M, 3) its up-facing samples
    middle: np.ndarray  # (3,) the middle of its crest
    axis: np.ndarray  # (3,) horizontal unit vector along it
    half: float  # half its length
    thickness: float
    room: float  # free height under it, down to the next part of the ground (inf: none is under it)

    def describe(self, unit: float, floor: float) -> str:
        """Its reason, in target file units (``unit`` per normalised unit) over ``floor``."""
        return (f"a bar: {2 * self.half * unit:.3g} long, {self.thickness * unit:.3g} thick, "
                f"{(self.middle[1] - floor) * unit:.3g} above the bottom, "
                + ("nothing under it" if math.isinf(self.room) else f"free for {self.room * unit:.3g} under it"))


def height_map(points: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray, float]:
    """The highest sample's height over each cell of a grid of side ``cell`` (x, z; -inf where the grid has no
    sample; gaps one cell wide inside the covered area closed with their neighbours' highest), the x, z of the
    grid's first cell's middle and the cell's side (``cell``, or larger: at most ``GRID`` cells a side)."""
    cell = grid_cell(points[:, [0, 2]], cell)
    low = points[:, [0, 2]].min(0) - cell / 2
    ij = np.floor((points[:, [0, 2]] - low) / cell).astype(int)
    height = np.full(ij.max(0) + 1, -np.inf)
    np.maximum.at(height, (ij[:, 0], ij[:, 1]), points[:, 1])
    covered = np.isfinite(height)
    gaps = ndimage.binary_closing(np.pad(covered, 1), structure=np.ones((3, 3)))[1:-1, 1:-1] & ~covered
    height[gaps] = ndimage.grey_dilation(height, size=(3, 3), mode="constant", cval=-np.inf)[gaps]
    return height, low + cell / 2, cell


def grid_cell(xz: np.ndarray, cell: float) -> float:
    """``cell``, or larger where the points ``xz`` (N, 2) would span more than ``GRID`` cells of it."""
    return max(cell, float(np.ptp(xz, axis=0).max()) / GRID)


def water_level(height: np.ndarray) -> np.ndarray:
    """The level water stands at over each cell of ``height`` poured in from all round and left to drain over
    the grid's edge (a morphological reconstruction by erosion; -inf where it drains away): at least the cell's
    own height."""
    cross = ndimage.generate_binary_structure(2, 1)
    # every cell full to the highest sample; a cell with nothing there stands or drains as its neighbours let it
    level = np.where(np.isfinite(height), np.max(height, initial=0.0), np.inf)
    while True:
        lower = np.maximum(ndimage.grey_erosion(level, footprint=cross, mode="constant", cval=-np.inf), height)
        if np.array_equal(lower, level):
            return level
        level = lower


def find_openings(points: np.ndarray, spacing: float) -> list[Opening]:
    """The ground's openings (see the module docstring), deepest first."""
    tall, size = float(np.ptp(points[:, 1])), float(np.ptp(points, axis=0).max())
    height, first, cell = height_map(points, CELL * spacing)
    level = water_level(height)
    standing = np.isfinite(level) & (level > height + MIN_DEPTH * spacing)
    joined = ndimage.binary_closing(np.pad(standing, JOIN_CELLS), structure=np.ones((3, 3)),
                                    iterations=JOIN_CELLS)[JOIN_CELLS:-JOIN_CELLS, JOIN_CELLS:-JOIN_CELLS]
    labels, count = ndimage.label(joined)
    found = []
    for k in range(1, count + 1):
        mask = labels == k  # with the cells of a handle over it
        water = mask & standing
        if water.sum() < MIN_CELLS or np.isfinite(height[water]).mean() < OWN_FLOOR:
            continue
        rim = float(np.median(level[water]))
        depth = rim - float(np.min(height[water & np.isfinite(height)]))
        width = float(max(2 * ndimage.distance_transform_edt(np.pad(mask, 1)).max() - 1, 1) * cell)
        if depth < max(MIN_DEPTH * spacing, DEEP * width, SHARE * tall) or width < SHARE * size:
            continue
        cells = first + np.argwhere(mask) * cell
        lo, hi = cells.min(0), cells.max(0)
        middle = (lo + hi) / 2
        reach = float(np.linalg.norm(cells - middle, axis=1).max()) + cell * math.sqrt(0.5)
        found.append(Opening(middle, width / 2, reach, rim, depth))
    return sorted(found, key=lambda o: -o.depth)


def thickness(points: np.ndarray, normals: np.ndarray, up: np.ndarray, spacing: float
              ) -> tuple[np.ndarray, np.ndarray]:
    """(U,) the ground's thickness under each up-facing sample ``up`` (indices): down to the highest down-facing
    sample below it within ``spacing`` of its column (the part's underside; inf where there is none), and (U,) the
    free height under that underside down to the next sample in the column (inf where there is none: the ground's
    bottom is no floor here, a rail on a wall hangs things below its own lowest point)."""
    thick, room = np.full(len(up), np.inf), np.full(len(up), np.inf)
    if not len(up):
        return thick, room
    row, other = column_neighbours(points[up], points, spacing)
    y, top = points[other, 1], points[up[row], 1]
    under = np.full(len(up), -np.inf)
    np.maximum.at(under, row, np.where((y < top) & (normals[other, 1] <= -UP), y, -np.inf))
    found = np.isfinite(under)
    thick[found] = points[up[found], 1] - under[found]
    below = np.full(len(up), -np.inf)
    np.maximum.at(below, row, np.where(y < under[row] - spacing, y, -np.inf))
    room[found] = under[found] - below[found]
    return thick, room


def column_neighbours(tops: np.ndarray, points: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Every pair of a sample of ``tops`` (T, 3) and a sample of ``points`` (P, 3) whose horizontal (x, z) distance is
    at most ``radius`` (the two in one column): (K,) rows of ``tops`` and (K,) rows of ``points``."""
    pairs = cKDTree(tops[:, [0, 2]]).sparse_distance_matrix(cKDTree(points[:, [0, 2]]), radius, output_type="ndarray")
    return pairs["i"].astype(np.int64), pairs["j"].astype(np.int64)


def find_bars(points: np.ndarray, normals: np.ndarray, spacing: float) -> list[Bar]:
    """The ground's bars (see the module docstring), longest first."""
    size = float(np.ptp(points, axis=0).max())
    up = np.flatnonzero(normals[:, 1] >= UP)
    thick, room = thickness(points, normals, up, spacing)
    thin = np.isfinite(thick) & (thick >= spacing)  # thinner: a sheet's edge, or too thin for the samples to see
    pts, thick, room = points[up[thin]], thick[thin], room[thin]
    if len(pts) < MIN_BAR:
        return []
    pairs = cKDTree(pts).query_pairs(JOIN * spacing, output_type="ndarray")
    ratio = thick[pairs[:, 0]] / thick[pairs[:, 1]]
    pairs = pairs[(ratio <= SAME) & (ratio >= 1 / SAME)]  # one part: its thickness changes little from sample to sample
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(pts), len(pts)))
    count, label = connected_components(graph, directed=False)
    bars = []
    for k in np.flatnonzero(np.bincount(label) >= MIN_BAR):
        member = label == k
        crest, t, free = pts[member], float(np.median(thick[member])), float(np.median(room[member]))
        width = inscribed(crest[:, [0, 2]], spacing)
        xz = crest[:, [0, 2]] - crest[:, [0, 2]].mean(0)
        direction = np.linalg.svd(xz, full_matrices=False)[2][0]
        along = xz @ direction
        length = float(np.ptp(along)) + spacing
        # the widest disc is measured to a cell: up to a spacing wide, down to a spacing narrow
        if (width > ROUND * t + spacing or t > ROUND * max(width - spacing, spacing)
                or length < max(LONG * max(t, width), SHARE * size)
                or free < ROOM * t):
            continue
        line = np.array([direction[0], 0.0, direction[1]])
        middle = crest.mean(0) + line * (along.max() + along.min()) / 2
        bars.append(Bar(crest, middle, line, length / 2, t, free))
    return sorted(bars, key=lambda b: -b.half)


def inscribed(xz: np.ndarray, spacing: float) -> float:
    """The diameter of the largest disc inside the area the samples ``xz`` (N, 2) cover: the samples on a grid of
    their spacing (at most ``GRID`` cells a side), closed over one cell (the gaps between samples), and the largest
    distance of a covered cell from an uncovered one."""
    cell = grid_cell(xz, spacing)
    cells = np.floor((xz - xz.min(0)) / cell).astype(int) + 1
    grid = np.zeros(cells.max(0) + 2, dtype=bool)
    grid[cells[:, 0], cells[:, 1]] = True
    grid = ndimage.binary_closing(grid, structure=np.ones((3, 3)))
    return float(max(2 * ndimage.distance_transform_edt(grid).max() - 1, 1) * cell)
