"""Where the search's candidates come from: poses that already touch the target, from geometry alone.

The benchmark protocol (and any user's file) starts the source anywhere with any rotation, and local descent
spends its whole budget getting close. The search instead enumerates poses that already touch the target and
lets the guide rank them in batches, with no gradient (``ranking``).

``propose``: points on the target surface (area-weighted, denser where the surface faces up and along rims),
split into regions (``REGIONS``): surfaces facing up, sideways and down, the target's cavity (inside its convex
hull, outside the target as the penetration term defines it), lateral gaps, drops (the source lowered from
above onto a point's column, every ``sampling.summits`` peak first: a spire's tip or a head's top has too little
area to be drawn) and the floor (standing where the target stands, under or around it). Each point gets a source
orientation from the source's own frames (its upright frame and its flip turned about +Y, its stable resting
poses; uniform rotations in the ``random`` init mode), and ``settle`` moves the source until it touches without
interpenetrating. The prompt's relation (``RelationReading``) only *weights* how many proposals each region gets
(``region_weights``); every region keeps a share. The caller's start is one more candidate where it is near the
target.

Frames: every pose maps the source local frame to the normalised frame (``pose``); points and directions here
are in the normalised frame.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
import trimesh
from scipy.spatial import Delaunay, QhullError

from ctp_core import losses
from ctp_core.config import AlignConfig, share_of
from ctp_core.geometry import sampling
from ctp_core.geometry.pose import (
    Poses,
    matrix_to_quaternion,
    quaternion_product,
    quaternion_to_matrix,
    random_quaternions,
)
from ctp_core.objective import NEAR, clearance
from ctp_core.orientation import canonical
from ctp_core.pairs import UP_FACING, PreparedPair
from ctp_core.relations.vocabulary import RelationReading

REGIONS: tuple[str, ...] = ("top", "side", "bottom", "inside", "gap", "drop", "floor")
# How a proposal comes into contact (``settle``): toward the closest target sample (a surface's outward normal
# is where it starts from), straight down its site's -normal (lowered from above), or not at all (it rests on
# the floor where it was put and only leaves the target if it starts inside it).
APPROACHES: tuple[str, ...] = ("closest", "straight", "none")
SETTLE_POINTS = 256  # source samples checked for penetration when settling proposals
APPROACH_POINTS = 64  # source samples used while sliding proposals into contact
CONTACT_SAMPLES = 6000  # target samples for settling proposals (the losses use ``loss.samples``)
SETTLE_ITERATIONS = 12
PUSH_ITERATIONS = 3
HULL_POINTS = 96  # source convex hull vertices kept for the stable poses
CAVITY_PROBES = 4096  # quasi-random points in the target AABB tried as cavity proposals

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


def region_weights(reading: RelationReading | None) -> dict[str, float]:
    """Weight of every region for the reading's position in the source's role (``Relation.figure_regions``,
    ``ground_regions``; a reading of two: its position, "front+facing": front); at least 1 each (1: no preference,
    and every region for no relation)."""
    chosen = {} if reading is None else reading.regions
    return {r: max(1.0, float(chosen.get(r, 1.0))) for r in REGIONS}


def allocate(available: dict[str, int], weights: dict[str, float], total: int, min_share: float) -> dict[str, int]:
    """Proposals per region: proportional to weight x size (in region points), each non-empty region keeping at
    least ``min_share`` of its unweighted count and at least one."""
    present = {r: n for r, n in available.items() if n > 0}
    if not present:
        return {r: 0 for r in available}
    size = sum(present.values())
    plain = {r: total * n / size for r, n in present.items()}
    mass = {r: weights[r] * n for r, n in present.items()}
    norm = sum(mass.values())
    counts = {r: max(1, share_of(plain[r], min_share), int(round(total * mass[r] / norm))) for r in present}
    return {r: counts.get(r, 0) for r in available}


def orientations(pair: PreparedPair, config: AlignConfig, generator: torch.Generator) -> torch.Tensor:
    """(R, 4) source orientations, source local -> normalised, from the source's own frames.

    The upright frame and its flip, each turned in ``search.yaw_steps`` about +Y, and the ``search.stable_poses``
    most probable resting poses (trimesh, on the source's convex hull) turned the same way; in the ``random``
    init mode as many uniform rotations instead (the resting poses are not computed).
    """
    cfg = config.search
    if config.optim.init_rotation == "random":  # as many as the source's own frames give at most
        return random_quaternions(cfg.yaw_steps * (2 + cfg.stable_poses), generator)
    yaw = torch.arange(cfg.yaw_steps, dtype=torch.float32) * (2 * math.pi / cfg.yaw_steps)
    turns = torch.stack([torch.cos(yaw / 2), 0 * yaw, torch.sin(yaw / 2), 0 * yaw], dim=1)
    up = pair.source_upright.rotation
    flip = np.diag([1.0, -1.0, -1.0])  # half turn about x: upside down
    bases = [up, flip @ up]
    if cfg.stable_poses:
        rests = _stable_poses(canonical.unit_size(pair.source), config.seed)  # rotations do not depend on size
        z_to_y = trimesh.transformations.rotation_matrix(-math.pi / 2, [1, 0, 0])[:3, :3]  # rests stand on +Z
        bases += [z_to_y @ np.asarray(m)[:3, :3] for m in rests[: cfg.stable_poses]]
    base = torch.tensor(np.stack([matrix_to_quaternion(b) for b in bases]), dtype=torch.float32)
    q = quaternion_product(turns[:, None].expand(-1, len(base), -1), base[None].expand(len(turns), -1, -1))
    return q.reshape(-1, 4)


def _stable_poses(source: trimesh.Trimesh, seed: int) -> list[np.ndarray]:
    """trimesh's resting poses of the source's convex hull, most probable first; none for a flat source (a
    single face or a planar mesh has no 3-D hull to rest on: its own frames are the orientations).

    Pass a unit-size copy (``canonical.unit_size``): trimesh's tolerances are absolute, and at 1e-6 the hull of
    a box has no faces (no resting poses at all)."""
    try:
        hull = source.convex_hull
        if len(hull.vertices) > HULL_POINTS:  # trimesh's stable poses loop over hull faces: keep the hull small
            keep = np.random.default_rng(seed).choice(len(hull.vertices), HULL_POINTS, replace=False)
            hull = trimesh.convex.convex_hull(hull.vertices[keep])
        if not hull.volume > 0:
            return []
        with np.errstate(all="ignore"):
            rests, _ = trimesh.poses.compute_stable_poses(hull, center_mass=hull.center_mass, seed=seed)
    except (QhullError, ValueError, IndexError):
        return []
    return list(rests)


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
    _, near = anchor.tree.query(points, k=min(8, len(points)), workers=1)
    spread = 1.0 - np.linalg.norm(normals[near].mean(axis=1), axis=1)
    height = (points[:, 1] - points[:, 1].min()) / max(float(np.ptp(points[:, 1])), 1e-9)
    density = 1.0 + np.clip(ny, 0.0, None) + (spread > 0.3) + 2.0 * height**4
    regions = {"top": np.flatnonzero(ny > UP_FACING), "bottom": np.flatnonzero(ny < -UP_FACING),
               "side": np.flatnonzero(np.abs(ny) <= UP_FACING)}
    return points, normals, regions, density


def cavity_points(pair: PreparedPair, seed: int) -> np.ndarray:
    """Points inside the target's convex hull but outside the target (its cavity, as the penetration term sees
    it: behind no oriented surface), away from the walls; (P, 3), possibly empty."""
    return hollow(pair.target_vertices.cpu().numpy().astype(np.float64), pair.index, seed, CAVITY_SIGMA)


CAVITY_MARGIN = 0.02  # of the hull's box diagonal: how far a cavity point stays from the walls
CAVITY_SIGMA = 0.01  # the depth's nearest-sample width in the normalised frame (a target's diagonal is about 3)


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
    dist, _ = index.tree.query(probes, k=1, workers=1)
    depth = losses.signed_depth(torch.as_tensor(probes, dtype=torch.float32)[None], index, sigma, 8)[0]
    keep = (depth.numpy() < 0) & (dist > CAVITY_MARGIN * float(np.linalg.norm(hi - lo)))
    return probes[keep]


def floor_points(pair: PreparedPair, count: int, margin: float, rng: np.random.Generator) -> np.ndarray:
    """(count, 3) points on the plane the target stands on (its lowest point's height, normalised frame, +Y up),
    uniform over the related object's footprint widened by ``margin`` on every side: things under or beside
    an object rest where it does."""
    lo, hi = pair.anchor.points.min(0).values.numpy(), pair.anchor.points.max(0).values.numpy()
    out = lo - margin + (hi - lo + 2 * margin) * rng.random((count, 3))
    out[:, 1] = pair.floor
    return out


def contact_index(pair: PreparedPair, count: int = CONTACT_SAMPLES, seed: int = 0) -> losses.SurfaceIndex:
    """Denser target samples than the losses' (normalised frame, outward normals) for placing proposals: the
    sampled depth and distance are only as good as the spacing."""
    parts = pair.target_outward  # a scene of placed objects: all of them, oriented once by prepare_pair
    oriented = parts[0] if len(parts) == 1 else trimesh.util.concatenate(
        [trimesh.Trimesh(m.vertices, m.faces, process=False) for m in parts])
    points, normals = sampling.surface_samples(oriented, count, seed)
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
        dist, idx = index.tree.query(posed.reshape(-1, 3).numpy().astype(np.float64), k=2, workers=1)
        idx = torch.as_tensor(idx.reshape(*posed.shape[:2], 2), dtype=torch.long)
        dist = torch.as_tensor(dist[:, 0].reshape(posed.shape[:2]), dtype=centre.dtype)
        # behind the sampled surface and mostly along its normal: above a feature thinner than the sample
        # spacing (a spire's tip) a point is behind the planes of the samples on either side, though outside
        depth = losses.signed_depth(posed, index, 0.01, 2, idx=idx)
        # a sample outside the target's box (by more than a sample spacing) is outside the target: far from a
        # surface thinner than the spacing (a plate under a source 100 times its size) the nearest sample's side
        # is a coin toss, and a wrong "inside" pushed such a source hundreds of radii away
        within = ((posed >= low) & (posed <= high)).all(dim=-1)
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


def propose(pair: PreparedPair, config: AlignConfig, weights: dict[str, float], log_s: float | Sequence[float],
            generator: torch.Generator, init: Poses | None = None) -> Proposals:
    """``search.candidates`` poses in contact, drawn per region by ``allocate`` (see module docstring).

    Proposals the settling could not free from the target are dropped. ``log_s`` is the source scale of every
    proposal (rigid: kept from the files or the caller's start), or the scales they take in turn (scale mode:
    ``scaling.ScalePlan.rungs``, the first one sizing the floor's margin, the gaps and the summits' cells);
    ``init`` (one pose) is added as a candidate as given when it is within ``objective.NEAR`` of the target.
    """
    cfg = config.search
    rungs = [float(log_s)] if isinstance(log_s, int | float) else [float(r) for r in log_s]
    rng = np.random.default_rng(config.seed)
    points, normals, regions, density = surface_regions(pair)
    cavity = cavity_points(pair, config.seed)
    sides = regions["side"]
    # unweighted shares: the surface regions by area (sample counts); the cavity as at most a quarter of the
    # surface, the lateral gaps as half the sides, drops from above as a quarter of the surface and the floor as
    # an eighth, whatever the number of probes that landed there
    available = {"top": len(regions["top"]), "side": len(sides), "bottom": len(regions["bottom"]),
                 "inside": min(len(cavity), len(points) // 4), "gap": len(sides) // 2, "drop": len(points) // 4,
                 "floor": len(points) // 8}
    counts = allocate(available, weights, cfg.candidates, cfg.min_share)
    rotations = orientations(pair, config, generator)
    up = np.array([0.0, 1.0, 0.0])
    diagonal = pair.source_diagonal * math.exp(rungs[0])
    everywhere = np.arange(len(points))
    parts = []
    for region, n in counts.items():
        if n == 0:
            continue
        zero, ones, above = np.zeros(n), np.ones(n, bool), np.tile(up, (n, 1))
        if region == "inside":  # centred on a cavity point, pushed up out of any wall
            parts.append((cavity[rng.integers(len(cavity), size=n)], above, zero, ~ones, "closest"))
        elif region == "floor":  # standing on the plane the target stands on, under it or around it
            parts.append((floor_points(pair, n, diagonal, rng), above, zero, ones, "none"))
        else:
            pool = {"gap": sides, "drop": everywhere}.get(region, regions.get(region))
            w = density[pool] / density[pool].sum()
            pick = pool[rng.choice(len(pool), size=n, p=w)]
            if region == "drop":  # lowered from above onto a point's column: every summit first, then by density
                peaks = sampling.summits(points, diagonal)[: n // 2]
                pick[: len(peaks)] = peaks
                parts.append((points[pick], above, zero, ones, "straight"))
                continue
            choices = np.array([g for g in cfg.gaps if g > 0] or [0.0]) if region == "gap" else np.zeros(1)
            parts.append((points[pick], normals[pick], rng.choice(choices, size=n) * diagonal, ones, "closest"))
    labels = [region for region, n in counts.items() if n for _ in range(n)]
    as_t = lambda i: torch.as_tensor(np.concatenate([p[i] for p in parts]), dtype=torch.float32)  # noqa: E731
    sites = Site(as_t(0), as_t(1), as_t(2), torch.as_tensor(np.concatenate([p[3] for p in parts])),
                 torch.as_tensor(np.concatenate([np.full(len(p[0]), APPROACHES.index(p[4])) for p in parts])))
    q = rotations[torch.as_tensor(rng.integers(len(rotations), size=len(sites.anchor)))]
    index = contact_index(pair, seed=config.seed)
    scales = torch.tensor(rungs, dtype=torch.float32)[torch.arange(len(q)) % len(rungs)]  # every region, every rung
    poses, free = place(pair, index, q, sites, scales)
    labels = [label for label, ok in zip(labels, free.tolist(), strict=True) if ok]
    sites = sites.select(free)
    if init is not None and float(clearance(pair, index, init.select(slice(0, 1)))[0]) <= NEAR:
        # the caller's start, as given, where it is near the target (a start away from it answers no contact
        # search, yet an image guide can rank it high: an absent source differs less from the goal than a
        # misplaced one); no site: the orientation sweep skips it
        poses = Poses.cat([init.select(slice(0, 1)), poses])
        labels = ["init", *labels]
        given = Site(init.t[:1].cpu(), torch.tensor([[0.0, 1.0, 0.0]]), torch.zeros(1),
                     torch.zeros(1, dtype=torch.bool), torch.zeros(1, dtype=torch.long))
        sites = Site(*(torch.cat([a, b]) for a, b in zip(vars(given).values(), vars(sites).values(), strict=True)))
    device = pair.source_vertices.device
    return Proposals(Poses(poses.t.to(device), poses.q.to(device), poses.log_s.to(device)), labels, sites,
                     rotations, index)


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
