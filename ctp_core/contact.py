"""Poses in contact with the target: where a source touches (``Site``), how it gets there (``settle``,
``place``) and how far a posed source is from the target (``clearance``, ``contact_gap``, ``touch_limit``).

The search's proposals (``search.proposals``), the relations' own builders (``relations.builders``), the
objective and the optimiser all put sources against the target the same way and measure their gap in the same
unit, the posed source's diagonal. Frames: every pose maps the source local frame to the normalised frame;
points and directions here are in the normalised frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import trimesh
from scipy.spatial import Delaunay, QhullError

from ctp_core import losses
from ctp_core.geometry import sampling
from ctp_core.geometry.pose import Poses, apply_pose, quaternion_to_matrix
from ctp_core.pairs import UP_FACING, PreparedPair, triangles

REACH = 2.0  # source diagonals: a pose whose source is farther than this from the target places it nowhere
TOUCH = 0.1  # source diagonals: a refined pose this close to the target touches it (plus the samples' spacing)
# How a proposal comes into contact (``settle``): toward the closest target sample (a surface's outward normal
# is where it starts from), straight down its site's -normal (lowered from above), or not at all (it rests on
# the floor where it was put and only leaves the target if it starts inside it).
APPROACHES: tuple[str, ...] = ("closest", "straight", "none")
CONTACT_SAMPLES = 6000  # target samples for settling proposals (the losses use ``loss.samples``)
SETTLE_POINTS = 256  # source samples checked for penetration when settling proposals
APPROACH_POINTS = 64  # source samples used while sliding proposals into contact
SETTLE_ITERATIONS = 12
NEAR = 0.25  # target radii: settling's nearest-sample search is bounded to this (``nearest_two``)
PUSH_ITERATIONS = 3


def clearance(pair: PreparedPair, index: losses.SurfaceIndex, poses: Poses, points: int = 64) -> torch.Tensor:
    """(B,) the smallest distance between each posed source (``points`` of its samples) and the target samples,
    in source diagonals (normalised frame)."""
    posed = apply_pose(pair.source_subset(points), poses.t, poses.q, poses.log_s).detach().cpu()
    flat = posed.reshape(-1, 3).numpy().astype(np.float64)
    dist, _ = index.tree.query(flat)
    return torch.as_tensor(dist.reshape(len(poses), -1).min(axis=1), dtype=torch.float32) / source_diagonal(pair, poses)


def source_diagonal(pair: PreparedPair, poses: Poses) -> torch.Tensor:
    """(B,) each posed source's diagonal (``PreparedPair.source_diagonal`` x its scale), normalised units (CPU):
    the unit of ``clearance`` and ``touch_limit``."""
    return pair.source_diagonal * poses.log_s.detach().cpu().exp()


def contact_gap(pair: PreparedPair, poses: Poses) -> torch.Tensor:
    """(B,) each pose's gap to the target in source diagonals: its ``clearance`` less the target samples' spacing
    (a small source on a big target is farther from the nearest sample than from the surface), at least 0."""
    return (clearance(pair, pair.index, poses) - (touch_limit(pair, poses) - TOUCH)).clamp(min=0)


def touching(gap: float) -> bool:
    """Whether a ``contact_gap`` counts as touching: at most ``TOUCH``, as the answer's selection counts it."""
    return gap <= TOUCH


def touch_limit(pair: PreparedPair, poses: Poses) -> torch.Tensor:
    """(B,) the ``clearance`` (source diagonals) under which a pose touches: ``TOUCH`` plus the spacing of the
    target samples (a small source on a big target is farther from the nearest sample than from the surface)."""
    return TOUCH + pair.sample_spacing(len(pair.index.points)) / source_diagonal(pair, poses)


@dataclass
class Site:
    """Where proposals touch the target: an anchor and approach direction per proposal (normalised frame)."""

    anchor: torch.Tensor  # (N, 3) a target surface point, a cavity point or a floor point
    normal: torch.Tensor  # (N, 3) approach along -normal (outward normal; +Y for cavity, drop and floor points)
    gap: torch.Tensor  # (N,) distance kept from the target after contact (lateral proposals)
    on_surface: torch.Tensor  # (N,) bool: the source starts with its extreme point along -normal at the anchor
    # (a surface, drop or floor point; else it starts centred there: a cavity point)
    approach: torch.Tensor  # (N,) index into APPROACHES

    def select(self, index) -> Site:
        return Site(*(value[index] for value in vars(self).values()))


