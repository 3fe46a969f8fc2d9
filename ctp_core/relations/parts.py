"""Parts of the ground the geometry can name, from the ground alone: where people put things on, beside or against it.

``PARTS`` is their registry: each part with its name (``reading.places.PartName``), its detector, the places a prompt
names that select it and the relations whose preference uses it; docs/relations.md, "Adding a part", says how to add
one, and ``check`` (run by the tests) what is inconsistent.

A relation holds in many places ("a cup on the table" holds on the whole top); its *usual place* (``Spec.usual``) is
one of these parts, centred: the support surface a person uses (the top of a table, the seat of a chair, the shelf
the prompt names), the middle of a side. ``find_parts`` finds them once per pair (``per_pair``), in the
normalised frame (+Y up, the ground's front and left as ``measures.axes`` gives them), from the samples of the object
the source relates to (``PreparedPair.anchor``):

- **support surfaces**: up-facing samples (normal within ``UP_COS`` of +Y) joined where they are near in height and
  across (``JOIN_SPACINGS`` sample spacings): a table's top, a chair's seat, a bookcase's boards, a bench's slats as
  one. Each has its height, area and, per sample, its *clearance*: how high a thing standing there can be before it
  meets the ground above it (inf where nothing is above);
- each surface named by the first part of ``PARTS`` whose detector takes it: **the top**, the highest surface; a
  **shelf**, a surface with the ground's underside above most of it (``COVERED``); **the seat**, another surface
  with a back rising behind it (ground higher than it by a third of its width along one of its edges, over at least
  ``BACK`` of that edge's length); else **a surface**;
- **the sides**: front, behind, left, right, each with its span across (where its middle is) and whether a person
  reaches it (``accessible``: a ground with a front of its own stands with its back against a wall).

``usual_surface`` picks the surface "on" means for a figure of a given size: the one the prompt's place names
(``RelationReading.place``: the top, a shelf by its order: the place's part in ``PARTS``), else the highest uncovered
surface that holds the figure with room (``room``: a table's top; a chair's seat, not its backrest's top rail).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ctp_core.pairs import PreparedPair, per_pair
from ctp_core.reading.places import OFF_MIDDLE, SHELVES, PartName, Place
from ctp_core.reading.records import RelationName
from ctp_core.relations import thin
from ctp_core.relations.measures import OFF_CENTRE, Context, axes, hinge, soft_min, toward

UP_COS = 0.85  # a support sample's normal: at least this cosine with +Y (a seat's gentle slope, not a dome's flank)
JOIN_SPACINGS = 3.0  # support samples this many sample spacings apart (across and in height) belong to one surface
COLUMN = 1.5  # a sample's column: this many sample spacings about it, seen from above
MIN_SAMPLES = 6  # a surface has at least this many samples (fewer: a rim's crest, an edge's bevel)
COVERED = 0.8  # a shelf: the ground above at least this share of its samples
BACK = 0.5  # a seat: ground rising over at least this share of one edge's length (its back)
SIDE_GAP = 0.1  # ``side_place``: a gap to the ground up to this many figure diagonals is "a hand's width"
FIT = 0.75  # ``usual_surface``: a surface holds a figure whose footprint overhangs it by up to a quarter (a cushion
# as large as the seat it is on: the judge's stability says whether it rests; this only chooses where)
ROOM_SHARE = 0.5  # ``usual_surface``: the highest surface with at least this share of the roomiest one's room
TOP_BAND = 0.05  # "on top of": the highest surface is the top where it is within this share of the ground's height
THIN_SAMPLES = 20000  # the ground's samples its thin parts are found on (``thin``): a peg a tenth of the ground
# wide has a few dozen
SIDES = (RelationName.FRONT, RelationName.BEHIND, RelationName.LEFT, RelationName.RIGHT)


@dataclass
class Surface:
    """One support surface (normalised frame)."""

    points: np.ndarray  # (M, 3) its samples
    clearance: np.ndarray  # (M,) free height above each sample (inf: open above)
    height: float  # the median height of its samples
    spacing: float  # the samples' spacing: area per sample is its square
    name: PartName = PartName.SURFACE  # the part it is (``PARTS``)
    reason: str = ""

    @property
    def area(self) -> float:
        return len(self.points) * self.spacing**2

    def free(self, height: float) -> np.ndarray:
        """(M,) bool: the samples where a figure ``height`` tall stands clear of the ground above."""
        return self.clearance >= height


@dataclass(frozen=True)
class GroundSide:
    """One side of the ground (normalised frame)."""

    name: RelationName  # front, behind, left, right
    direction: np.ndarray  # (3,) horizontal unit vector out of that side
    across: np.ndarray  # (3,) horizontal unit vector along the side
    reach: float  # the ground's farthest extent along ``direction``
    span: tuple[float, float]  # the ground's extent along ``across``
    accessible: bool
    reason: str = ""

    @property
    def middle(self) -> float:
        return (self.span[0] + self.span[1]) / 2

    @property
    def half(self) -> float:
        return max((self.span[1] - self.span[0]) / 2, 1e-9)


@dataclass(frozen=True)
class Parts:
    """The ground's named parts (``find_parts``); what is chosen on them per figure size is ``usual_spot``'s, kept
    beside them (``_spots``)."""

    surfaces: tuple[Surface, ...] = ()  # highest first
    sides: dict[RelationName, GroundSide] = field(default_factory=dict)
    height: float = 0.0  # the ground's height, normalised units
    floor: float = 0.0

    def describe(self) -> list[str]:
        """One line per named part, with its reason (reports, the page)."""
        lines = [s.reason for s in self.surfaces if s.name != PartName.SURFACE]
        lines += [s.reason for s in self.sides.values()]
        return lines


@dataclass(frozen=True)
class ThinParts:
    """The ground's thin parts (``thin_parts``), found apart from the others: only what reads them pays for them
    (``hang``, ``in``, the run's report)."""

    bars: tuple[thin.Bar, ...] = ()  # longest first
    openings: tuple[thin.Opening, ...] = ()  # deepest first
    unit: float = 1.0  # target file units per normalised unit: what reasons say
    floor: float = 0.0  # the ground's bottom, normalised frame

    def describe(self) -> list[str]:
        """One line per bar, opening and rim, with its size and height (reports, the page)."""
        lines = [b.describe(self.unit, self.floor) for b in self.bars]
        return lines + [line for o in self.openings for line in o.describe(self.unit, self.floor)]


def describe(pair: PreparedPair) -> list[str]:
    """Every named part of the pair's ground, with its reason: what a run's report lists."""
    return find_parts(pair).describe() + thin_parts(pair).describe()


@per_pair
def find_parts(pair: PreparedPair) -> Parts:
    """The pair's ground's ``Parts``, found on first use and kept while the pair lives."""
    anchor = pair.anchor
    points = anchor.points.detach().cpu().numpy().astype(np.float64)
    normals = anchor.normals.detach().cpu().numpy().astype(np.float64)
    spacing = pair.sample_spacing(len(pair.index.points))
    floor, top = float(points[:, 1].min()), float(points[:, 1].max())
    front, left = axes(torch.as_tensor(pair.target_front, dtype=torch.float32)[None], pair.front_trusted)
    surfaces = tuple(_surfaces(points, normals, spacing, floor, file_unit(pair)))
    return Parts(surfaces, _sides(points, front, left, pair.front_trusted), top - floor, floor)


@per_pair
def thin_parts(pair: PreparedPair) -> ThinParts:
    """The pair's ground's ``ThinParts`` (``relations.thin``, on ``THIN_SAMPLES`` samples of it), found on first use
    and kept while the pair lives."""
    points, normals, spacing = pair.anchor_samples(THIN_SAMPLES)
    floor = float(pair.anchor.points[:, 1].min())
    return ThinParts(tuple(thin.find_bars(points, normals, spacing)), tuple(thin.find_openings(points, spacing)),
                     file_unit(pair), floor)


def file_unit(pair: PreparedPair) -> float:
    """Target file units per normalised unit: what reasons say sizes and heights in."""
    return 1.0 / pair.target_to_normalised.scale


def _surfaces(points: np.ndarray, normals: np.ndarray, spacing: float, floor: float, unit: float) -> list[Surface]:
    up = np.flatnonzero(normals[:, 1] >= UP_COS)
    if len(up) < MIN_SAMPLES:
        return []
    pts = points[up]
    pairs = cKDTree(pts).query_pairs(JOIN_SPACINGS * spacing, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(pts), len(pts)))
    count, label = connected_components(graph, directed=False)
    clearance = _clearance(points, normals, pts, spacing)
    surfaces = [Surface(pts[label == k], clearance[label == k], float(np.median(pts[label == k, 1])), spacing)
                for k in range(count) if (label == k).sum() >= MIN_SAMPLES]
    surfaces.sort(key=lambda s: -s.height)
    for i, s in enumerate(surfaces):
        found = Found(s, i == 0, points, spacing, (s.height - floor) * unit, s.area * unit**2)
        s.name, s.reason = next((part.name, why) for part in PARTS.values() if part.detect is not None
                                for why in [part.detect(found)] if why is not None)
    return surfaces


