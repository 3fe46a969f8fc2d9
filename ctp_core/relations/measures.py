"""What every relation's judge measures: a posed figure and its ground as samples (``Samples``, ``Ground``,
``Context``), gaps to the ground's surface, hinges and smooth extremes, the support footprint and stability,
the ground's axes and summits.

Roles: with the source as the figure ("a cup on a table") the figure is the posed source and the ground is the
target (the related object of a scene, ``PreparedPair.anchor``); with the source as the ground the same
measures are read the other way round. Everything is in the normalised frame (+Y up), lengths in figure
diagonals unless said otherwise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch
from scipy.spatial import ConvexHull, QhullError

from ctp_core import losses
from ctp_core.geometry import sampling
from ctp_core.geometry.pose import Poses, apply_pose, quaternion_to_matrix
from ctp_core.pairs import UP_FACING, PreparedPair, per_pair
from ctp_core.reading.places import Place
from ctp_core.reading.relation import RelationReading
from ctp_core.render.cameras import FIRST_AZIMUTH

FIGURE_POINTS = 192  # figure samples a score looks at: enough to find a contact patch, cheap for hundreds of poses
GROUND_POINTS = 256  # samples of a *posed* ground (the source in the ground role), compared by brute force
CONTACT = 0.03  # touching: within this of the ground surface (``surface_gap``: along the nearest normal): a cup's base
# on a table is within a few hundredths of its diagonal of the sampled top once settled by the search
SMOOTH = 0.02  # width of the quadratic start of every hinge: gradients stay continuous at the threshold
SOFT = 0.01  # temperature of the smooth minima/maxima over samples: a hundredth of a diagonal
# an up-facing one (a peg's top), in figure diagonals
FAR = 1.0  # a condition that has nothing to measure against (no overhead surface at all): a whole diagonal
# ``preference``: among poses where the relation holds, which is the usual arrangement (see its docstring)
OFF_CENTRE = 0.5  # weight of the figure's distance from the ground's middle (in the ground's half-widths)


def axes(front: torch.Tensor, trusted: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """(front, left) horizontal unit vectors (B, 3), normalised frame, of a ground whose front is ``front`` (B, 3):
    its own where ``trusted`` (left = up x front: glTF's front +Z with +Y up has its own left at +X), else the
    viewer's (the preview's first camera, ``cameras.FIRST_AZIMUTH``): front toward the viewer, left the viewer's
    left (an object facing the viewer has its own left on the viewer's right)."""
    if trusted:
        f = horizontal_unit(front)
        return f, torch.stack([f[..., 2], torch.zeros_like(f[..., 0]), -f[..., 0]], -1)
    a = math.radians(FIRST_AZIMUTH)
    as_t = lambda v: torch.tensor(v, dtype=front.dtype, device=front.device).expand_as(front)  # noqa: E731
    return as_t([math.sin(a), 0.0, math.cos(a)]), as_t([-math.cos(a), 0.0, math.sin(a)])


def toward(side: str, front: torch.Tensor, left: torch.Tensor) -> torch.Tensor:
    """The horizontal direction (B, 3) of a ground's ``side`` (``front``, ``behind``, ``left``, ``right``), from its
    ``axes``."""
    return {"front": front, "behind": -front, "left": left, "right": -left}[side]


def horizontal_unit(v: torch.Tensor) -> torch.Tensor:
    """``v`` (..., 3) with no vertical part, unit length (0 where it is vertical)."""
    flat = v * torch.tensor([1.0, 0.0, 1.0], dtype=v.dtype, device=v.device)
    return flat / flat.norm(dim=-1, keepdim=True).clamp_min(1e-9)


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


@dataclass
class Samples:
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


class Ground:
    """Nearest ground samples to figure points, optionally restricted to a subset (e.g. up-facing)."""

    def __init__(self, samples: Samples, trees: dict[str, losses.SurfaceIndex | None]):
        self.samples, self.trees = samples, trees

    def mask(self, which: str) -> torch.Tensor:
        ny = self.samples.normals[..., 1]
        return {"all": torch.ones_like(ny, dtype=torch.bool), "up": ny > UP_FACING, "down": ny < -UP_FACING,
                "wall": ny.abs() <= UP_FACING, "not_down": ny >= -UP_FACING}[which]

    def nearest(self, points: torch.Tensor, which: str = "all") -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(u, n, found) for (B, N, 3) points: nearest ground sample of the subset, its normal, whether the subset
        has any sample (B, N) (points of a pose whose subset is empty get a far sample)."""
        side = self.samples
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


def surface_gap(points: torch.Tensor, ground: Ground, which: str = "all") -> tuple[torch.Tensor, torch.Tensor]:
    """(B, N) distance from each point to the ground surface (the sampled surface as discs of the samples'
    spacing; 0 behind it), and the signed height along the normal (positive outside)."""
    return gap_to(points, ground, *ground.nearest(points, which))


def bearing_gap(points: torch.Tensor, ground: Ground, which: str, reach: torch.Tensor) -> torch.Tensor:
    """(B, N) ``surface_gap`` from the side the ground surface faces: a point further behind it than ``reach``
    (B,) is as far as it is deep. ``surface_gap`` is 0 anywhere behind, which makes a thin ground (a plate, a board)
    bear a figure from either side: a ball hanging under a board is not resting on it."""
    gap, along = surface_gap(points, ground, which)
    return torch.maximum(gap, -along - reach[:, None])


def gap_to(points: torch.Tensor, ground: Ground, u: torch.Tensor, n: torch.Tensor, found: torch.Tensor
            ) -> tuple[torch.Tensor, torch.Tensor]:
    """``surface_gap`` to given nearest ground samples ``u`` with normals ``n`` (``Ground.nearest``)."""
    diff = points - u
    along = (diff * n).sum(-1)
    tangent = (diff - along[..., None] * n).norm(dim=-1)
    spacing = ground.samples.spacing.reshape(-1, 1)
    gap = torch.sqrt(along.clamp_min(0.0) ** 2 + (tangent - spacing).clamp_min(0.0) ** 2 + 1e-12)
    far = torch.full_like(gap, 1e6)
    return torch.where(found, gap, far), torch.where(found, along, far)


def hull_distance_2d(query: torch.Tensor, points: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """(B,) signed distance of query (B, 2) to the convex hull of points (B or 1, N, 2) (positive outside; the
    maximum over the hull's edge lines, exact inside and a lower bound outside), of each pose's points where
    ``mask`` (B or 1, N) keeps them. Fewer than three usable points: the distance to the nearest of them (a line's or
    a point's footprint). Each hull's edges come from Qhull one pose at a time; the distances are one batch."""
    batch = query.shape[0]
    keep = (torch.ones((1, points.shape[1]), dtype=torch.bool, device=points.device) if mask is None
            else mask.detach())
    rows, mask_rows = (torch.arange(batch) if n > 1 else torch.zeros(batch, dtype=torch.long)  # a row per pose
                       for n in (points.shape[0], keep.shape[0]))
    flat, kept = points.detach().cpu().double().numpy(), keep.cpu().numpy()
    found: dict[tuple[int, int], np.ndarray | None] = {}  # a hull's edges per (points row, mask row)
    edges = []
    for i in range(batch):
        key = (int(rows[i]), int(mask_rows[i]))
        if key not in found:
            found[key] = _edges_2d(flat[key[0]], kept[key[1]])
        edges.append(found[key])
    out = torch.zeros(batch, dtype=query.dtype, device=query.device)
    hull = {i: e for i, e in enumerate(edges) if e is not None}
    if hull:
        at = torch.as_tensor(list(hull))
        out = out.index_put((at,), _hull_distances(query[at], points[rows[at]], keep[mask_rows[at]],
                                                   list(hull.values())))
    for i in (i for i in range(batch) if edges[i] is None):
        pts = points[rows[i]][keep[mask_rows[i]]]
        one = (pts - query[i]).norm(dim=-1).min() if len(pts) else torch.tensor(FAR * 1e3, dtype=out.dtype)
        out = out.index_put((torch.tensor([i]),), one[None])  # collinear or too few: the nearest point's distance
    return out


def _edges_2d(points: np.ndarray, keep: np.ndarray) -> np.ndarray | None:
    """(E, 2) indices into ``points`` (N, 2) of the convex hull's edges of those ``keep`` holds; None when they
    make no 2-D hull (fewer than 3 points, a line)."""
    chosen = np.flatnonzero(keep)
    if len(chosen) < 3:
        return None
    try:
        return chosen[ConvexHull(points[chosen]).simplices]
    except (QhullError, ValueError):
        return None


def _hull_distances(query: torch.Tensor, points: torch.Tensor, keep: torch.Tensor, edges: list[np.ndarray]
                    ) -> torch.Tensor:
    """(H,) ``hull_distance_2d`` of H queries (H, 2) against their own points (H, N, 2), those ``keep`` (H, N)
    holds, whose hulls have ``edges`` (per query, (E, 2) indices into its points): the largest distance past an
    edge line, each edge's normal turned away from the mean of the kept points."""
    index = np.zeros((len(edges), max(len(e) for e in edges), 2), dtype=np.int64)
    valid = np.zeros(index.shape[:2], dtype=bool)
    for k, e in enumerate(edges):
        index[k, : len(e)], valid[k, : len(e)] = e, True
    ends = torch.as_tensor(index, device=points.device)
    a, c = (torch.gather(points, 1, ends[..., j, None].expand(-1, -1, 2)) for j in (0, 1))
    edge = c - a
    normal = torch.stack([edge[..., 1], -edge[..., 0]], -1)
    normal = normal / normal.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    weights = keep.to(points.dtype)
    inner = (points.detach() * weights[..., None]).sum(1) / weights.sum(1, keepdim=True)
    sign = torch.sign(((a.detach() - inner[:, None]) * normal.detach()).sum(-1))  # every edge's normal outward
    normal = normal * torch.where(sign == 0, torch.ones_like(sign), sign)[..., None]
    reach = ((query[:, None] - a) * normal).sum(-1)
    return reach.masked_fill(~torch.as_tensor(valid, device=points.device), -torch.inf).max(-1).values


def hull_distance_3d(query: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
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


@dataclass
class Features:
    """Per-pair samples the scores reuse (built once by ``features``; the target never moves)."""

    source_points: torch.Tensor  # (FIGURE_POINTS, 3) source local frame
    source_normals: torch.Tensor  # (FIGURE_POINTS, 3) source local frame, unit
    source_centre: torch.Tensor  # (3,) source local frame: mean of area-weighted samples
    source_spacing: float  # source local units: sqrt(area / count)
    target: Samples  # the related object (``PreparedPair.anchor``), static
    target_trees: dict[str, losses.SurfaceIndex | None]  # per normal subset ("up", "down", "wall", ...)
    target_figure: Samples  # a subset of the target as a figure (the ground role), static
    grounds: list[torch.Tensor]  # (M, 3) samples of each named ground where there are several ("between")
    source_up: torch.Tensor  # (3,) source local frame, unit: its own up (``source_upright``: the file's for glTF)


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
    target = Samples(t_points[None], t_normals[None], t_points.mean(0)[None], diag[None],
                  torch.tensor([t_spacing], device=device), anchor)
    ny = t_normals[:, 1]
    subsets = {"all": torch.ones_like(ny, dtype=torch.bool), "up": ny > UP_FACING, "down": ny < -UP_FACING,
               "wall": ny.abs() <= UP_FACING, "not_down": ny >= -UP_FACING}
    trees = {k: (anchor if k == "all" else losses.SurfaceIndex(t_points[m], t_normals[m]) if m.any() else None)
             for k, m in subsets.items()}
    pick = torch.linspace(0, len(t_points) - 1, min(GROUND_POINTS, len(t_points))).long()
    figure = Samples(t_points[pick][None], t_normals[pick][None], t_points.mean(0)[None], diag[None],
                  torch.tensor([t_spacing], device=device), anchor)
    centre = as_t(local.apply(pts.mean(0)[None])[0])
    grounds = [g.points for g in pair.grounds]
    up = local.apply_directions(pair.source_upright.up[None])[0]
    return Features(s_points, s_normals, centre, math.sqrt(s_area / FIGURE_POINTS), target, trees, figure, grounds,
                    as_t(up / np.linalg.norm(up)))


def posed_source(feat: Features, poses: Poses) -> Samples:
    """The source's samples at each pose, (B, N, 3), with its centre, diagonal and sample spacing."""
    pts = apply_pose(feat.source_points, poses.t, poses.q, poses.log_s)
    rot = quaternion_to_matrix(poses.q)
    nrm = torch.einsum("bij,nj->bni", rot, feat.source_normals)
    centre = apply_pose(feat.source_centre[None], poses.t, poses.q, poses.log_s)[:, 0]
    scale = poses.log_s.exp()
    local = feat.source_points
    diag = (local.max(0).values - local.min(0).values).norm() * scale
    return Samples(pts, nrm, centre, diag, feat.source_spacing * scale)


def roles(pair: PreparedPair, poses: Poses, placed: bool) -> tuple[Samples, Ground, torch.Tensor]:
    """(figure, ground, floor height (B,)) for either role: ``placed``, the source is the figure."""
    feat = features(pair)
    source = posed_source(feat, poses)
    b = len(poses)
    if placed:
        floor = torch.full((b,), pair.floor, device=source.points.device)
        return source, Ground(feat.target, feat.target_trees), floor
    fig = feat.target_figure
    figure = Samples(fig.points.expand(b, -1, -1), fig.normals.expand(b, -1, -1), fig.centre.expand(b, -1),
                  fig.diagonal.expand(b), fig.spacing.expand(b))
    floor = soft_min(source.points[..., 1], SOFT * source.diagonal[:, None])  # the ground's lowest level
    return figure, Ground(source, {}), floor


def context(pair: PreparedPair, poses: Poses, reading: RelationReading | None) -> Context:
    """The figure, the ground, the floor and the fronts for either role: the target's front
    (``PreparedPair.target_front``, normalised frame) and the posed source's (``source_front``, turned by the pose);
    the ground's axes in its own frame or the viewer's (``axes``)."""
    placed = reading is None or reading.source_is_figure  # no relation: the source is what is placed
    figure, ground, floor = roles(pair, poses, placed)
    as_t = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32, device=poses.t.device)  # noqa: E731
    own = torch.einsum("bij,j->bi", quaternion_to_matrix(poses.q), as_t(pair.source_front))
    target = as_t(pair.target_front).expand(len(poses), 3)
    ground_front, figure_front = (target, own) if placed else (own, target)
    front, left = axes(ground_front, pair.front_trusted)
    flat = figure_front * torch.tensor([1.0, 0.0, 1.0], device=figure_front.device)
    grounds = features(pair).grounds if placed else []
    upright = _uprightness(pair, poses) if placed else None
    return Context(figure, ground, floor, front=front, left=left, heading=flat, grounds=grounds,
                   pair=pair if placed else None, reading=reading, upright=upright)


def _uprightness(pair: PreparedPair, poses: Poses) -> torch.Tensor:
    """(B,) how far each pose turns the source from standing as it is set down (its own up, ``Features.source_up``),
    0 upright to 2 upside down: 1 less the cosine between its posed up and +Y."""
    up = features(pair).source_up.to(poses.t.device)
    return 1.0 - torch.einsum("bij,j->bi", quaternion_to_matrix(poses.q), up)[:, 1]


@dataclass
class Context:
    figure: Samples
    ground: Ground
    floor: torch.Tensor  # (B,)
    depth: torch.Tensor | None = None  # ``support_depth``, once computed (a convex hull per pose)
    front: torch.Tensor | None = None  # (B, 3) the ground's front, horizontal (``axes``): sides are named from it
    left: torch.Tensor | None = None  # (B, 3) the ground's left, horizontal
    heading: torch.Tensor | None = None  # (B, 3) the figure's own front (unit), its vertical part dropped: as long
    # as the cosine of its elevation, so a front pointing up faces nothing (a chair lying on its back)
    grounds: list[torch.Tensor] = field(default_factory=list)  # (M, 3) each named ground's samples ("between"),
    # the source the figure; empty with one ground
    pair: PreparedPair | None = None  # the pair, where the source is the figure: its ground's parts (``parts``)
    reading: RelationReading | None = None  # the reading judged: the place its prompt names
    upright: torch.Tensor | None = None  # (B,) ``_uprightness``, where the source is the figure

    @property
    def place(self) -> Place | None:
        """The place on or beside the ground the prompt names (``RelationReading.place``), or None."""
        return None if self.reading is None else self.reading.place

    @property
    def unit(self) -> torch.Tensor:  # (B,) figure diagonal
        return self.figure.diagonal

    def tol(self) -> torch.Tensor:
        """(B,) height tolerance, normalised units: ``CONTACT`` figure diagonals (a bottom band, the floor)."""
        return CONTACT * self.unit

    def reach(self) -> torch.Tensor:
        """(B,) contact tolerance of a gap to the ground's surface: ``tol``, and at least a third of the ground's
        sample spacing, the sampled surface's resolution as ``contact.settle`` allows it (a sample counts inside
        only past a third of the spacing); the spacing is in ``surface_gap`` tangentially, but along the normal a
        coarsely sampled tip rises between its samples: a small cross settled on a church's spire stood 1.15 x
        ``tol`` above its nearest up-facing sample."""
        return torch.maximum(self.tol(), self.ground.samples.spacing.reshape(-1).expand_as(self.unit) / 3)

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
        gap, _ = surface_gap(self.figure.points, self.ground, which)
        return self.h(self.finite(soft_min(gap, self.tau())) - self.reach())


def half_width(fig: Samples) -> torch.Tensor:
    """(B,) the figure's horizontal half-extent about its centre (the largest horizontal sample distance)."""
    return (fig.points[..., [0, 2]] - fig.centre[:, None, [0, 2]]).norm(dim=-1).max(-1).values.detach()


def support_mask(c: Context) -> torch.Tensor:
    """(B, N) the figure samples that bear weight: touching ground surface that does not face down, or the floor."""
    gap, _ = surface_gap(c.figure.points, c.ground, "not_down")
    return (gap <= c.reach()[:, None]) | (c.figure.points[..., 1] - c.floor[:, None] <= c.tol()[:, None])


def support_depth(c: Context) -> torch.Tensor:
    """(B,) signed horizontal distance of the centre's projection to the convex footprint of the support patch
    (positive outside, normalised units); a whole ``FAR`` figure diagonal with no support at all."""
    if c.depth is None:
        mask = support_mask(c).detach()
        dist = hull_distance_2d(c.figure.centre[:, [0, 2]], c.figure.points[..., [0, 2]], mask)
        c.depth = torch.where(mask.any(-1), dist, torch.full_like(dist, FAR) * c.unit)
    return c.depth


def stability(c: Context) -> torch.Tensor:
    """Horizontal distance (figure diagonals, hinged) of the centre's projection outside the convex footprint
    of the support patch (``support_depth``)."""
    return c.h(support_depth(c))


def ground_summits(ground: Samples, radius: float) -> torch.Tensor:
    """(B or 1, P, 3) the ground's summit samples (``sampling.summits``: highest in their column and its
    neighbours, ``radius`` cells); a posed ground (one per pose) keeps its highest sample only."""
    if not ground.static:
        idx = ground.points[..., 1].argmax(-1)
        return torch.gather(ground.points, 1, idx[:, None, None].expand(-1, 1, 3))
    pts = ground.points[0]
    peaks = sampling.summits(pts.detach().cpu().double().numpy(), radius)
    return pts[torch.as_tensor(peaks, dtype=torch.long, device=pts.device)][None]


def summit_drop(c: Context) -> torch.Tensor:
    """(B,) the height between the ground's highest point and the figure's bottom, either way, in figure diagonals:
    hard extremes (the smooth ones sit a few tau out, and would lift a plate)."""
    top = c.ground.samples.points[..., 1].max(-1).values.expand_as(c.unit)
    return (top - c.figure.points[..., 1].min(-1).values).abs() / c.unit


def off_centre(c: Context) -> torch.Tensor:
    """(B,) ``OFF_CENTRE`` x the horizontal distance of the figure's centre from the middle of the ground's
    footprint, in the ground's half-widths."""
    gp = c.ground.samples.points[..., [0, 2]]
    low, high = gp.min(1).values, gp.max(1).values
    half = ((high - low).norm(dim=-1) / 2).clamp_min(1e-9)
    return OFF_CENTRE * (c.figure.centre[:, [0, 2]] - (low + high) / 2).norm(dim=-1) / half


def turned(c: Context) -> torch.Tensor:
    """(B,) ``Context.upright``: how far the figure is turned from standing as it is set down (0 where the source
    is the ground)."""
    return c.upright if c.upright is not None else torch.zeros_like(c.unit)


ON_FLOOR = 0.25  # ``off_floor``: what standing off the floor by the whole contact tolerance costs


def off_floor(c: Context) -> torch.Tensor:
    """(B,) the figure's bottom's height from the floor, either way, ``ON_FLOOR`` per contact tolerance
    (``Context.tol``: within it the judge says it stands there, but a box sunk by all of it shows)."""
    return ON_FLOOR * (c.bottom() - c.floor).abs() / c.tol()
