"""The resting family: ``on``, ``stand``, ``sit``, ``lie``: the figure rests on its ground from above."""

from __future__ import annotations

import math

import numpy as np
import torch

from ctp_core import contact
from ctp_core.contact import Proposals, opening_sides
from ctp_core.geometry.pose import matrix_to_quaternion, quaternion_to_matrix
from ctp_core.pairs import PreparedPair
from ctp_core.reading.places import OFF_MIDDLE, SHELVES
from ctp_core.reading.records import RelationName
from ctp_core.reading.relation import RelationReading
from ctp_core.relations import parts
from ctp_core.relations.building import LEAN_POINTS, lowered, random_resting, yawed
from ctp_core.relations.measures import (
    FAR,
    Context,
    bearing_gap,
    ground_summits,
    half_width,
    off_centre,
    soft_max,
    soft_min,
    stability,
    summit_drop,
    support_depth,
    turned,
)
from ctp_core.relations.spec import Bound, Judge, Spec

ON_TOP = 0.05  # "on top of": no ground surface higher than the figure's top by more than this over it
FOOTPRINT_MIDDLE = 0.5  # ... over the middle of its footprint: this share of its half-width about its centre


def score_resting(c: Context) -> torch.Tensor:
    """Resting on (``on``, ``stand``, ``sit``, ``lie``): supported from below by ground surface that faces up,
    on the side it faces (so the centre of mass is above the contact: never from under a thin ground); its
    centre of mass over that support; and on top of it: no part of the ground higher than the figure's top
    over the figure's footprint (a cup on a table's lower shelf, or under the table, is not on it).

    Sum of: the figure's lowest part within contact of up-facing ground surface (the bottom band: samples
    within ``CONTACT`` of the figure's lowest point, their smooth minimum ``bearing_gap`` to up-facing samples);
    ``stable`` (the centre's horizontal distance outside the footprint of the support patch); the height
    of the ground above the figure's top, over its footprint, past ``ON_TOP``.
    """
    fig = c.figure
    gap = bearing_gap(fig.points, c.ground, "up", c.reach())
    band = fig.points[..., 1] <= (c.bottom() + c.tol())[:, None]
    support = c.h(c.finite(soft_min(gap, c.tau(), mask=band)) - c.reach())
    return torch.minimum(support, _apex(c)) + stability(c) + _overhead(c)


def _apex(c: Context) -> torch.Tensor:
    """Support by a summit: a cross on a spire's tip, a ball on a post's top. The tip is a point, sampled
    sparsely and facing sideways around it, so no up-facing sample need be near; it bears the figure when a
    summit of the ground (``ground_summits``, the figure's half-width as the neighbourhood) lies under the figure's
    footprint (within its half-width of the centre's column) at its bottom (within ``reach`` and the ground's
    sample spacing): 0 there, ``FAR`` elsewhere (the up-facing support, ``score_resting``, says how far). A
    cup touching a table's leg with its base's edge is beside no summit: the table's top is higher."""
    fig = c.figure
    width = half_width(fig)
    peaks = ground_summits(c.ground.samples, float(width.mean())).detach()  # (B or 1, P, 3)
    offset = (peaks[..., [0, 2]] - fig.centre[:, None, [0, 2]]).norm(dim=-1)
    slack = (c.reach() + c.ground.samples.spacing.reshape(-1).expand_as(c.unit))[:, None]
    under = (offset <= width[:, None]) & ((peaks[..., 1] - c.bottom()[:, None]).abs() <= slack)
    return torch.where(under.detach().any(-1), torch.zeros_like(c.unit), torch.full_like(c.unit, FAR))


def _overhead(c: Context) -> torch.Tensor:
    """How far ground surface rises above the figure's top over the middle of its footprint (within half its
    half-width of its centre's column: a shelf above covers it, a chair's back rising at its edge does not), in
    figure diagonals, hinged; 0 where the prompt names a shelf ("on the middle shelf": a board is above it)."""
    fig, ground = c.figure, c.ground.samples
    if c.place in SHELVES:
        return torch.zeros_like(c.unit)
    radius = FOOTPRINT_MIDDLE * half_width(fig)  # (B,)
    gp = ground.points.expand(fig.points.shape[0], -1, -1)
    horizontal = (gp[..., [0, 2]] - fig.centre[:, None, [0, 2]]).norm(dim=-1)
    over = horizontal <= radius[:, None]
    height = soft_max(gp[..., 1], c.tau(), mask=over)
    height = torch.where(torch.isfinite(height), height, torch.full_like(height, -1e3))
    return c.h(height - c.top() - ON_TOP * c.unit)


def _unsteady(c: Context) -> torch.Tensor:
    """(B,) 1 less the depth of the centre's projection inside its support's footprint, in its half-widths, in
    [0, 1]."""
    depth = -support_depth(c)
    return (1.0 - depth / half_width(c.figure).clamp_min(1e-9)).clamp(0.0, 1.0)