def _clearance(points: np.ndarray, normals: np.ndarray, up: np.ndarray, spacing: float) -> np.ndarray:
    """(U,) for each up-facing sample, how far above it the nearest underside of the ground is (a down-facing
    sample within ``COLUMN`` spacings of its column, higher by more than ``JOIN_SPACINGS`` spacings: a board's
    underside, not a divider's face beside it); inf where none is."""
    down = points[normals[:, 1] <= -UP_COS]
    out = np.full(len(up), np.inf)
    if not len(down):
        return out
    row, other = thin.column_neighbours(up, down, COLUMN * spacing)
    above = down[other, 1] - up[row, 1]
    higher = above > JOIN_SPACINGS * spacing
    np.minimum.at(out, row[higher], above[higher])
    return out


@dataclass(frozen=True)
class Found:
    """A support surface as the parts' detectors see it: the surface, whether it is the highest, the ground's samples
    and their spacing, and its height over the ground's base and its area in target file units (what reasons say)."""

    surface: Surface
    highest: bool
    points: np.ndarray
    spacing: float
    height: float
    area: float

    @property
    def at(self) -> str:
        return f"facing up, {self.height:.3g} above the bottom, {self.area:.3g} square units (the file's units) in area"


def _top(f: Found) -> str | None:
    return f"the top: the highest surface, {f.at}" if f.highest else None