@dataclass
class Proposals:
    poses: Poses  # (N,) source local -> normalised
    region: list[str]  # (N,) which region each was drawn from ("init" for the caller's start)
    sites: Site | None = None  # (N,) where each touches (None: not placed by the search, e.g. random starts)
    rotations: torch.Tensor | None = None  # (R, 4) the source orientations the proposals were drawn from
    index: losses.SurfaceIndex | None = None  # the contact samples they were placed with

    def select(self, index: list[int]) -> Proposals:
        """These proposals at ``index`` (the orientations and contact samples are shared)."""
        sites = None if self.sites is None else self.sites.select(torch.as_tensor(index, dtype=torch.long))
        return Proposals(self.poses.select(index), [self.region[i] for i in index], sites, self.rotations, self.index)


def surface_regions(pair: PreparedPair) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray], np.ndarray]:
    """Target samples, normals, indices per surface region and a density weight per sample (of the object the
    source relates to, ``PreparedPair.anchor``, when the target is a scene of placed objects).

    Samples are area-weighted already; the density adds weight where the surface faces up, on rims (where
    the normals of neighbouring samples disagree) and toward the top of the target (small tops, a spire's or a
    head's, have little area but are where things are put).
    """
    anchor = pair.anchor  # in a scene of placed objects, the one the source relates to
    points = anchor.points.cpu().numpy().astype(np.float64)
    normals = anchor.normals.cpu().numpy().astype(np.float64)
    ny = normals[:, 1]
    _, near = anchor.tree.query(points, k=min(8, len(points)))
    spread = 1.0 - np.linalg.norm(normals[near].mean(axis=1), axis=1)
    height = (points[:, 1] - points[:, 1].min()) / max(float(np.ptp(points[:, 1])), 1e-9)
    density = 1.0 + np.clip(ny, 0.0, None) + (spread > 0.3) + 2.0 * height**4
    regions = {"top": np.flatnonzero(ny > UP_FACING), "bottom": np.flatnonzero(ny < -UP_FACING),
               "side": np.flatnonzero(np.abs(ny) <= UP_FACING)}
    return points, normals, regions, density


def contact_index(pair: PreparedPair, count: int = CONTACT_SAMPLES, seed: int = 0) -> losses.SurfaceIndex:
    """Denser target samples than the losses' (normalised frame, outward normals) for placing proposals: the
    sampled depth and distance are only as good as the spacing."""
    # a scene of placed objects: all of them, oriented once by prepare_pair
    points, normals = sampling.surface_samples(triangles(pair.target_outward), count, seed)
    frame = pair.target_to_normalised
    as_t = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32)  # noqa: E731
    return losses.SurfaceIndex(as_t(frame.apply(points)), as_t(frame.apply_directions(normals)))


