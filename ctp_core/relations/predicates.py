"""The prompt's relation judged by the geometry: how far a posed source is from satisfying it.

``relation_score(pair, poses, reading)`` gives one value per pose, shape (B,), in the objective's batched layout:
0 when the relation holds, growing with the violation, in diagonals of the relation's *figure* (the thing placed;
the source unless the reading makes it the ground, ``RelationReading.source_is_figure``), so the same
arrangement scores the same at any file scale. Each score is a sum of smooth hinges (``hinge``) on distances
and heights measured in the normalised frame (+Y up, the target upright; ``pairs``), from surface samples and
their outward normals; it is differentiable in the pose (nearest-sample *selection* carries no gradient, as in
``losses``), so it can be a refinement term as well as a ranking key and a report. ``holds(score)`` is the
verdict; ``verdict`` packs one pose's verdict for reports (``RelationVerdict``). ``stable`` is the
centre-of-mass-over-support check, usable as a metric and as an objective term.

Roles: with the source as the figure ("a cup on a table") the figure is the posed source and the *ground* is
the target (the related object of a scene, ``PreparedPair.anchor``); with the source as the ground ("a table
under a vase") the same definitions are read the other way round: the target is the figure and the posed
source its ground. The definitions, in words, are in ``docs/relations.md`` and in each ``_score_*`` docstring.

``JUDGES`` is the engine's one table of the relations: each relation's score and preference, under the name of its
record in ``priors.relations.RELATIONS`` (which says the rest: resting, stability, region weights).

Directions (sides, orientations) are the ground's own (``axes``: its front from ``PreparedPair.target_front`` or the
posed source's ``source_front``), or the viewer's where the pair's fronts cannot be trusted; a reading of two
relations (``front+facing``) scores their sum.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass
from functools import partial

import numpy as np
import torch
from scipy.spatial import ConvexHull, QhullError

from ctp_core import losses
from ctp_core.geometry import sampling
from ctp_core.geometry.pose import Poses, apply_pose, quaternion_to_matrix
from ctp_core.pairs import UP_FACING, PreparedPair, per_pair
from ctp_core.relations.vocabulary import RELATIONS, RelationReading
from ctp_core.render.cameras import FIRST_AZIMUTH

# --- constants (figure diagonals unless said otherwise) ------------------------------------------------------
FIGURE_POINTS = 192  # figure samples a score looks at: enough to find a contact patch, cheap for hundreds of poses
GROUND_POINTS = 256  # samples of a *posed* ground (the source in the ground role), compared by brute force
CONTACT = 0.03  # touching: within this of the ground surface (``_gap``: along the nearest normal): a cup's base
# on a table is within a few hundredths of its diagonal of the sampled top once settled by the search
SMOOTH = 0.02  # width of the quadratic start of every hinge: gradients stay continuous at the threshold
SOFT = 0.01  # temperature of the smooth minima/maxima over samples: a hundredth of a diagonal
HOLDS = 0.02  # a relation holds when its score is at most this (hinges are exactly 0 once within tolerance)
ON_TOP = 0.05  # "on top of": no ground surface higher than the figure's top by more than this over it
IN_DEPTH = 0.1  # "in": the figure's lowest point this far below the rim (less is resting on the rim)
UNDER_REACH = 0.5  # "under": a downward-facing ground sample above the figure within this of its centre's column
BESIDE_GAP = 0.5  # "beside": the gap at most this many *mean* diagonals of figure and ground
LEAN_RISE = 0.25  # "lean": the side contact at least this far above the figure's bottom (lying flat: ~0)
HANG_DROP = 0.05  # "hang": the centre of mass at least this far below the contact's mean height
WEAR_CENTRE = 0.5  # "wear": the ground's summit within this many figure half-widths of the centre's column
PENETRATE = (0.02, 0.9)  # "penetrate": the share of the figure inside the ground, in this open range
WRAP_SHARE = 0.3  # "wrap": at least this share of the figure touching (the relation table's contact is 0.6)
FIXED = 0.5  # ``preference`` "hang": hung under a down-facing surface (fixed to a ceiling) rather than resting on
# an up-facing one (a peg's top), in figure diagonals
FAR = 1.0  # a condition that has nothing to measure against (no overhead surface at all): a whole diagonal
NEAR_GAP = 1.0  # "near": the gap at most this many *mean* diagonals of figure and ground (twice ``BESIDE_GAP``)
FAR_GAP = 2.0  # "far": the gap at least this many mean diagonals
CLEAR = 2 * CONTACT  # "above", "below": the gap's bound in the score; what holds is a gap of at least ``CONTACT``
# (the score's tolerance, ``HOLDS`` + ``SMOOTH`` / 2, takes the rest): not touching
FACING = math.cos(math.radians(45.0))  # orientations: the figure's front within 45 degrees of the wanted direction
# ``preference``: among poses where the relation holds, which is the usual arrangement (see its docstring)
OFF_CENTRE = 0.5  # weight of the figure's distance from the ground's middle (in the ground's half-widths)
ENCLOSING_RAYS = 16  # ``_enclosure``: horizontal directions looked along from the figure's foot
FOOT = 0.05  # ``_enclosure``: the figure's foot, this far above its lowest point


@dataclass(frozen=True)
class RelationVerdict:
    """One pose's relation, as reports show it: the name, the source's role, the score and the verdict."""

    name: str
    role: str  # "figure" (the source is the thing placed) or "ground" (the target is placed on/in/... the source)
    score: float  # figure diagonals; 0 when it holds
    holds: bool
    stable: bool | None = None  # centre of mass over its support; None where the relation is not a resting one
    side: str | None = None  # the side of the ground the figure is on, where the reading names one
    frame: str | None = None  # whose front sides and orientations are judged in: "target" (its own) or "viewer"
    parts: list[dict] | None = None  # each relation of a reading that says two ("front+facing"): name, score, holds
    note: str | None = None  # what the verdict cannot judge here (``UNHELD``: nothing in the pair holds the figure up)

    def to_dict(self) -> dict:
        """The verdict as reports write it: ``side``, ``frame``, ``parts`` and ``note`` only where they say
        something."""
        out = asdict(self)
        return {k: v for k, v in out.items() if v is not None or k not in ("side", "frame", "parts", "note")}


# the verdict's ``note`` where a relation that asks no support (not ``steady``: above, below, hang, ...) leaves its
# figure touching neither its ground nor the floor: what holds it (a cord, a bracket, the wall behind) is not in the
# pair, so ``stable`` is None rather than a claim either way
UNHELD = ("nothing in the pair holds it up (it touches neither its ground nor the floor): a cord, bracket or wall "
          "that would is not modelled, and stability is not judged")


def frame(pair: PreparedPair) -> str:
    """Whose front the sides and orientations are judged in: the target's own where it can be trusted
    (``PreparedPair.front_trusted``), else the viewer's (the preview's first camera)."""
    return "target" if pair.front_trusted else "viewer"


def axes(front: torch.Tensor, trusted: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """(front, left) horizontal unit vectors (B, 3), normalised frame, of a ground whose front is ``front`` (B, 3):
    its own where ``trusted`` (left = up x front: glTF's front +Z with +Y up has its own left at +X), else the
    viewer's (the preview's first camera, ``cameras.FIRST_AZIMUTH``): front toward the viewer, left the viewer's
    left (an object facing the viewer has its own left on the viewer's right)."""
    if trusted:
        f = _horizontal(front)
        return f, torch.stack([f[..., 2], torch.zeros_like(f[..., 0]), -f[..., 0]], -1)
    a = math.radians(FIRST_AZIMUTH)
    as_t = lambda v: torch.tensor(v, dtype=front.dtype, device=front.device).expand_as(front)  # noqa: E731
    return as_t([math.sin(a), 0.0, math.cos(a)]), as_t([-math.cos(a), 0.0, math.sin(a)])


def toward(side: str, front: torch.Tensor, left: torch.Tensor) -> torch.Tensor:
    """The horizontal direction (B, 3) of a ground's ``side`` (``front``, ``behind``, ``left``, ``right``), from its
    ``axes``."""
    return {"front": front, "behind": -front, "left": left, "right": -left}[side]


def _horizontal(v: torch.Tensor) -> torch.Tensor:
    """``v`` (..., 3) with no vertical part, unit length (0 where it is vertical)."""
    flat = v * torch.tensor([1.0, 0.0, 1.0], dtype=v.dtype, device=v.device)
    return flat / flat.norm(dim=-1, keepdim=True).clamp_min(1e-9)


def holds(scores: torch.Tensor | float) -> torch.Tensor | bool:
    """The verdict of scores from ``relation_score``: at most ``HOLDS``."""
    if isinstance(scores, torch.Tensor):
        return scores <= HOLDS
    return bool(scores <= HOLDS)


def hinge(x: torch.Tensor, width: float = SMOOTH) -> torch.Tensor:
    """0 for x <= 0, x^2 / 2w up to w, then x - w/2: a hinge with a continuous gradient."""
    pos = x.clamp_min(0.0)
    return torch.where(pos < width, pos * pos / (2 * width), pos - width / 2)


def soft_min(x: torch.Tensor, tau: torch.Tensor | float, dim: int = -1, mask: torch.Tensor | None = None
             ) -> torch.Tensor:
    """The softmax(-x/tau)-weighted mean of x over ``dim``: smooth, never below the minimum, near it for a
    small tau; entries outside ``mask`` are left out (all out: +inf)."""
    logits = -x / tau
    if mask is not None:
        logits = logits.masked_fill(~mask, -torch.inf)
    w = torch.softmax(logits, dim=dim)
    out = (torch.nan_to_num(w, nan=0.0) * torch.where(torch.isfinite(x), x, torch.zeros_like(x))).sum(dim)
    if mask is not None:
        out = torch.where(mask.any(dim), out, torch.full_like(out, torch.inf))
    return out


def soft_max(x: torch.Tensor, tau: torch.Tensor | float, dim: int = -1, mask: torch.Tensor | None = None
             ) -> torch.Tensor:
    return -soft_min(-x, tau, dim, mask)


# --- one side of a relation, posed -------------------------------------------------------------------------------

@dataclass
class Side:
    """One object's samples in the normalised frame: (B or 1, N, 3) points and outward unit normals."""

    points: torch.Tensor
    normals: torch.Tensor
    centre: torch.Tensor  # (B or 1, 3) centre of mass stand-in: the mean of area-weighted surface samples
    diagonal: torch.Tensor  # (B or 1,) AABB diagonal, normalised units
    spacing: torch.Tensor  # (B or 1,) how far a surface point can be from its nearest sample
    tree: losses.SurfaceIndex | None = None  # a static side (the target): KD-tree queries instead of brute force

    @property
    def static(self) -> bool:
        return self.tree is not None


class _Ground:
    """Nearest ground samples to figure points, optionally restricted to a subset (e.g. up-facing)."""

    def __init__(self, side: Side, trees: dict[str, losses.SurfaceIndex | None]):
        self.side, self.trees = side, trees

    def mask(self, which: str) -> torch.Tensor:
        ny = self.side.normals[..., 1]
        return {"all": torch.ones_like(ny, dtype=torch.bool), "up": ny > UP_FACING, "down": ny < -UP_FACING,
                "side": ny.abs() <= UP_FACING, "not_down": ny >= -UP_FACING}[which]

    def nearest(self, points: torch.Tensor, which: str = "all") -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(u, n, found) for (B, N, 3) points: nearest ground sample of the subset, its normal, whether the subset
        has any sample (B, N) (points of a pose whose subset is empty get a far sample)."""
        side = self.side
        if side.static:
            tree = self.trees.get(which)
            if tree is None:  # an empty subset
                far = torch.full_like(points, 1e6)
                return far, torch.zeros_like(points), torch.zeros(points.shape[:2], dtype=torch.bool)
            idx = tree.neighbours(points, 1)[..., 0]
            return tree.points[idx], tree.normals[idx], torch.ones(points.shape[:2], dtype=torch.bool)
        mask = self.mask(which)  # (B, M)
        with torch.no_grad():
            d = torch.cdist(points.detach(), side.points.detach())
            d = d.masked_fill(~mask[:, None, :], torch.inf)
            idx = d.argmin(-1)  # (B, N)
        found = mask.any(-1)[:, None].expand(idx.shape)
        gather = lambda a: torch.gather(a, 1, idx[..., None].expand(-1, -1, 3))  # noqa: E731
        return gather(side.points), gather(side.normals), found


def _gap(points: torch.Tensor, ground: _Ground, which: str = "all") -> tuple[torch.Tensor, torch.Tensor]:
    """(B, N) distance from each point to the ground surface (the sampled surface as discs of the samples'
    spacing; 0 behind it), and the signed height along the normal (positive outside)."""
    return _gap_to(points, ground, *ground.nearest(points, which))


def _bearing_gap(points: torch.Tensor, ground: _Ground, which: str, reach: torch.Tensor) -> torch.Tensor:
    """(B, N) ``_gap`` from the side the ground surface faces: a point further behind it than ``reach`` (B,) is as
    far as it is deep. ``_gap`` is 0 anywhere behind, which makes a thin ground (a plate, a board) bear a figure
    from either side: a ball hanging under a board is not resting on it."""
    gap, along = _gap(points, ground, which)
    return torch.maximum(gap, -along - reach[:, None])


def _gap_to(points: torch.Tensor, ground: _Ground, u: torch.Tensor, n: torch.Tensor, found: torch.Tensor
            ) -> tuple[torch.Tensor, torch.Tensor]:
    """``_gap`` to given nearest ground samples ``u`` with normals ``n`` (``_Ground.nearest``)."""
    diff = points - u
    along = (diff * n).sum(-1)
    tangent = (diff - along[..., None] * n).norm(dim=-1)
    spacing = ground.side.spacing.reshape(-1, 1)
    gap = torch.sqrt(along.clamp_min(0.0) ** 2 + (tangent - spacing).clamp_min(0.0) ** 2 + 1e-12)
    far = torch.full_like(gap, 1e6)
    return torch.where(found, gap, far), torch.where(found, along, far)


# --- convex hulls: indices from detached points, geometry from live ones (gradients reach the points) -------------

def _hull_distance_2d(query: torch.Tensor, points: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """(B,) signed distance of query (B, 2) to the convex hull of points (B or 1, N, 2) (positive outside; the
    maximum over the hull's edge lines, exact inside and a lower bound outside). Fewer than three usable points:
    the distance to the nearest of them (a line's or a point's footprint)."""
    out = []
    shared = points.shape[0] == 1 and mask is None  # one hull for every pose (a static ground)
    edges = _edges_2d(points[0]) if shared else None
    for i in range(query.shape[0]):
        pts = points[i if points.shape[0] > 1 else 0]
        if mask is not None:
            pts = pts[mask[i if mask.shape[0] > 1 else 0]]
        out.append(_one_hull_2d(query[i], pts, edges if shared else _edges_2d(pts)))
    return torch.stack(out)


def _edges_2d(pts: torch.Tensor) -> torch.Tensor | None:
    """(E, 2) indices of the convex hull's edges; None when there is no 2-D hull (fewer than 3 points, a line)."""
    if len(pts) < 3:
        return None
    try:
        return torch.as_tensor(ConvexHull(pts.detach().cpu().double().numpy()).simplices, device=pts.device)
    except (QhullError, ValueError):
        return None


def _one_hull_2d(q: torch.Tensor, pts: torch.Tensor, simplices: torch.Tensor | None) -> torch.Tensor:
    if len(pts) == 0:
        return torch.tensor(FAR * 1e3, dtype=q.dtype, device=q.device)
    if simplices is None:  # collinear or too few: the distance to the nearest of the points
        return (pts - q).norm(dim=-1).min()
    a, c = pts[simplices[:, 0]], pts[simplices[:, 1]]
    edge = c - a
    normal = torch.stack([edge[:, 1], -edge[:, 0]], -1)
    normal = normal / normal.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    inner = pts.mean(0)
    sign = torch.sign(((a - inner) * normal).sum(-1)).detach()  # orient every edge normal outward
    normal = normal * torch.where(sign == 0, torch.ones_like(sign), sign)[:, None]
    return ((q - a) * normal).sum(-1).max()


def _hull_distance_3d(query: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """(B,) signed distance of query (B, 3) to the convex hull of points (B or 1, N, 3) (positive outside; the
    maximum over the facet planes). A flat ground has no hull: the distance to its nearest point."""
    out = []
    cache: dict[int, tuple] = {}
    for i in range(query.shape[0]):
        j = i if points.shape[0] > 1 else 0
        pts = points[j]
        if j not in cache:
            try:
                hull = ConvexHull(pts.detach().cpu().double().numpy())
                cache[j] = (torch.as_tensor(hull.simplices, device=pts.device),)
            except (QhullError, ValueError):
                cache[j] = (None,)
        (simplices,) = cache[j]
        if simplices is None:
            out.append((pts - query[i]).norm(dim=-1).min())
            continue
        a, b_, c = pts[simplices[:, 0]], pts[simplices[:, 1]], pts[simplices[:, 2]]
        normal = torch.linalg.cross(b_ - a, c - a)
        normal = normal / normal.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        sign = torch.sign(((a - pts.mean(0)) * normal).sum(-1)).detach()
        normal = normal * torch.where(sign == 0, torch.ones_like(sign), sign)[:, None]
        out.append(((query[i] - a) * normal).sum(-1).max())
    return torch.stack(out)


# --- what a pair needs once ---------------------------------------------------------------------------------------

@dataclass
class Features:
    """Per-pair samples the scores reuse (built once by ``features``; the target never moves)."""

    source_points: torch.Tensor  # (FIGURE_POINTS, 3) source local frame
    source_normals: torch.Tensor  # (FIGURE_POINTS, 3) source local frame, unit
    source_centre: torch.Tensor  # (3,) source local frame: mean of area-weighted samples
    source_spacing: float  # source local units: sqrt(area / count)
    target: Side  # the related object (``PreparedPair.anchor``), static
    target_trees: dict[str, losses.SurfaceIndex | None]  # per normal subset ("up", "down", "side", ...)
    target_figure: Side  # a subset of the target as a figure (the ground role), static


@per_pair
def features(pair: PreparedPair) -> Features:
    """The pair's ``Features``, built on first use and kept while the pair lives."""
    with torch.inference_mode(False), torch.no_grad():  # normal tensors: the refinement's gradient reuses them
        return _build(pair)


def _build(pair: PreparedPair) -> Features:
    device = pair.source_samples.device
    as_t = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32, device=device)  # noqa: E731
    pts, nrm = sampling.surface_samples(pair.source, FIGURE_POINTS, seed=17)
    local = pair.source_to_local
    s_points = as_t(local.apply(pts))
    s_normals = torch.nn.functional.normalize(as_t(local.apply_directions(nrm)), dim=-1)
    s_area = float(pair.source.area) * local.scale**2
    anchor = pair.anchor
    t_points, t_normals = anchor.points, torch.nn.functional.normalize(anchor.normals, dim=-1)
    lo, hi = t_points.min(0).values, t_points.max(0).values
    diag = (hi - lo).norm()
    t_spacing = pair.sample_spacing(len(pair.index.points))
    target = Side(t_points[None], t_normals[None], t_points.mean(0)[None], diag[None],
                  torch.tensor([t_spacing], device=device), anchor)
    ny = t_normals[:, 1]
    subsets = {"all": torch.ones_like(ny, dtype=torch.bool), "up": ny > UP_FACING, "down": ny < -UP_FACING,
               "side": ny.abs() <= UP_FACING, "not_down": ny >= -UP_FACING}
    trees = {k: (anchor if k == "all" else losses.SurfaceIndex(t_points[m], t_normals[m]) if m.any() else None)
             for k, m in subsets.items()}
    pick = torch.linspace(0, len(t_points) - 1, min(GROUND_POINTS, len(t_points))).long()
    figure = Side(t_points[pick][None], t_normals[pick][None], t_points.mean(0)[None], diag[None],
                  torch.tensor([t_spacing], device=device), anchor)
    centre = as_t(local.apply(pts.mean(0)[None])[0])
    return Features(s_points, s_normals, centre, math.sqrt(s_area / FIGURE_POINTS), target, trees, figure)


def posed_source(feat: Features, poses: Poses) -> Side:
    """The source's samples at each pose, (B, N, 3), with its centre, diagonal and sample spacing."""
    pts = apply_pose(feat.source_points, poses.t, poses.q, poses.log_s)
    rot = quaternion_to_matrix(poses.q)
    nrm = torch.einsum("bij,nj->bni", rot, feat.source_normals)
    centre = apply_pose(feat.source_centre[None], poses.t, poses.q, poses.log_s)[:, 0]
    scale = poses.log_s.exp()
    local = feat.source_points
    diag = (local.max(0).values - local.min(0).values).norm() * scale
    return Side(pts, nrm, centre, diag, feat.source_spacing * scale)


def _roles(pair: PreparedPair, poses: Poses, placed: bool) -> tuple[Side, _Ground, torch.Tensor]:
    """(figure, ground, floor height (B,)) for either role: ``placed``, the source is the figure."""
    feat = features(pair)
    source = posed_source(feat, poses)
    b = len(poses)
    if placed:
        floor = torch.full((b,), pair.floor, device=source.points.device)
        return source, _Ground(feat.target, feat.target_trees), floor
    fig = feat.target_figure
    figure = Side(fig.points.expand(b, -1, -1), fig.normals.expand(b, -1, -1), fig.centre.expand(b, -1),
                  fig.diagonal.expand(b), fig.spacing.expand(b))
    floor = soft_min(source.points[..., 1], SOFT * source.diagonal[:, None])  # the ground's lowest level
    return figure, _Ground(source, {}), floor


def _context(pair: PreparedPair, poses: Poses, reading: RelationReading | None) -> _Ctx:
    """The figure, the ground, the floor and the fronts for either role: the target's front
    (``PreparedPair.target_front``, normalised frame) and the posed source's (``source_front``, turned by the pose);
    the ground's axes in its own frame or the viewer's (``axes``)."""
    placed = reading is None or reading.source_is_figure  # no relation: the source is what is placed
    figure, ground, floor = _roles(pair, poses, placed)
    as_t = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32, device=poses.t.device)  # noqa: E731
    own = torch.einsum("bij,j->bi", quaternion_to_matrix(poses.q), as_t(pair.source_front))
    target = as_t(pair.target_front).expand(len(poses), 3)
    ground_front, figure_front = (target, own) if placed else (own, target)
    front, left = axes(ground_front, pair.front_trusted)
    flat = figure_front * torch.tensor([1.0, 0.0, 1.0], device=figure_front.device)
    return _Ctx(figure, ground, floor, front=front, left=left, heading=flat)


# --- the relations ------------------------------------------------------------------------------------------------

@dataclass
class _Ctx:
    figure: Side
    ground: _Ground
    floor: torch.Tensor  # (B,)
    depth: torch.Tensor | None = None  # ``_support_depth``, once computed (a convex hull per pose)
    front: torch.Tensor | None = None  # (B, 3) the ground's front, horizontal (``axes``): sides are named from it
    left: torch.Tensor | None = None  # (B, 3) the ground's left, horizontal
    heading: torch.Tensor | None = None  # (B, 3) the figure's own front (unit), its vertical part dropped: as long
    # as the cosine of its elevation, so a front pointing up faces nothing (a chair lying on its back)

    @property
    def unit(self) -> torch.Tensor:  # (B,) figure diagonal
        return self.figure.diagonal

    def tol(self) -> torch.Tensor:
        """(B,) height tolerance, normalised units: ``CONTACT`` figure diagonals (a bottom band, the floor)."""
        return CONTACT * self.unit

    def reach(self) -> torch.Tensor:
        """(B,) contact tolerance of a gap to the ground's surface: ``tol``, and at least a third of the ground's
        sample spacing, the sampled surface's resolution as ``contact.settle`` allows it (a sample counts inside
        only past a third of the spacing); the spacing is in ``_gap`` tangentially, but along the normal a
        coarsely sampled tip rises between its samples: a small cross settled on a church's spire stood 1.15 x
        ``tol`` above its nearest up-facing sample."""
        return torch.maximum(self.tol(), self.ground.side.spacing.reshape(-1).expand_as(self.unit) / 3)

    def tau(self) -> torch.Tensor:
        return (SOFT * self.unit)[:, None]

    def bottom(self) -> torch.Tensor:
        return soft_min(self.figure.points[..., 1], self.tau())

    def top(self) -> torch.Tensor:
        return soft_max(self.figure.points[..., 1], self.tau())

    def h(self, x: torch.Tensor) -> torch.Tensor:
        """hinge of a length in normalised units, in figure diagonals."""
        return hinge(x / self.unit)

    def finite(self, x: torch.Tensor) -> torch.Tensor:
        """x with +inf (nothing to measure against) replaced by ``FAR`` figure diagonals."""
        return torch.where(torch.isfinite(x) & (x < 1e3), x, FAR * self.unit)

    def touching(self, which: str = "all") -> torch.Tensor:
        """Violation of contact with the ground's ``which`` surface: smooth min gap over the figure - tolerance."""
        gap, _ = _gap(self.figure.points, self.ground, which)
        return self.h(self.finite(soft_min(gap, self.tau())) - self.reach())


def _score_resting(c: _Ctx) -> torch.Tensor:
    """Resting on (``on``, ``stand``, ``sit``, ``lie``): supported from below by ground surface that faces up,
    on the side it faces (so the centre of mass is above the contact: never from under a thin ground); its
    centre of mass over that support; and on top of it: no part of the ground higher than the figure's top
    over the figure's footprint (a cup on a table's lower shelf, or under the table, is not on it).

    Sum of: the figure's lowest part within contact of up-facing ground surface (the bottom band: samples
    within ``CONTACT`` of the figure's lowest point, their smooth minimum ``_bearing_gap`` to up-facing samples);
    ``stable`` (the centre's horizontal distance outside the footprint of the support patch); the height
    of the ground above the figure's top, over its footprint, past ``ON_TOP``.
    """
    fig = c.figure
    gap = _bearing_gap(fig.points, c.ground, "up", c.reach())
    band = fig.points[..., 1] <= (c.bottom() + c.tol())[:, None]
    support = c.h(c.finite(soft_min(gap, c.tau(), mask=band)) - c.reach())
    return torch.minimum(support, _apex(c)) + _stability(c) + _overhead(c)


def _apex(c: _Ctx) -> torch.Tensor:
    """Support by a summit: a cross on a spire's tip, a ball on a post's top. The tip is a point, sampled
    sparsely and facing sideways around it, so no up-facing sample need be near; it bears the figure when a
    summit of the ground (``_summits``, the figure's half-width as the neighbourhood) lies under the figure's
    footprint (within its half-width of the centre's column) at its bottom (within ``reach`` and the ground's
    sample spacing): 0 there, ``FAR`` elsewhere (the up-facing support, ``_score_resting``, says how far). A
    cup touching a table's leg with its base's edge is beside no summit: the table's top is higher."""
    fig = c.figure
    width = _half_width(fig)
    peaks = _summits(c.ground.side, float(width.mean())).detach()  # (B or 1, P, 3)
    offset = (peaks[..., [0, 2]] - fig.centre[:, None, [0, 2]]).norm(dim=-1)
    slack = (c.reach() + c.ground.side.spacing.reshape(-1).expand_as(c.unit))[:, None]
    under = (offset <= width[:, None]) & ((peaks[..., 1] - c.bottom()[:, None]).abs() <= slack)
    return torch.where(under.detach().any(-1), torch.zeros_like(c.unit), torch.full_like(c.unit, FAR))


def _overhead(c: _Ctx) -> torch.Tensor:
    """How far ground surface rises above the figure's top over its footprint (figure diagonals, hinged)."""
    fig, ground = c.figure, c.ground.side
    radius = _half_width(fig)  # (B,)
    gp = ground.points.expand(fig.points.shape[0], -1, -1)
    horizontal = (gp[..., [0, 2]] - fig.centre[:, None, [0, 2]]).norm(dim=-1)
    over = horizontal <= radius[:, None]
    height = soft_max(gp[..., 1], c.tau(), mask=over)
    height = torch.where(torch.isfinite(height), height, torch.full_like(height, -1e3))
    return c.h(height - c.top() - ON_TOP * c.unit)


def _half_width(fig: Side) -> torch.Tensor:
    """(B,) the figure's horizontal half-extent about its centre (the largest horizontal sample distance)."""
    return (fig.points[..., [0, 2]] - fig.centre[:, None, [0, 2]]).norm(dim=-1).max(-1).values.detach()


def _support_mask(c: _Ctx) -> torch.Tensor:
    """(B, N) the figure samples that bear weight: touching ground surface that does not face down, or the floor."""
    gap, _ = _gap(c.figure.points, c.ground, "not_down")
    return (gap <= c.reach()[:, None]) | (c.figure.points[..., 1] - c.floor[:, None] <= c.tol()[:, None])


def _support_depth(c: _Ctx) -> torch.Tensor:
    """(B,) signed horizontal distance of the centre's projection to the convex footprint of the support patch
    (positive outside, normalised units); a whole ``FAR`` figure diagonal with no support at all."""
    if c.depth is None:
        mask = _support_mask(c).detach()
        dist = _hull_distance_2d(c.figure.centre[:, [0, 2]], c.figure.points[..., [0, 2]], mask)
        c.depth = torch.where(mask.any(-1), dist, torch.full_like(dist, FAR) * c.unit)
    return c.depth


def _stability(c: _Ctx) -> torch.Tensor:
    """Horizontal distance (figure diagonals, hinged) of the centre's projection outside the convex footprint
    of the support patch (``_support_depth``)."""
    return c.h(_support_depth(c))


def _score_in(c: _Ctx) -> torch.Tensor:
    """``in``: inside the ground's cavity: the figure's lowest point below the ground's rim (its top) by at least
    ``IN_DEPTH`` and inside the ground's convex hull under its centre (so inside the hull's footprint), resting
    on the inner floor or walls (in contact with the ground). A candle in a holder or a lipstick in its cover
    sticks out above the rim: its centre need not be below it, its foot must."""
    fig, ground = c.figure, c.ground.side
    rim = ground.points[..., 1].max(-1).values.expand_as(c.unit)
    foot = torch.stack([fig.centre[:, 0], c.bottom(), fig.centre[:, 2]], -1)
    hull = _hull_distance_3d(foot, ground.points)
    return c.h(c.bottom() - rim + IN_DEPTH * c.unit) + c.h(hull) + c.touching()


def _score_under(c: _Ctx) -> torch.Tensor:
    """``under``: below a downward-facing part of the ground and inside its footprint, standing where the ground
    stands (its lowest level). Sum of: the horizontal distance from the figure's centre to the nearest
    downward-facing ground sample above the figure's top, past ``UNDER_REACH`` figure half-widths (a vertical
    shortfall counts as distance too); the figure's centre outside the ground's footprint; its bottom off the
    floor (above or below it) past contact."""
    fig, ground = c.figure, c.ground.side
    gp = ground.points.expand(fig.points.shape[0], -1, -1)
    down = c.ground.mask("down").expand(gp.shape[:2])
    horizontal = (gp[..., [0, 2]] - fig.centre[:, None, [0, 2]]).norm(dim=-1)
    below = (c.top()[:, None] - gp[..., 1]).clamp_min(0.0)  # the ground sample lower than the figure's top
    reach = soft_min(horizontal + below, c.tau(), mask=down)
    reach = torch.where(torch.isfinite(reach), reach, FAR * c.unit)
    overhead = c.h(reach - UNDER_REACH * _half_width(fig))
    inside = c.h(_hull_distance_2d(fig.centre[:, [0, 2]], ground.points[..., [0, 2]]))
    return overhead + inside + c.h((c.bottom() - c.floor).abs() - c.tol())


def _score_beside(c: _Ctx) -> torch.Tensor:
    """``beside`` (next to, behind, in front of): on the ground's floor (the figure's bottom at the ground's
    lowest level), its centre outside the ground's footprint, and a gap to the ground at most ``BESIDE_GAP``
    mean diagonals; contact is not required."""
    fig, ground = c.figure, c.ground.side
    floor = c.h((c.bottom() - c.floor).abs() - c.tol())
    outside = c.h(-_hull_distance_2d(fig.centre[:, [0, 2]], ground.points[..., [0, 2]]))
    gap, mean_diag = _apart(c)
    return floor + outside + c.h(gap - BESIDE_GAP * mean_diag)


def _apart(c: _Ctx) -> tuple[torch.Tensor, torch.Tensor]:
    """(B,) the gap between the figure and the ground's surface (a smooth minimum over the figure's samples), and
    the mean of their diagonals, normalised units."""
    gap, _ = _gap(c.figure.points, c.ground)
    return c.finite(soft_min(gap, c.tau())), (c.unit + c.ground.side.diagonal.expand_as(c.unit)) / 2


def _score_side(c: _Ctx, side: str) -> torch.Tensor:
    """``front``, ``behind``, ``left``, ``right``: ``beside`` the ground on that side of it, in its own frame
    (``axes``: the viewer's where its front cannot be trusted): the figure's centre beyond the ground's extent
    that way (its farthest sample along the side's direction) by more than it is beyond the ground's extent either
    way across (a wedge from the ground's corners: a box level with a sofa's left end and a little in front is on
    its left; one well in front of that end is in front)."""
    way = toward(side, c.front, c.left)
    across = c.left if side in ("front", "behind") else c.front
    aside = torch.maximum(_beyond(c, across), _beyond(c, -across)).clamp_min(0.0)
    return _score_beside(c) + c.h(aside - _beyond(c, way))


def _beyond(c: _Ctx, direction: torch.Tensor) -> torch.Tensor:
    """(B,) how far the figure's centre lies beyond the ground's farthest sample along ``direction`` (B, 3)."""
    extent = (c.ground.side.points * direction[:, None, :]).sum(-1).max(-1).values
    return (c.figure.centre * direction).sum(-1) - extent


def _score_above(c: _Ctx) -> torch.Tensor:
    """``above`` (no contact: a painting above a sofa, a lamp over a table; Sr3D's): the figure's bottom higher than
    the ground's top by more than contact (``CLEAR``), their footprints overlapping (``_overlap``)."""
    top = c.ground.side.points[..., 1].max(-1).values.expand_as(c.unit)
    return c.h(top + CLEAR * c.unit - c.bottom()) + _overlap(c)


def _score_below(c: _Ctx) -> torch.Tensor:
    """``below``: the figure's top lower than the ground's *underside over it* (the lowest ground surface over the
    figure's footprint: within its half-width of its centre's column) by more than contact, their footprints
    overlapping (``_overlap``). Sr3D's "below" (under the ground's bottom) where the ground is compact (a lamp hung
    over a box); under a lifted part of a ground that stands on the floor (a shelf board between its uprights, a
    desk's top) too, where Sr3D's can never hold. A ground with nothing lifted over the figure (a block on the
    floor) leaves no room: the score is then least tucked low against it, and never holds. ``under`` is the
    same place standing on the floor; ``below`` asks no contact with anything."""
    fig = c.figure
    gp = c.ground.side.points.expand(fig.points.shape[0], -1, -1)
    over = (gp[..., [0, 2]] - fig.centre[:, None, [0, 2]]).norm(dim=-1) <= _half_width(fig)[:, None]
    clearance = soft_min(gp[..., 1], c.tau(), mask=over) - c.top()
    clearance = torch.where(torch.isfinite(clearance), clearance, -FAR * c.unit)  # nothing over it
    return c.h(CLEAR * c.unit - clearance) + _overlap(c)


def _overlap(c: _Ctx) -> torch.Tensor:
    """How far the footprints (seen from above) are from overlapping: the figure's centre farther than its own
    half-width from the ground's footprint (its convex hull), figure diagonals, hinged."""
    hull = _hull_distance_2d(c.figure.centre[:, [0, 2]], c.ground.side.points[..., [0, 2]])
    return c.h(hull - _half_width(c.figure))


def _score_near(c: _Ctx) -> torch.Tensor:
    """``near``: the gap to the ground at most ``NEAR_GAP`` mean diagonals of the two (a scale-free band: a cup
    near a plate is a few centimetres away, a car near a house a few metres)."""
    gap, mean_diag = _apart(c)
    return c.h(gap - NEAR_GAP * mean_diag)


def _score_far(c: _Ctx) -> torch.Tensor:
    """``far``: the gap to the ground at least ``FAR_GAP`` mean diagonals of the two."""
    gap, mean_diag = _apart(c)
    return c.h(FAR_GAP * mean_diag - gap)


def _score_facing(c: _Ctx, sign: float) -> torch.Tensor:
    """``facing`` (sign 1; Holodeck's "face to") and ``facing_away`` (-1): the figure's own front within 45 degrees
    (``FACING``) of the horizontal direction to the ground's centre, or of the direction away from it (a chair lying
    on its back, its front up, faces nothing). In cosine units (scale-free by nature)."""
    toward = _horizontal(c.ground.side.centre - c.figure.centre)
    return hinge(FACING - sign * (c.heading * toward).sum(-1))


def _score_aligned(c: _Ctx) -> torch.Tensor:
    """``aligned`` (with): the figure's front within 45 degrees of the ground's horizontal front (``axes``; the
    viewer's frame makes it face the viewer). In cosine units."""
    return hinge(FACING - (c.heading * c.front).sum(-1))


def _score_lean(c: _Ctx) -> torch.Tensor:
    """``lean``: touching a side of the ground (a sideways-facing surface) at least ``LEAN_RISE`` above the
    figure's bottom, while that bottom is on the floor (a board lying flat against a box's foot only touches
    at the floor)."""
    fig = c.figure
    gap, _ = _gap(fig.points, c.ground, "side")
    raised = fig.points[..., 1] >= (c.bottom() + LEAN_RISE * c.unit)[:, None]
    side = c.h(c.finite(soft_min(gap, c.tau(), mask=raised)) - c.reach())
    return side + c.h((c.bottom() - c.floor).abs() - c.tol())


def _score_hang(c: _Ctx) -> torch.Tensor:
    """``hang``: in contact with the ground, the contact at the figure's upper part: the centre of mass at least
    ``HANG_DROP`` below the highest touching sample (a ring hangs from a peg through it; resting on top of the
    peg, its centre is above every contact)."""
    fig = c.figure
    gap, _ = _gap(fig.points, c.ground)
    touching = gap <= c.reach()[:, None]
    nearest = gap <= gap.min(-1, keepdim=True).values  # no contact: the nearest sample stands for it
    height = soft_max(fig.points[..., 1], c.tau(), mask=(touching | nearest).detach())
    return c.touching() + c.h(fig.centre[:, 1] - height + HANG_DROP * c.unit)


def _score_wear(c: _Ctx) -> torch.Tensor:
    """``wear``: on a summit of the ground (a peak of its top surface: a head's top, ``sampling.summits`` with
    the figure's width as the neighbourhood; the one nearest the figure), covering it: that summit within
    ``WEAR_CENTRE`` figure half-widths of the figure's centre column, the figure's bottom below it, in contact."""
    fig, ground = c.figure, c.ground.side
    width = _half_width(fig)
    peaks = _summits(ground, float(width.mean()))  # (B or 1, P, 3)
    offset = (peaks[..., [0, 2]] - fig.centre[:, None, [0, 2]]).norm(dim=-1)  # (B, P)
    above = (c.bottom()[:, None] - peaks[..., 1]).clamp_min(0.0)  # the figure's bottom above the peak: not covering
    cost = soft_min(hinge((offset - WEAR_CENTRE * width[:, None]) / c.unit[:, None])
                    + hinge(above / c.unit[:, None]), SOFT)
    return cost + c.touching()


def _summits(ground: Side, radius: float) -> torch.Tensor:
    """(B or 1, P, 3) the ground's summit samples (``sampling.summits``: highest in their column and its
    neighbours, ``radius`` cells); a posed ground (one per pose) keeps its highest sample only."""
    if not ground.static:
        idx = ground.points[..., 1].argmax(-1)
        return torch.gather(ground.points, 1, idx[:, None, None].expand(-1, 1, 3))
    pts = ground.points[0]
    peaks = sampling.summits(pts.detach().cpu().double().numpy(), radius)
    return pts[torch.as_tensor(peaks, dtype=torch.long, device=pts.device)][None]


def _score_penetrate(c: _Ctx) -> torch.Tensor:
    """``penetrate``: a bounded share of the figure inside the ground (between ``PENETRATE``'s bounds, as a
    smooth count of samples behind the ground's surface), so it enters through the surface and stays partly
    out."""
    _, along = _gap(c.figure.points, c.ground)
    inside = torch.sigmoid(-along / c.tau()).mean(-1)
    lo, hi = PENETRATE
    return hinge(lo - inside) + hinge(inside - hi)


def _score_attach(c: _Ctx) -> torch.Tensor:
    """``attach``: in contact with the ground's surface (glued, mounted, clipped: a face or a foot)."""
    return c.touching()


def _score_hold(c: _Ctx) -> torch.Tensor:
    """``hold``: in contact with the ground, at its side surfaces (a hand closes around a handle from the side),
    not set on top of it: the figure's centre below the ground's top."""
    ground_top = c.ground.side.points[..., 1].max(-1).values
    return c.touching("side") + c.h(c.figure.centre[:, 1] - ground_top)


def _score_wrap(c: _Ctx) -> torch.Tensor:
    """``wrap``: around a part of the ground: at least ``WRAP_SHARE`` of the figure's samples touching it (a
    smooth count)."""
    gap, _ = _gap(c.figure.points, c.ground)
    share = torch.sigmoid((c.reach()[:, None] - gap) / c.tau()).mean(-1)
    return c.touching() + hinge(WRAP_SHARE - share)


def relation_score(pair: PreparedPair, poses: Poses, reading: RelationReading | None) -> torch.Tensor:
    """(B,) how far each pose is from satisfying the ``reading`` (figure diagonals; 0 when it holds).

    A reading that makes the source the ground reads it the other way round (the target placed relative to the
    posed source). An unknown relation or None has no term: zeros. Differentiable in ``poses``.
    """
    if reading is None or not reading.known:
        return torch.zeros(len(poses), device=poses.t.device)
    return _score(_context(pair, poses, reading), reading)


def terms(pair: PreparedPair, poses: Poses, reading: RelationReading | None) -> dict[str, torch.Tensor]:
    """``rel`` (``relation_score``), ``stable`` (``stable`` for the readings it applies to that do not rest on
    their ground, ``Relation.steady`` but not ``rests``: the resting ones include it in their score; zeros
    otherwise) and ``prefer`` (``preference``), from one posing of the samples and one support footprint per pose
    (the objective's relation terms)."""
    zeros = torch.zeros(len(poses), device=poses.t.device)
    if reading is None or not reading.known:
        return {"rel": zeros, "stable": zeros, "prefer": zeros}
    c = _context(pair, poses, reading)
    steady = _stability(c) if reading.steady and not reading.rests else zeros
    return {"rel": _score(c, reading), "stable": steady, "prefer": sum(_prefer(c, p) for p in reading.parts)}


def stable(pair: PreparedPair, poses: Poses, reading: RelationReading | None = None) -> torch.Tensor:
    """(B,) how far the figure's centre of mass is from being over its support (figure diagonals, hinged; 0 when
    stable): its horizontal projection against the convex footprint of the samples touching ground surface that
    does not face down, or the floor. The figure is the reading's (the source without one). Differentiable in
    ``poses``; ``holds`` gives the verdict."""
    return _stability(_context(pair, poses, reading))


def preference(pair: PreparedPair, poses: Poses, reading: RelationReading | None) -> torch.Tensor:
    """(B,) how far each pose is from the *usual* arrangement of a relation that holds in many places (lower is
    better, about 0 to 2; zeros where the relation says nothing more): "a cup on the table" holds on the whole
    top, the corner included, and geometry at contact (soft-ICP) favours corners and edges, where more target
    samples fall near the source. Read among poses where the relation holds; never part of the verdict.

    - resting (``on``, ``stand``, ``sit``, ``lie``): on the *top* (``drop``: the height between the ground's
      highest point and the figure's bottom, in figure diagonals, either way: held a hair above a table's top,
      within the contact tolerance, is not resting on it; a cross "on top of" a church sits on its spire, not on a lower
      roof; a cup on a plate's inner floor is a fraction of its own size below the plate's rim), resting
      *steadily* (``unsteady``: 1 less the depth of the centre's projection inside its support's footprint, in
      its half-widths, at least 0: a plate lying flat rather than on its rim, a cup on its base rather than its
      side) and *near the middle* (``OFF_CENTRE`` x the horizontal distance of the figure's centre from the
      middle of the ground's footprint, in the ground's half-widths);
    - ``in``, ``under``, ``lean``: near the middle (a ball under a table's middle, not by a leg; a board leaning
      on a face's middle rather than on a corner); ``in`` also *held by its sides* (1 less ``_enclosure``: the
      share of horizontal directions from the figure's foot that meet the ground: 1 in a mug, a bun, a candle
      holder's cup; a candle within the convex hull of a candelabra's open frame, where "in" holds too, is
      half surrounded at best);
    - ``wear``: on the top (``drop``: the highest summit, a head's, not a shoulder);
    - ``hang``: hung freely from something that bears it (``_borne``): a ring on a peg, its centre straight
      below the peg, rather than flat against the wall the peg stands out from (where the contact above its
      centre is with the wall's side) or hooked over the wall's top edge with its centre out in front;
    - ``penetrate``: near the middle, *end first* (``_end_first``: a stick stuck into a block stands in its top
      rather than lying sunk along it) and *from above the floor* (the figure's depth below the floor the ground
      stands on, in figure diagonals: driven up through a block's base it would pass through the floor);
    - ``below``: on the floor (a box below a hung lamp stands under it), near the middle;
    - the others (``beside``: which side is the guide's to say; ``attach``, ``hold``, ``wrap``, the other
      directional ones): zeros (their ``Judge`` has no preference).
    Differentiable in ``poses`` but for the counts (a refinement term: ``objective.PREFER`` x ``lambda_rel``,
    and with a guide only as far as it cannot tell poses apart, ``Scorer.relation_terms``).
    """
    if reading is None or not reading.known or all(JUDGES[p].preference is None for p in reading.parts):
        return torch.zeros(len(poses), device=poses.t.device)
    c = _context(pair, poses, reading)
    return sum(_prefer(c, p) for p in reading.parts)


def _drop(c: _Ctx) -> torch.Tensor:
    """(B,) the height between the ground's highest point and the figure's bottom, either way, in figure diagonals:
    hard extremes (the smooth ones sit a few tau out, and would lift a plate)."""
    top = c.ground.side.points[..., 1].max(-1).values.expand_as(c.unit)
    return (top - c.figure.points[..., 1].min(-1).values).abs() / c.unit


def _unsteady(c: _Ctx) -> torch.Tensor:
    """(B,) 1 less the depth of the centre's projection inside its support's footprint, in its half-widths, in
    [0, 1]."""
    depth = -_support_depth(c)
    return (1.0 - depth / _half_width(c.figure).clamp_min(1e-9)).clamp(0.0, 1.0)


def _off_centre(c: _Ctx) -> torch.Tensor:
    """(B,) ``OFF_CENTRE`` x the horizontal distance of the figure's centre from the middle of the ground's
    footprint, in the ground's half-widths."""
    gp = c.ground.side.points[..., [0, 2]]
    low, high = gp.min(1).values, gp.max(1).values
    half = ((high - low).norm(dim=-1) / 2).clamp_min(1e-9)
    return OFF_CENTRE * (c.figure.centre[:, [0, 2]] - (low + high) / 2).norm(dim=-1) / half


def _prefer_resting(c: _Ctx) -> torch.Tensor:
    """Resting: on the top, steadily, near the middle."""
    return _drop(c) + _unsteady(c) + _off_centre(c)


def _prefer_in(c: _Ctx) -> torch.Tensor:
    """``in``: held by its sides, near the middle."""
    return 1.0 - _enclosure(c) + _off_centre(c)


def _prefer_below(c: _Ctx) -> torch.Tensor:
    """``below``: standing on the floor (its bottom's height from the floor, either way, past contact, in figure
    diagonals: a box below a hung lamp stands under it rather than floats or sinks), near the middle."""
    return c.h((c.bottom() - c.floor).abs() - c.tol()) + _off_centre(c)


def _prefer_penetrate(c: _Ctx) -> torch.Tensor:
    """``penetrate``: end first, from above the floor, near the middle."""
    below_floor = c.h(c.floor - c.figure.points[..., 1].min(-1).values)
    return _end_first(c) + below_floor + _off_centre(c)


def _borne(c: _Ctx) -> torch.Tensor:
    """(B,) how far the figure is from hanging freely from ground that bears it, in figure diagonals: its centre
    ``HANG_DROP`` below its highest sample touching an up-facing ground surface (a peg's or a hook's top, a
    branch: it rests there) and *plumb*: straight below that sample, as a hung thing swings to rest (a ring
    hooked over a wall's top edge with its centre out in front is not). Touching only a down-facing surface
    there (a lamp under a ceiling) it needs a fixing the geometry cannot see: ``FIXED`` more. ``FAR`` where it
    touches neither (only sides: flat against a wall)."""
    fig, reach = c.figure, c.reach()[:, None]
    out = torch.full_like(c.unit, FAR)
    for which, extra in (("down", FIXED), ("up", 0.0)):  # near the surface, not merely behind a sample's plane
        gap, along = _gap(fig.points.detach(), c.ground, which)
        bearing = (gap <= reach) & (along >= -reach)
        borne = bearing.any(-1)
        highest = fig.points[..., 1].detach().masked_fill(~bearing, -torch.inf).argmax(-1)
        support = fig.points[torch.arange(len(highest)), highest]  # (B, 3); any sample where nothing bears it
        hung = c.h(fig.centre[:, 1] - support[:, 1] + HANG_DROP * c.unit)
        plumb = (fig.centre[:, [0, 2]] - support[:, [0, 2]]).norm(dim=-1) / c.unit
        out = torch.where(borne, torch.minimum(out, hung + plumb + extra), out)
    return out


def _end_first(c: _Ctx) -> torch.Tensor:
    """(B,) 1 less how squarely the figure's long axis (its samples' principal direction) crosses the ground's
    surface where it enters (the mean |cosine| with the ground's normals at the figure's samples within contact
    of that surface, either side): 0 for a stick driven straight in, 1 for one lying sunk along the surface;
    ``FAR`` where nothing crosses it."""
    fig, reach = c.figure, c.reach()[:, None]
    centred = fig.points - fig.points.mean(1, keepdim=True)
    # (B, 3), the largest eigenvalue's; no gradient through it (eigh's is unbounded where eigenvalues meet: a ball)
    axis = torch.linalg.eigh((centred.transpose(1, 2) @ centred).detach())[1][..., -1]
    u, n, found = c.ground.nearest(fig.points.detach())
    gap, along = _gap_to(fig.points, c.ground, u, n, found)
    entry = ((gap <= reach) & (along.abs() <= reach)).detach()
    cos = (n * axis[:, None, :]).sum(-1).abs()
    share = (cos * entry).sum(-1) / entry.sum(-1).clamp_min(1)
    return torch.where(entry.any(-1), 1.0 - share, torch.full_like(share, FAR))


def _enclosure(c: _Ctx) -> torch.Tensor:
    """(B,) ``enclosure`` of the figure's foot: its centre's column, ``FOOT`` above its lowest point."""
    foot = torch.stack([c.figure.centre[:, 0], c.bottom() + FOOT * c.unit, c.figure.centre[:, 2]], -1)
    return enclosure(foot, c.ground.side.points, c.ground.side.spacing, FOOT * c.unit)


def enclosure(foot: torch.Tensor, ground: torch.Tensor, spacing: torch.Tensor | float,
              lift: torch.Tensor | float) -> torch.Tensor:
    """(B,) the share of ``ENCLOSING_RAYS`` horizontal directions from each ``foot`` (B, 3) along which a
    ``ground`` sample (B or 1, N, 3) lies within ``spacing`` of the ray (the samples as discs, as in ``_gap``):
    1 in a mug, a bun, a candle holder's cup. Samples lower than ``lift`` / 2 below the foot do not count (the
    foot stands ``lift`` above the floor it stands on, whose samples, as discs, would block every ray). A
    count: no gradient."""
    with torch.no_grad():
        angle = torch.arange(ENCLOSING_RAYS, device=foot.device) * (2 * math.pi / ENCLOSING_RAYS)
        dirs = torch.stack([angle.cos(), torch.zeros_like(angle), angle.sin()], -1)
        rel = ground - foot[:, None, :]  # (B, N, 3)
        along = rel @ dirs.T  # (B, N, D)
        perp = (rel.pow(2).sum(-1, keepdim=True) - along.pow(2)).clamp_min(0.0)
        radius = torch.as_tensor(spacing, device=foot.device).reshape(-1, 1, 1)
        around = rel[..., 1:2] > -torch.as_tensor(lift, device=foot.device).reshape(-1, 1, 1) / 2
        return ((along > 0) & (perp <= radius**2) & around).any(1).float().mean(-1)


@dataclass(frozen=True)
class Judge:
    """How the geometry judges one relation: its ``score`` (0 when it holds, ``relation_score``) and, where it holds
    in many places, its ``preference`` for the usual one (``preference``; None: it says nothing more)."""

    score: Callable[[_Ctx], torch.Tensor]
    preference: Callable[[_Ctx], torch.Tensor] | None = None


_RESTING = Judge(_score_resting, _prefer_resting)
JUDGES: dict[str, Judge] = {
    "on": _RESTING, "stand": _RESTING, "sit": _RESTING, "lie": _RESTING,
    "in": Judge(_score_in, _prefer_in), "under": Judge(_score_under, _off_centre),
    "beside": Judge(_score_beside), "lean": Judge(_score_lean, _off_centre),
    "hang": Judge(_score_hang, _borne), "wear": Judge(_score_wear, _drop),
    "penetrate": Judge(_score_penetrate, _prefer_penetrate), "attach": Judge(_score_attach),
    "hold": Judge(_score_hold), "wrap": Judge(_score_wrap),
    **{side: Judge(partial(_score_side, side=side)) for side in ("front", "behind", "left", "right")},
    "above": Judge(_score_above), "below": Judge(_score_below, _prefer_below), "near": Judge(_score_near),
    "far": Judge(_score_far), "facing": Judge(partial(_score_facing, sign=1.0)),
    "facing_away": Judge(partial(_score_facing, sign=-1.0)), "aligned": Judge(_score_aligned),
}
assert set(JUDGES) == set(RELATIONS), "every relation of the vocabulary has one judge, and only those"
assert all((JUDGES[name] is _RESTING) == r.rests for name, r in RELATIONS.items()), "the resting family, said twice"


def _score(c: _Ctx, reading: RelationReading) -> torch.Tensor:
    """The sum of the scores of the relations a reading names (each 0 when it holds)."""
    return sum(JUDGES[p].score(c) for p in reading.parts)


def _prefer(c: _Ctx, relation: str) -> torch.Tensor:
    """One relation's ``preference`` (zeros where it says nothing more)."""
    prefer = JUDGES[relation].preference
    return torch.zeros_like(c.unit) if prefer is None else prefer(c)


def verdict(pair: PreparedPair, pose: Poses | np.ndarray, reading: RelationReading | None) -> RelationVerdict | None:
    """One pose's verdict (a 1-pose ``Poses`` or a 4x4 source local -> normalised); None without a known relation."""
    if reading is None or not reading.known:
        return None
    if not isinstance(pose, Poses):
        pose = poses_of(pose, pair.source_samples.device)
    named = reading.parts
    with torch.no_grad():
        c = _context(pair, pose, reading)
        each = [float(JUDGES[p].score(c)[0]) for p in named]
        steady = bool(holds(float(_stability(c)[0]))) if reading.steady else None
        unheld = not reading.steady and not bool(_held(c)[0])
    return RelationVerdict(
        reading.name, reading.role, round(sum(each), 4), bool(holds(sum(each))),
        steady, reading.side, frame(pair) if reading.directional else None,
        [{"name": p, "score": round(e, 4), "holds": bool(holds(e))} for p, e in zip(named, each, strict=True)]
        if len(named) > 1 else None, UNHELD if unheld else None)


def _held(c: _Ctx) -> torch.Tensor:
    """(B,) whether anything in the pair can hold the figure up: it touches its ground (any surface: it rests on
    it, hangs from it or is fixed to it) or stands on the floor."""
    gap, _ = _gap(c.figure.points, c.ground)
    on_floor = c.figure.points[..., 1] - c.floor[:, None] <= c.tol()[:, None]
    return ((gap <= c.reach()[:, None]) | on_floor).any(-1)


def poses_of(matrix: np.ndarray, device: str | torch.device = "cpu") -> Poses:
    """A 1-pose ``Poses`` from a (4, 4) similarity, source local -> normalised."""
    from ctp_core.geometry.pose import matrix_to_quaternion

    m = np.asarray(matrix, dtype=np.float64)
    scale = float(np.cbrt(abs(np.linalg.det(m[:3, :3]))))
    q = matrix_to_quaternion(m[:3, :3] / scale)
    as_t = lambda a: torch.as_tensor(np.array(a), dtype=torch.float32, device=device)  # noqa: E731
    return Poses(as_t(m[None, :3, 3]), as_t(q[None]), as_t([math.log(scale)]))