def _shelf(f: Found) -> str | None:
    covered = float(np.isfinite(f.surface.clearance).mean())
    return f"a shelf: {f.at}, the ground above {covered:.0%} of it" if covered >= COVERED else None


def _seat(f: Found) -> str | None:
    back = _back(f.surface, f.points, f.spacing)
    return None if back is None else f"the seat: {f.at}, a back rising behind it ({back})"


def _surface(f: Found) -> str:
    return f"a surface: {f.at}"


def _back(surface: Surface, points: np.ndarray, spacing: float) -> str | None:
    """Which edge of ``surface`` a back rises from (ground higher than the surface by a third of the surface's
    width, within twice ``JOIN_SPACINGS`` spacings of that edge, along at least ``BACK`` of it, counted in tenths of the
    edge); None where none does."""
    xz = surface.points[:, [0, 2]]
    lo, hi = np.percentile(xz, 2, axis=0), np.percentile(xz, 98, axis=0)
    rise = surface.height + np.min(hi - lo) / 3
    high = points[points[:, 1] >= rise]
    if not len(high):
        return None
    margin = JOIN_SPACINGS * spacing
    for axis, sign, name in ((1, -1, "-z"), (1, 1, "+z"), (0, -1, "-x"), (0, 1, "+x")):
        edge = lo[axis] if sign < 0 else hi[axis]
        other = 1 - axis
        near = high[np.abs(high[:, 2 * axis] - edge) <= 2 * margin]  # column 0 is x, 2 is z
        inside = near[(near[:, 2 * other] >= lo[other]) & (near[:, 2 * other] <= hi[other])]
        if not len(inside):
            continue
        bins = np.linspace(lo[other], hi[other], 11)
        covered = np.unique(np.digitize(inside[:, 2 * other], bins)).size / 10
        if covered >= BACK:
            return f"along its {name} edge"
    return None


def _sides(points: np.ndarray, front: torch.Tensor, left: torch.Tensor, trusted: bool
           ) -> dict[RelationName, GroundSide]:
    out = {}
    for name in SIDES:
        u = toward(name, front, left)[0].double().numpy()
        v = np.array([u[2], 0.0, -u[0]])
        along, across = points @ u, points @ v
        against = trusted and name == RelationName.BEHIND
        reason = (f"{name}: against the wall (a thing with a front usually stands with its back to a wall)" if against
                  else f"{name}: a person reaches it")
        out[name] = GroundSide(name, u, v, float(along.max()), (float(across.min()), float(across.max())), not against,
                           reason)
    return out


