"""Into the ground: ``in`` (held in its cavity), ``penetrate`` (driven into it), ``wear`` (worn over its top)."""

from __future__ import annotations

import math

import numpy as np
import torch

from ctp_core import contact
from ctp_core.contact import Proposals, opening_sides, surface_regions
from ctp_core.geometry.pose import Poses, quaternion_product, quaternion_to_matrix
from ctp_core.pairs import PreparedPair
from ctp_core.reading.records import RelationName
from ctp_core.reading.relation import RelationReading
from ctp_core.relations import parts
from ctp_core.relations.building import LEAN_POINTS, labelled, long_axis_up, lowered, quaternion_onto, straight_sites
from ctp_core.relations.measures import (
    FAR,
    SOFT,
    Context,
    gap_to,
    ground_summits,
    half_width,
    hinge,
    hull_distance_3d,
    off_centre,
    soft_min,
    summit_drop,
    surface_gap,
)
from ctp_core.relations.spec import Bound, Judge, Spec

IN_DEPTH = 0.1  # "in": the figure's lowest point this far below the rim (less is resting on the rim)
PENETRATE = (0.02, 0.9)  # "penetrate": the share of the figure inside the ground, in this open range
WEAR_CENTRE = 0.5  # "wear": the ground's summit within this many figure half-widths of the centre's column
ENCLOSING_RAYS = 16  # ``_enclosure``: horizontal directions looked along from the figure's foot
FOOT = 0.05  # ``_enclosure``: the figure's foot, this far above its lowest point


def _score_in(c: Context) -> torch.Tensor:
    """``in``: inside the ground's cavity: the figure's lowest point below the ground's rim (its top) by at least
    ``IN_DEPTH`` and inside the ground's convex hull under its centre (so inside the hull's footprint), resting
    on the inner floor or walls (in contact with the ground). A candle in a holder or a lipstick in its cover
    sticks out above the rim: its centre need not be below it, its foot must."""
    fig, ground = c.figure, c.ground.samples
    rim = ground.points[..., 1].max(-1).values.expand_as(c.unit)
    foot = torch.stack([fig.centre[:, 0], c.bottom(), fig.centre[:, 2]], -1)
    hull = hull_distance_3d(foot, ground.points)
    return c.h(c.bottom() - rim + IN_DEPTH * c.unit) + c.h(hull) + c.touching()


def _prefer_in(c: Context) -> torch.Tensor:
    """``in``: held by its sides, near the middle, and in through an opening where the ground has openings, not
    through its wall (``parts.through_openings``)."""
    openings = parts.thin_parts(c.pair).openings if c.pair is not None else ()
    through = parts.through_openings(c, openings) if openings else torch.zeros_like(c.unit)
    return 1.0 - _enclosure(c) + off_centre(c) + through


def _where_in(c: Context) -> str | None:
    if c.pair is None or not (found := parts.thin_parts(c.pair)).openings:
        return None
    deepest = found.openings[0].describe(found.unit, found.floor)[0].removeprefix("an opening: ")
    return (f"in the cavity near its middle, held by its sides, in through one of its {len(found.openings)} "
            f"opening(s), not its wall (the deepest: {deepest})")


def _enclosure(c: Context) -> torch.Tensor:
    """(B,) ``enclosure`` of the figure's foot: its centre's column, ``FOOT`` above its lowest point."""
    foot = torch.stack([c.figure.centre[:, 0], c.bottom() + FOOT * c.unit, c.figure.centre[:, 2]], -1)
    return enclosure(foot, c.ground.samples.points, c.ground.samples.spacing, FOOT * c.unit)