def settle(pair: PreparedPair, index: losses.SurfaceIndex, q: torch.Tensor, anchor: torch.Tensor,
           normal: torch.Tensor, log_s: torch.Tensor, on_surface: bool,
           approach: str = "closest") -> tuple[torch.Tensor, torch.Tensor]:
    """Source centres (B, 3) that bring each rotated source into contact from outside, approaching along -normal,
    and whether each ended outside (a source wedged where pushing along the normal cannot free it did not).

    ``index``: target samples (``contact_index``). ``on_surface``: ``anchor`` is a target surface point with
    outward ``normal``; the source starts with its extreme point along -normal in the tangent plane there.
    Otherwise it starts centred at ``anchor``. Then, a few times (a sparse subset of the source samples): if a
    sample is inside the target (``losses.signed_depth``), push out along the normal by the deepest; else move
    toward the target by the smallest distance between source and target samples (sphere tracing: a step that
    short cannot pass through a sample), so it ends touching: along that closest pair (``approach`` "closest"),
    along -normal ("straight": lowered from above). Last, a denser subset is checked and only pushed out.
    ``approach`` "none": neither moved nor pushed, only checked (free where it was put, or dropped).
    """
    def subset(count: int) -> torch.Tensor:
        rot = quaternion_to_matrix(q) * log_s.exp()[:, None, None]
        return torch.einsum("bij,nj->bni", rot, pair.source_subset(count))

    tol = 2e-3 * pair.target_radius
    # the sampled depth is only as good as the sample spacing (an edge's neighbour plane votes near corners):
    # count a sample inside only past a third of that spacing
    spacing = pair.sample_spacing(len(index.points))
    inside_tol = max(tol, spacing / 3)
    low, high = index.points.min(0).values - spacing - tol, index.points.max(0).values + spacing + tol
    centre = anchor.clone()
    if on_surface:
        rotated = subset(SETTLE_POINTS)
        support = (-(rotated * normal[:, None, :]).sum(-1)).max(dim=1).values  # extent along -normal
        centre = anchor + normal * (support + tol)[:, None]

    def step(rotated: torch.Tensor, active: torch.Tensor, closing: bool) -> tuple[torch.Tensor, torch.Tensor]:
        """Move the active candidates once; returns the ones that still move and every active one's depth."""
        posed = rotated[active] + centre[active, None, :]
        # a sample outside the target's box (by more than a sample spacing) is outside the target: far from a
        # surface thinner than the spacing (a plate under a source 100 times its size) the nearest sample's side
        # is a coin toss, and a wrong "inside" pushed such a source hundreds of radii away
        within = ((posed >= low) & (posed <= high)).all(dim=-1)
        dist, idx = nearest_two(index, posed, within, NEAR * pair.target_radius)
        # behind the sampled surface and mostly along its normal: above a feature thinner than the sample
        # spacing (a spire's tip) a point is behind the planes of the samples on either side, though outside
        depth = losses.signed_depth(posed, index, 0.01, 2, idx=idx)
        depth = torch.where(within, depth, torch.zeros_like(depth))
        deepest = torch.where(depth >= 0.5 * dist, depth, torch.zeros_like(depth)).max(dim=1).values
        gap, nearest = dist.min(dim=1)
        rows = torch.arange(len(active))
        toward = index.points[idx[rows, nearest, 0]] - posed[rows, nearest]  # closest source sample -> its target's
        toward = toward / toward.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        inside = deepest > inside_tol
        if approach == "straight":
            toward = -normal[active]
        reach = (gap - tol).clamp_min(0.0) if closing else torch.zeros_like(gap)
        push = normal[active] * (deepest + tol)[:, None] if approach != "none" else torch.zeros_like(toward)
        move = torch.where(inside[:, None], push, toward * reach[:, None])
        centre[active] = centre[active] + move
        return active[move.norm(dim=-1) >= tol], deepest

    # approach with a sparse subset of the source (cheap), then check with a denser one and only push out
    sparse, dense = subset(APPROACH_POINTS), subset(SETTLE_POINTS)
    active = torch.arange(len(centre))
    for _ in range(SETTLE_ITERATIONS if approach != "none" else 0):
        active, _ = step(sparse, active, closing=True)
        if not len(active):
            break
    active = torch.arange(len(centre))
    depth = torch.zeros(len(centre))
    for _ in range(PUSH_ITERATIONS if approach != "none" else 1):  # "none": kept only if free where put
        moving, depth[active] = step(dense, active, closing=False)
        active = moving
        if not len(active):
            break
    return centre, depth <= inside_tol


def nearest_two(index: losses.SurfaceIndex, posed: torch.Tensor, within: torch.Tensor, near: float
                ) -> tuple[torch.Tensor, torch.Tensor]:
    """(B, N) each posed point's distance to its nearest sample of ``index`` and (B, N, 2) its two nearest samples,
    as one unbounded search for both finds them wherever they are read, for less: a far point's search visits much
    of the tree, and settling asks of many far points (the far side of a large source, a pose far from the target).
    First a search bounded to ``near``; points inside the target's box (``within``) beyond it are searched again
    without it. A pose none of whose points is that near needs its nearest point and that point's nearest sample
    still (its nearest may be outside the box): the index's few covering samples (``SurfaceIndex.cover``) bound
    each point's distance from above and below, and only the points whose distance can be the pose's least are
    searched, bounded by the least upper bound. Every other point outside the box keeps an infinite distance
    (never its pose's nearest, nor counted inside: its depth is not read)."""
    flat = posed.reshape(-1, 3).numpy().astype(np.float64)
    dist, idx = index.tree.query(flat, k=2, upper=near)
    close = np.isfinite(dist[:, 0]).reshape(posed.shape[:2]).any(1)  # a point within the bound: the pose's nearest
    inside = within.reshape(-1).numpy() & ~np.isfinite(dist[:, 1])
    if inside.any():
        dist[inside], idx[inside] = index.tree.query(flat[inside], k=2)
    lone = np.flatnonzero(~close)
    if len(lone):
        points = flat.reshape(*posed.shape[:2], 3)[lone]  # (L, N, 3)
        few, radius = index.cover
        square = (points**2).sum(-1)[..., None] + (few**2).sum(-1) - 2 * points @ few.T  # (L, N, C)
        upper = np.sqrt(np.clip(square, 0.0, None).min(-1))  # (L, N): each point at least this near
        known = dist[:, 0].reshape(posed.shape[:2])[lone]  # points inside the box, searched already
        least = np.minimum(upper.min(1), known.min(1))  # each pose's nearest point is at least this near
        can = (upper - radius <= least[:, None]) & ~np.isfinite(known)  # those that can be it, not yet searched
        for i, pose in enumerate(lone):
            rows = pose * posed.shape[1] + np.flatnonzero(can[i])
            dist[rows, 0], idx[rows, 0] = index.tree.query(flat[rows], upper=least[i] * (1 + 1e-9))
    idx = np.where(np.isfinite(dist), idx, 0)  # a point left far is outside the box: its neighbours are not read
    return (torch.as_tensor(dist[:, 0].reshape(posed.shape[:2]), dtype=posed.dtype),
            torch.as_tensor(idx.reshape(*posed.shape[:2], 2), dtype=torch.long))