def usual_surface(found: Parts, height: float, footprint: tuple[float, float], place: Place | None = None
                  ) -> Surface | None:
    """The surface "on" means for a figure ``height`` tall with ``footprint`` (its shorter and longer horizontal
    sides), normalised units: the one ``place`` names (the top: the highest surface, where it is the ground's top,
    else None; a shelf by its order from the bottom among the covered surfaces), else the highest uncovered surface
    the figure fits (``room`` at least ``FIT``) with room (at least ``ROOM_SHARE`` of the roomiest's: a table's
    top; a chair's seat rather than its backrest's top rail; an armchair's seat rather than an arm its base only
    just fits); None where none fits (a spire, a head: the summit is the usual place)."""
    if place == Place.TOP:  # the highest surface where it is the ground's top; else a summit (a spire's tip)
        top = found.surfaces[0] if found.surfaces else None
        return top if top is not None and top.height >= found.floor + (1 - TOP_BAND) * found.height else None
    fits = [(s, room(s, height, footprint)) for s in found.surfaces]
    fits = [(s, r) for s, r in fits if r >= FIT]
    if not fits:
        return None
    if place in SHELVES:
        boards = sorted([s for s, _ in fits if s.name == PartName.SHELF] or [s for s, _ in fits],
                        key=lambda s: s.height)
        return boards[round(SHELVES[place] * (len(boards) - 1))]
    open_above = [(s, r) for s, r in fits if s.name != PartName.SHELF] or fits
    roomiest = max(r for _, r in open_above)
    return next(s for s, r in open_above if r >= ROOM_SHARE * roomiest)


def room(surface: Surface, height: float, footprint: tuple[float, float]) -> float:
    """How many times the figure's footprint's shorter side fits across the widest clear spot of ``surface``'s
    free area (``Surface.free``: clear of the ground above for its ``height``): the diameter of the largest disc
    inside it (``thin.inscribed``) over that side; 0 where the free area is smaller than ``FIT`` squared of the
    footprint's. A ring round a tower's top is as roomy as it is wide, not as its outer extent."""
    free = surface.free(height)
    if not free.any() or free.sum() * surface.spacing**2 < FIT**2 * footprint[0] * footprint[1]:
        return 0.0
    return thin.inscribed(surface.points[free][:, [0, 2]], surface.spacing) / max(footprint[0], 1e-12)


@per_pair
def upright_shape(pair: PreparedPair) -> tuple[float, float, float]:
    """(height, shorter horizontal side, longer horizontal side) of the source standing as it is set down
    (``source_upright``), in its diagonals: a posed figure's are these times its diagonal."""
    pts = pair.source_vertices.cpu().numpy().astype(np.float64) @ pair.source_upright.rotation.T
    sides = np.ptp(pts, axis=0)
    diagonal = max(float(np.linalg.norm(sides)), 1e-12)
    small, large = sorted((float(sides[0]), float(sides[2])))
    return float(sides[1]) / diagonal, small / diagonal, large / diagonal


@dataclass(frozen=True)
class Spot:
    """Where on the usual surface a figure goes: the surface, the middle (x, z) of its free area for the figure
    and that area's half diagonal extent (normalised units), from its samples' 5th to 95th percentiles (a stray
    sample does not widen it; a slatted seat's uneven samples do not move its middle)."""

    surface: Surface
    middle: np.ndarray
    half: float


def usual_spot(pair: PreparedPair, diagonal: float, place: Place | None) -> Spot | None:
    """``usual_surface`` and its ``Spot`` for the source at a posed diagonal ``diagonal`` (normalised units), kept
    per size and place beside the pair's parts (every preference of a run asks it again)."""
    chosen = _spots(pair)
    key = (round(diagonal, 9), place)
    if key not in chosen:
        height, small, large = upright_shape(pair)
        surface = usual_surface(find_parts(pair), height * diagonal, (small * diagonal, large * diagonal), place)
        chosen[key] = None if surface is None else _spot(surface, height * diagonal)
    return chosen[key]


@per_pair
def _spots(pair: PreparedPair) -> dict[tuple[float, Place | None], Spot | None]:
    """``usual_spot``'s answers for the pair, by size and place."""
    return {}