def enclosure(foot: torch.Tensor, ground: torch.Tensor, spacing: torch.Tensor | float,
              lift: torch.Tensor | float) -> torch.Tensor:
    """(B,) the share of ``ENCLOSING_RAYS`` horizontal directions from each ``foot`` (B, 3) along which a
    ``ground`` sample (B or 1, N, 3) lies within ``spacing`` of the ray (the samples as discs, as in ``surface_gap``):
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


def _score_penetrate(c: Context) -> torch.Tensor:
    """``penetrate``: a bounded share of the figure inside the ground (between ``PENETRATE``'s bounds, as a
    smooth count of samples behind the ground's surface), so it enters through the surface and stays partly
    out."""
    _, along = surface_gap(c.figure.points, c.ground)
    inside = torch.sigmoid(-along / c.tau()).mean(-1)
    lo, hi = PENETRATE
    return hinge(lo - inside) + hinge(inside - hi)


def _prefer_penetrate(c: Context) -> torch.Tensor:
    """``penetrate``: end first, from above the floor, near the middle."""
    below_floor = c.h(c.floor - c.figure.points[..., 1].min(-1).values)
    return _end_first(c) + below_floor + off_centre(c)


def _end_first(c: Context) -> torch.Tensor:
    """(B,) 1 less how squarely the figure's long axis (its samples' principal direction) crosses the ground's
    surface where it enters (the mean |cosine| with the ground's normals at the figure's samples within contact
    of that surface, either side): 0 for a stick driven straight in, 1 for one lying sunk along the surface;
    ``FAR`` where nothing crosses it."""
    fig, reach = c.figure, c.reach()[:, None]
    centred = fig.points - fig.points.mean(1, keepdim=True)
    # (B, 3), the largest eigenvalue's; no gradient through it (eigh's is unbounded where eigenvalues meet: a ball)
    axis = torch.linalg.eigh((centred.transpose(1, 2) @ centred).detach())[1][..., -1]
    u, n, found = c.ground.nearest(fig.points.detach())
    gap, along = gap_to(fig.points, c.ground, u, n, found)
    entry = ((gap <= reach) & (along.abs() <= reach)).detach()
    cos = (n * axis[:, None, :]).sum(-1).abs()
    share = (cos * entry).sum(-1) / entry.sum(-1).clamp_min(1)
    return torch.where(entry.any(-1), 1.0 - share, torch.full_like(share, FAR))


def _score_wear(c: Context) -> torch.Tensor:
    """``wear``: on a summit of the ground (a peak of its top surface: a head's top, ``sampling.summits`` with
    the figure's width as the neighbourhood; the one nearest the figure), covering it: that summit within
    ``WEAR_CENTRE`` figure half-widths of the figure's centre column, the figure's bottom below it, in contact."""
    fig, ground = c.figure, c.ground.samples
    width = half_width(fig)
    peaks = ground_summits(ground, float(width.mean()))  # (B or 1, P, 3)
    offset = (peaks[..., [0, 2]] - fig.centre[:, None, [0, 2]]).norm(dim=-1)  # (B, P)
    above = (c.bottom()[:, None] - peaks[..., 1]).clamp_min(0.0)  # the figure's bottom above the peak: not covering
    cost = soft_min(hinge((offset - WEAR_CENTRE * width[:, None]) / c.unit[:, None])
                    + hinge(above / c.unit[:, None]), SOFT)
    return cost + c.touching()


PIERCE_DEPTH = (0.1, 0.5)  # "penetrate": how much of its length the source is driven in, uniform in this range
ENCLOSURE_BATCH = 64  # up-facing points whose enclosure is measured at once (memory: batch x samples x rays)


def contained(pair: PreparedPair, proposals: Proposals, seed: int, reading: RelationReading | None,
              log_s: float, count: int) -> Proposals | None:
    """Sources standing in the target's most enclosed up-facing places (``extend``); None where no up-facing
    point is enclosed at all. An opening's floor is among the most enclosed already: which of them is the
    preference's to say (``parts.through_openings``)."""
    points, _, regions, density = surface_regions(pair)
    top = regions["top"]
    if not len(top):
        return None
    lift = FOOT * pair.source_diagonal * math.exp(log_s)  # the source's foot, as the predicate's
    ground = torch.as_tensor(points, dtype=torch.float32)
    feet = ground[torch.as_tensor(top)] + torch.tensor([0.0, lift, 0.0])
    spacing = pair.sample_spacing(len(points))
    held = torch.cat([enclosure(chunk, ground[None], spacing, lift)
                      for chunk in feet.split(ENCLOSURE_BATCH)]).numpy().astype(np.float64)
    weights = density[top] * held**4
    if weights.sum() <= 0:
        return None
    rng = np.random.default_rng(seed + 29)
    pick = top[rng.choice(len(top), size=count, p=weights / weights.sum())]
    upright = long_axis_up(pair, rng, count // 2)
    resting = proposals.rotations[torch.as_tensor(rng.integers(len(proposals.rotations), size=count - len(upright)))]
    q = torch.cat([upright, resting.cpu()])
    up = torch.tensor([0.0, 1.0, 0.0]).expand(count, 3)
    return lowered(pair, proposals, q, torch.as_tensor(points[pick], dtype=torch.float32), up, True, log_s,
                    "contained")


def pierced(pair: PreparedPair, proposals: Proposals, seed: int, reading: RelationReading | None,
            log_s: float, count: int) -> Proposals:
    """Sources driven end first into the target (``extend``): on the longest principal axis along the inward
    normal of a surface sample that does not face down (either end first, any turn about that axis),
    ``PIERCE_DEPTH`` of their length in, raised where that would pass below the floor the target stands on.
    Not settled: they are meant to intersect."""
    points, normals, regions, density = surface_regions(pair)
    rng = np.random.default_rng(seed + 37)
    weights = density.copy()
    weights[regions["bottom"]] = 0.0  # from below, it would pass through the floor the target stands on
    pick = rng.choice(len(points), size=count, p=weights / weights.sum())
    inward = -normals[pick] / np.linalg.norm(normals[pick], axis=1, keepdims=True)
    up = np.array([0.0, 1.0, 0.0])
    standing = long_axis_up(pair, rng, count)  # on its long axis, either end up, turned about it
    q = torch.cat([quaternion_product(quaternion_onto(up, d)[None], standing[i:i + 1]) for i, d in enumerate(inward)])
    local = pair.source_subset(LEAN_POINTS).cpu()
    rotated = torch.einsum("bij,nj->bni", quaternion_to_matrix(q), local) * math.exp(log_s)
    d = torch.as_tensor(inward, dtype=torch.float32)
    along = (rotated * d[:, None, :]).sum(-1)  # extent along the inward normal
    lead, length = along.max(1).values, along.max(1).values - along.min(1).values
    depth = torch.as_tensor(rng.uniform(*PIERCE_DEPTH, size=count), dtype=torch.float32) * length
    t = torch.as_tensor(points[pick], dtype=torch.float32) - d * (lead - depth)[:, None]
    # not through the floor the target stands on: raised to it where it would pass below (less deep from above)
    t[:, 1] += (pair.floor - (t[:, 1] + rotated[..., 1].min(1).values)).clamp_min(0.0)
    sites = straight_sites(torch.as_tensor(points[pick], dtype=torch.float32), -d, True)
    return labelled(pair, proposals, Poses(t, q, torch.full((count,), log_s)), sites, "pierce")


FIT_STEPS = 64  # log scales scanned for the ``wear`` fit over twice the ladder's span
FIT_TOLERANCE = math.log(1.25)  # a ``wear`` fit's band: the scales where the source's inside is within 25 % of the


def cavity_bound(pair: PreparedPair, seed: int) -> float | None:
    """``in``: the largest log scale at which the source's two shortest sides fit the target cavity's two
    horizontal sides (normalised frame, +Y up); None without a cavity."""
    cavity = contact.cavity_points(pair, seed)
    if len(cavity) < 8:
        return None
    opening = opening_sides(pair, cavity)
    sides = np.sort(np.ptp(pair.source_vertices.cpu().numpy(), axis=0))[:2]
    return float(np.min(np.log(opening / np.maximum(sides, 1e-30))))


def wear_fit(pair: PreparedPair, seed: int, around: float, span: float) -> Bound | None:
    """``wear``: the smallest log scale (within ``span`` of ``around``) at which the source's cavity,
    in its upright frame, is as wide as the target's top part as deep as the cavity (normalised frame, +Y up): a
    cap on a sphere comes down until its rim meets it, so a larger one sits lower, over a wider part. With the
    band of scales within ``FIT_TOLERANCE`` of fitting; None when the source has no cavity or the scan finds no
    such scale."""
    local = pair.source_vertices.cpu().numpy().astype(np.float64)
    surface = pair.source_surface
    diagonal = float(np.linalg.norm(np.ptp(local, axis=0)))  # the source's, local frame
    sigma = contact.CAVITY_SIGMA * diagonal / max(
        float(np.linalg.norm(np.ptp(pair.target_vertices.cpu().numpy(), axis=0))), 1e-30)
    inside = contact.hollow(local, surface, seed, sigma)
    if len(inside) < 8:
        return None
    upright = inside @ pair.source_upright.rotation.T
    margin = 2 * contact.CAVITY_MARGIN * diagonal
    width, depth = float(np.ptp(upright[:, [0, 2]], axis=0).max()) + margin, float(np.ptp(upright[:, 1])) + margin
    points = pair.anchor.points.cpu().numpy().astype(np.float64)
    top = float(points[:, 1].max())
    scales = np.linspace(around - span, around + span, FIT_STEPS)
    misfit = []  # ln(the covered part's width / the inside's width) at each scale: > 0 while it cannot go on
    for log_s in scales:
        part = points[points[:, 1] >= top - math.exp(log_s) * depth]
        head = float(np.ptp(part[:, [0, 2]], axis=0).max()) if len(part) > 1 else 0.0
        misfit.append(math.log(max(head, 1e-30) / (math.exp(log_s) * width)))
    misfit = np.asarray(misfit)
    fits = np.flatnonzero(misfit <= 0)
    if not len(fits) or fits[0] == 0:  # never wide enough, or wide enough at any scale scanned: no fit
        return None
    best = int(fits[0])  # the smallest scale whose inside takes the part it covers: snug
    near = scales[np.abs(misfit) <= FIT_TOLERANCE]
    near = near[np.abs(near - scales[best]) <= 2 * FIT_TOLERANCE + 1e-9]  # the best's own stretch, not a far one
    return Bound("wear: fits what wears it", float(scales[best]), "fit",
                 band=(float(min(near.min(initial=scales[best]), scales[best])),
                       float(max(near.max(initial=scales[best]), scales[best]))))


def _fits_cavity(pair: PreparedPair, seed: int, around: float, span: float) -> Bound | None:
    limit = cavity_bound(pair, seed)
    return None if limit is None else Bound("in: fits the cavity", limit, "upper")


R = RelationName
SPECS: dict[RelationName, Spec] = {
    R.IN: Spec(R.IN, Judge(_score_in, _prefer_in), contained, _fits_cavity,
               "in the cavity, near its middle, held by its sides", where=_where_in),
    R.PENETRATE: Spec(R.PENETRATE, Judge(_score_penetrate, _prefer_penetrate), pierced,
                      usual="end first into the middle, from above the floor"),
    R.WEAR: Spec(R.WEAR, Judge(_score_wear, summit_drop), bound=wear_fit, usual="over the highest summit"),
}
del R