def place(pair: PreparedPair, index: losses.SurfaceIndex, q: torch.Tensor, sites: Site,
          log_s: float | torch.Tensor) -> tuple[Poses, torch.Tensor]:
    """Poses with orientations ``q`` and scales ``log_s`` (one, or one each) settled into contact at ``sites``
    (``settle``), then moved out by each site's gap; returns the poses that ended free of the target and the mask
    of which did."""
    scale = torch.as_tensor(log_s, dtype=torch.float32).cpu().expand(len(q)).clone()
    t = torch.empty(len(q), 3)
    free = torch.ones(len(q), dtype=torch.bool)
    for surface in (True, False):
        for mode, approach in enumerate(APPROACHES):
            sel = (sites.on_surface == surface) & (sites.approach == mode)
            if sel.any():
                t[sel], free[sel] = settle(pair, index, q[sel], sites.anchor[sel], sites.normal[sel], scale[sel],
                                           on_surface=surface, approach=approach)
    t = t + sites.normal * sites.gap[:, None]
    return Poses(t, q, scale).select(free), free


CAVITY_PROBES = 4096  # quasi-random points in the target AABB tried as cavity proposals
CAVITY_MARGIN = 0.02  # of the hull's box diagonal: how far a cavity point stays from the walls
CAVITY_SIGMA = 0.01  # the depth's nearest-sample width in the normalised frame (a target's diagonal is about 3)


def cavity_points(pair: PreparedPair, seed: int) -> np.ndarray:
    """Points inside the target's convex hull but outside the target (its cavity, as the penetration term sees
    it: behind no oriented surface), away from the walls; (P, 3), possibly empty."""
    return hollow(pair.target_vertices.cpu().numpy().astype(np.float64), pair.index, seed, CAVITY_SIGMA)


def hollow(verts: np.ndarray, index: losses.SurfaceIndex, seed: int, sigma: float) -> np.ndarray:
    """Points inside the convex hull of ``verts`` but outside the surface ``index`` samples (outward normals, the
    same frame), at least ``CAVITY_MARGIN`` of the box diagonal from the walls; (P, 3), possibly empty.
    ``sigma``: the signed depth's width, in the frame's units."""
    lo, hi = verts.min(0), verts.max(0)
    probes = lo + (hi - lo) * np.random.default_rng(seed).random((CAVITY_PROBES, 3))
    try:
        hull = Delaunay(trimesh.convex.convex_hull(verts).vertices)
    except (QhullError, ValueError):  # a flat mesh has no volume and no cavity
        return np.zeros((0, 3))
    probes = probes[hull.find_simplex(probes) >= 0]
    if not len(probes):
        return probes
    dist, _ = index.tree.query(probes)
    depth = losses.signed_depth(torch.as_tensor(probes, dtype=torch.float32)[None], index, sigma, 8)[0]
    keep = (depth.numpy() < 0) & (dist > CAVITY_MARGIN * float(np.linalg.norm(hi - lo)))
    return probes[keep]


def opening_sides(pair: PreparedPair, points: np.ndarray) -> np.ndarray:
    """The two horizontal sides of the opening that cavity ``points`` span, shortest first, with the probes' wall
    gap (``CAVITY_MARGIN`` of the target's diagonal) added back: the cavity's width, wall to wall."""
    verts = pair.target_vertices.cpu().numpy().astype(np.float64)
    margin = 2 * CAVITY_MARGIN * float(np.linalg.norm(np.ptp(verts, axis=0)))
    return np.sort(np.ptp(points[:, [0, 2]], axis=0) + margin)