def _spot(surface: Surface, height: float) -> Spot:
    free = surface.free(height)
    xz = (surface.points[free] if free.any() else surface.points)[:, [0, 2]]
    low, high = np.percentile(xz, 5, axis=0), np.percentile(xz, 95, axis=0)
    return Spot(surface, (low + high) / 2, max(float(np.linalg.norm(high - low) / 2), 1e-9))


def spot_place(c: Context, spot: Spot) -> torch.Tensor:
    """(B,) how far the figure's centre is from where on the usual surface it goes (``spot``): the middle of its
    free area, in its half-spans; where the prompt names an end, an edge or a corner, how near the middle it is
    instead (and for a named end, how far toward the other end)."""
    place, half = c.place, spot.half
    offset = c.figure.centre[:, [0, 2]] - torch.as_tensor(spot.middle, dtype=c.unit.dtype, device=c.unit.device)
    if place not in OFF_MIDDLE:
        return offset.norm(dim=-1) / half
    away = (1.0 - offset.norm(dim=-1) / half).clamp_min(0.0)
    if place in (Place.LEFT_END, Place.RIGHT_END):
        sign = 1.0 if place == Place.LEFT_END else -1.0
        away = away + (-sign * (offset * c.left[:, [0, 2]]).sum(-1) / half).clamp_min(0.0)
    return away


def side_place(c: Context, side: GroundSide, gap: bool = True) -> torch.Tensor:
    """(B,) how far the figure is from the middle of ``side``: its centre's offset along the side from the side's
    middle, in the side's half-spans; how far its centre is short of being out beyond that side (figure diagonals);
    with ``gap``, its gap to the ground out that way (their extents', as a person sees a stool beside a desk, not
    to the nearest surface: a desk's top overhangs the room under it) past ``SIDE_GAP`` figure diagonals (a hand's
    width away, not across the room)."""
    as_t = lambda a: torch.as_tensor(a, dtype=c.unit.dtype, device=c.unit.device)  # noqa: E731
    centre = c.figure.centre
    across = ((centre @ as_t(side.across)) - side.middle).abs() / side.half
    beyond = (centre @ as_t(side.direction)) - side.reach
    out = across + hinge(-beyond / c.unit)
    if gap:  # the figure's nearest extent out that way past the ground's farthest: their bounding boxes' gap
        nearest = soft_min(c.figure.points @ as_t(side.direction), c.tau())
        out = out + hinge((nearest - side.reach) / c.unit - SIDE_GAP)
    return out