def _prefer_resting(c: Context) -> torch.Tensor:
    """Resting: standing as it is set down (``measures.turned``), steadily, on the usual surface
    (``parts.usual_spot``: a table's top, a chair's seat, the shelf the prompt names) in the middle of its free
    area (``parts.spot_place``); on the top near the middle where no surface holds the figure (a spire, a head)."""
    steady = _unsteady(c) + turned(c)
    spot = _spot(c)
    if spot is None:
        return summit_drop(c) + steady + off_centre(c)
    drop = (spot.surface.height - c.figure.points[..., 1].min(-1).values).abs() / c.unit
    return drop + steady + parts.spot_place(c, spot)


def _spot(c: Context) -> parts.Spot | None:
    return None if c.pair is None else parts.usual_spot(c.pair, float(c.unit.detach().mean()), c.place)


def _where(c: Context) -> str | None:
    """The surface the usual place is on, and why (``parts.usual_spot``)."""
    if c.pair is None:
        return None
    spot = _spot(c)
    if spot is None:
        return "no surface holds it: on the top, near the middle"
    at = f"; at its {c.place}" if c.place in OFF_MIDDLE else "; in the middle of its free area"
    return spot.surface.reason + at


FLAT = 0.5  # a lid: its upright height at most this share of its smaller horizontal side
OPENING_DEPTH = 0.1  # a top opening: cavity points within this share of the target's height from its top


def lid_bound(pair: PreparedPair, seed: int) -> float | None:
    """``on``, a flat source (its upright height at most ``FLAT`` of its smaller horizontal side) on a target open
    at the top (cavity points, ``contact.cavity_points``, within ``OPENING_DEPTH`` of its height from its top):
    the smallest log scale at which the source's footprint (its two horizontal sides, upright frame) covers that
    opening's two horizontal sides, as a lid covers a jar's or a box's rim; None otherwise."""
    upright = pair.source_vertices.cpu().numpy().astype(np.float64) @ pair.source_upright.rotation.T
    sides = np.ptp(upright, axis=0)
    footprint = np.sort(sides[[0, 2]])
    if sides[1] > FLAT * footprint[0]:
        return None
    cavity = contact.cavity_points(pair, seed)
    verts = pair.target_vertices.cpu().numpy().astype(np.float64)
    top, height = float(verts[:, 1].max()), float(np.ptp(verts[:, 1]))
    mouth = cavity[cavity[:, 1] >= top - OPENING_DEPTH * height]
    if len(mouth) < 8:
        return None
    return float(np.max(np.log(opening_sides(pair, mouth) / np.maximum(footprint, 1e-30))))


def _lid(pair: PreparedPair, seed: int, around: float, span: float) -> Bound | None:
    limit = lid_bound(pair, seed)
    return None if limit is None else Bound("on: a lid covers the opening", limit, "lower")


MIDDLE_JITTER = 0.15  # ``on_usual_surface``: anchors this share of the surface's half-span about its middle, at most


def on_usual_surface(pair: PreparedPair, proposals: Proposals, seed: int, reading: RelationReading | None,
                     log_s: float, count: int) -> Proposals | None:
    """Sources lowered onto the middle of the usual surface (``parts.usual_spot``: the one "on" means for this
    figure, or the one the prompt's place names), within ``MIDDLE_JITTER`` of its half-span, half of them standing
    as the source is set down (``source_upright``), half in its other resting frames, turned about +Y at random
    (``extend``): the regions' proposals fall anywhere on the ground and the refinement centres them only as far
    as the contact lets it. None where no surface holds the figure, or where the prompt names an end or an edge."""
    scale = math.exp(log_s)
    place = None if reading is None else reading.place
    spot = parts.usual_spot(pair, pair.source_diagonal * scale, place)
    if spot is None or place in OFF_MIDDLE:
        return None
    rng = np.random.default_rng(seed + 47)
    resting = random_resting(proposals, rng, count)
    standing = torch.as_tensor(matrix_to_quaternion(pair.source_upright.rotation), dtype=torch.float32)
    resting[: (count + 1) // 2] = standing  # half as it is set down, half in its other resting frames
    q = yawed(resting, rng.uniform(0, 2 * math.pi, count))
    rotated = torch.einsum("bij,nj->bni", quaternion_to_matrix(q), pair.source_subset(LEAN_POINTS).cpu()) * scale
    offset = rng.uniform(-1, 1, (count, 2)) * MIDDLE_JITTER * spot.half
    start = torch.zeros(count, 3)
    start[:, [0, 2]] = torch.as_tensor(spot.middle + offset, dtype=torch.float32)
    start[:, 1] = spot.surface.height - rotated[..., 1].min(dim=1).values + 0.01 * pair.target_radius
    up = torch.tensor([0.0, 1.0, 0.0]).expand(count, 3)
    return lowered(pair, proposals, q, start, up, False, log_s, "on")


_RESTING = Judge(score_resting, _prefer_resting)
_USUAL = ("on the usual surface (a table's or cabinet's top, the seat of a chair, sofa or bench, the shelf or end the "
          "prompt names), standing as it is set down, steadily, in the middle of the surface's free area")
R = RelationName
SPECS: dict[RelationName, Spec] = {
    R.ON: Spec(R.ON, _RESTING, on_usual_surface, _lid, usual=_USUAL, where=_where),
    **{name: Spec(name, _RESTING, on_usual_surface, usual=_USUAL, where=_where) for name in (R.STAND, R.SIT, R.LIE)},
}
del R
