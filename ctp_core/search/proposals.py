"""Where the search's candidates come from: poses that already touch the target, from geometry alone.

The benchmark protocol (and any user's file) starts the source anywhere with any rotation, and local descent
spends its whole budget getting close. The search instead enumerates poses that already touch the target and
lets the guide rank them in batches, with no gradient (``coarse_to_fine``).

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

import numpy as np
import torch
import trimesh
from scipy.spatial import QhullError

from ctp_core.config import AlignConfig, share_of
from ctp_core.contact import (
    APPROACHES,
    REACH,
    Proposals,
    Site,
    cavity_points,
    clearance,
    contact_index,
    place,
    surface_regions,
)
from ctp_core.geometry import sampling
from ctp_core.geometry.pose import (
    Poses,
    matrix_to_quaternion,
    quaternion_product,
    quaternion_to_matrix,
    random_quaternions,
)
from ctp_core.orientation import canonical
from ctp_core.pairs import PreparedPair
from ctp_core.reading.relation import RelationReading

REGIONS: tuple[str, ...] = ("top", "side", "bottom", "inside", "gap", "drop", "floor")
HULL_POINTS = 96  # source convex hull vertices kept for the stable poses


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
    init mode as many uniform rotations instead (the resting poses are not computed). A source that keeps its up
    (``PreparedPair.source_keeps_up``) gets its upright frame turned about +Y only, in either mode.
    """
    cfg = config.search
    yaw = torch.arange(cfg.yaw_steps, dtype=torch.float32) * (2 * math.pi / cfg.yaw_steps)
    turns = torch.stack([torch.cos(yaw / 2), 0 * yaw, torch.sin(yaw / 2), 0 * yaw], dim=1)
    up = pair.source_upright.rotation
    if pair.source_keeps_up:  # its upright frame turned about +Y, nothing else (random mode too)
        return quaternion_product(turns, torch.as_tensor(matrix_to_quaternion(up), dtype=torch.float32)[None]
                                  .expand(len(turns), -1))
    if config.optim.init_rotation == "random":  # as many as the source's own frames give at most
        return random_quaternions(cfg.yaw_steps * (2 + cfg.stable_poses), generator)
    flip = np.diag([1.0, -1.0, -1.0])  # half turn about x: upside down
    bases = [up, flip @ up]
    if cfg.stable_poses:
        rests = _stable_poses(canonical.unit_size(pair.source), config.seed)  # rotations do not depend on size
        z_to_y = trimesh.transformations.rotation_matrix(-math.pi / 2, [1, 0, 0])[:3, :3]  # rests stand on +Z
        bases += [z_to_y @ np.asarray(m)[:3, :3] for m in rests[: cfg.stable_poses]]
    base = torch.tensor(np.stack([matrix_to_quaternion(b) for b in bases]), dtype=torch.float32)
    q = quaternion_product(turns[:, None].expand(-1, len(base), -1), base[None].expand(len(turns), -1, -1))
    return q.reshape(-1, 4)


STANDING_COS = math.cos(math.radians(2.0))  # a pose whose source's up is this close to +Y keeps it standing


def standing(pair: PreparedPair, poses: Poses) -> torch.Tensor:
    """(B,) indices of the poses that keep the source standing: its own up (``source_upright``) within 2 degrees
    of +Y (what ``orientations`` makes for a source that keeps its up; a builder's own turns may not)."""
    up = torch.as_tensor(pair.source_upright.up, dtype=torch.float32)
    posed = torch.einsum("bij,j->bi", quaternion_to_matrix(poses.q.cpu()), up)
    return torch.nonzero(posed[:, 1] >= STANDING_COS).flatten()


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


def floor_points(pair: PreparedPair, count: int, margin: float, rng: np.random.Generator) -> np.ndarray:
    """(count, 3) points on the plane the target stands on (its lowest point's height, normalised frame, +Y up),
    uniform over the related object's footprint widened by ``margin`` on every side: things under or beside
    an object rest where it does."""
    lo, hi = pair.anchor.points.min(0).values.numpy(), pair.anchor.points.max(0).values.numpy()
    out = lo - margin + (hi - lo + 2 * margin) * rng.random((count, 3))
    out[:, 1] = pair.floor
    return out


def propose(pair: PreparedPair, config: AlignConfig, weights: dict[str, float], log_s: float | Sequence[float],
            generator: torch.Generator, init: Poses | None = None) -> Proposals:
    """``search.candidates`` poses in contact, drawn per region by ``allocate`` (see module docstring).

    Proposals the settling could not free from the target are dropped. ``log_s`` is the source scale of every
    proposal (rigid: kept from the files or the caller's start), or the scales they take in turn (scale mode:
    ``scaling.ScalePlan.rungs``, the first one sizing the floor's margin, the gaps and the summits' cells);
    ``init`` (one pose) is added as a candidate as given when it is within ``contact.REACH`` of the target.
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
    if init is not None and float(clearance(pair, index, init.select(slice(0, 1)))[0]) <= REACH:
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