def bar_place(c: Context, bars: tuple[thin.Bar, ...]) -> torch.Tensor:
    """(B,) how far the figure's centre is from under the middle of the nearest of ``bars`` (hung from a bar, its
    centre is plumb under it): ``OFF_CENTRE`` x its offset along the bar in the bar's half-lengths, and its
    horizontal distance from the bar's crest (up to ``CREST_POINTS`` of its samples: two rails joined at their ends
    are one bar, and the middle of their extent is on neither) in figure diagonals."""
    as_t = lambda a: torch.as_tensor(a, dtype=c.unit.dtype, device=c.unit.device)  # noqa: E731
    centre = c.figure.centre[:, [0, 2]]
    costs = []
    for bar in bars:
        along = (centre - as_t(bar.middle[[0, 2]])) @ as_t(bar.axis[[0, 2]])
        crest = as_t(bar.points[:: -(-len(bar.points) // CREST_POINTS), [0, 2]])
        across = torch.cdist(centre, crest).min(-1).values
        costs.append(OFF_CENTRE * along.abs() / bar.half + across / c.unit)
    return torch.stack(costs, -1).min(-1).values


def through_openings(c: Context, openings: tuple[thin.Opening, ...]) -> torch.Tensor:
    """(B,) how far the figure is from in through the nearest of ``openings``: the share of its samples below the
    opening's rim that are out beyond its reach (through its wall: a pencil lying across a narrow holder, not
    standing in it), the least over the openings; a count, no gradient."""
    as_t = lambda a: torch.as_tensor(np.asarray(a), dtype=c.unit.dtype, device=c.unit.device)  # noqa: E731
    points = c.figure.points.detach()
    shares = [((points[..., [0, 2]] - as_t(o.middle)).norm(dim=-1) > o.reach) & (points[..., 1] < o.rim)
              for o in openings]
    return torch.stack([s.float().mean(-1) for s in shares], -1).min(-1).values


CREST_POINTS = 256  # ``bar_place``: a bar's crest samples its distance is measured to
MIDDLE_WIDTH = 0.2  # ``near_middle``: how far from a middle, in half-spans, still counts as near it
MIDDLE_WEIGHT = 4.0  # ... and how much more a sample there is drawn than one elsewhere


def near_side_middles(found: Parts, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(N,) a drawing weight for each of a ground's side samples (``points``, horizontal unit ``normals``): 1, and
    up to ``MIDDLE_WEIGHT`` more near the middle of the side a person reaches that the sample faces out of (a
    builder's share of poses at the usual place; the others keep every side's ends and corners in reach)."""
    weight = np.ones(len(points))
    for side in found.sides.values():
        if not side.accessible:
            continue
        facing = normals @ side.direction >= np.cos(np.pi / 4)
        weight += facing * near_middle((points @ side.across - side.middle) / side.half)
    return weight


def near_bar_middles(found: ThinParts, points: np.ndarray) -> np.ndarray:
    """(N,) a drawing weight for each of a ground's up-facing samples ``points``: 1, one more on a bar (within its
    thickness of its crest) and up to ``MIDDLE_WEIGHT`` more near that bar's middle."""
    weight = np.ones(len(points))
    for bar in found.bars:
        on = cKDTree(bar.points).query(points, k=1, workers=1)[0] <= bar.thickness
        weight += on * (1.0 + near_middle((points - bar.middle) @ bar.axis / bar.half))
    return weight


def near_middle(offset: np.ndarray) -> np.ndarray:
    """(N,) up to ``MIDDLE_WEIGHT``, falling off with ``offset`` from a middle (in half-spans) over
    ``MIDDLE_WIDTH``: what a builder's drawing weight adds near the usual place."""
    return MIDDLE_WEIGHT * np.exp(-0.5 * (offset / MIDDLE_WIDTH) ** 2)


# --- the registry --------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Part:
    """One part the geometry names: ``detect`` says why a support surface is this part (None: it is not; the sides
    are found by ``_sides``, no detector), ``places`` the places a prompt names that select it, ``relations`` those
    whose preference uses it."""

    name: PartName
    detect: Callable[[Found], str | None] | None
    places: frozenset[Place] = frozenset()
    relations: frozenset[RelationName] = frozenset()


_RESTING = frozenset({RelationName.ON, RelationName.STAND, RelationName.SIT, RelationName.LIE})
# In the order the detectors are asked (a surface is the first part that takes it; ``surface`` takes every one).
PARTS: dict[PartName, Part] = {p.name: p for p in (
    Part(PartName.TOP, _top, frozenset({Place.TOP}), _RESTING),
    Part(PartName.SHELF, _shelf, frozenset(SHELVES), _RESTING),
    Part(PartName.SEAT, _seat, frozenset(), _RESTING),
    Part(PartName.SURFACE, _surface, frozenset(OFF_MIDDLE), _RESTING),
    Part(PartName.SIDE, None, frozenset(), frozenset({*SIDES, RelationName.BESIDE, RelationName.LEAN})),
    Part(PartName.BAR, None, frozenset(), frozenset({RelationName.HANG})),
    Part(PartName.OPENING, None, frozenset(), frozenset({RelationName.IN})),
    Part(PartName.RIM, None, frozenset(), frozenset({RelationName.IN})),
)}


def check(parts: dict[PartName, Part]) -> list[str]:
    """What is inconsistent among the parts, the places and the relations (empty when nothing is): every part has a
    name of ``PartName`` and is filed under it, every place selects one part, every relation a part names exists,
    and the last detector takes every surface."""
    problems = [f"{name}: a part name without a part" for name in PartName if name not in parts]
    problems += [f"{name}: filed under another name" for name, part in parts.items() if part.name != name]
    for place in Place:
        owners = [p.name for p in parts.values() if place in p.places]
        if len(owners) != 1:
            problems.append(f"{place}: selects {len(owners)} parts ({owners})")
    problems += [f"{p.name}: names {r}, no relation" for p in parts.values() for r in p.relations
                 if r not in set(RelationName)]
    detectors = [p for p in parts.values() if p.detect is not None]
    if not detectors or detectors[-1].name != PartName.SURFACE:
        problems.append("the last detector is not the surface's (some surface would have no name)")
    return problems
