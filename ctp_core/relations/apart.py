"""Where, without contact or beside it: ``beside``, ``under``, the sides (``front``, ``behind``, ``left``,
``right``), ``above``, ``below``, ``near``, ``far`` and the orientations (``facing``, ``facing_away``, ``aligned``)."""

from __future__ import annotations

import math
from functools import partial

import numpy as np
import torch
from scipy.spatial import cKDTree

from ctp_core.contact import Proposals, surface_regions
from ctp_core.geometry.pose import quaternion_to_matrix
from ctp_core.pairs import PreparedPair
from ctp_core.reading.records import RelationName
from ctp_core.reading.relation import RelationReading
from ctp_core.relations import parts
from ctp_core.relations.building import LEAN_POINTS, kept_where_put, random_resting, target_axes, yawed
from ctp_core.relations.measures import (
    CONTACT,
    FAR,
    OFF_CENTRE,
    Context,
    half_width,
    hinge,
    horizontal_unit,
    hull_distance_2d,
    off_centre,
    off_floor,
    soft_max,
    soft_min,
    surface_gap,
    toward,
    turned,
)
from ctp_core.relations.spec import Judge, Spec

BESIDE_GAP = 0.5  # "beside": the gap at most this many *mean* diagonals of figure and ground
UNDER_REACH = 0.5  # "under": a downward-facing ground sample above the figure within this of its centre's column
SIDE_OVERLAP = 0.05  # front/behind/left/right: the figure's near side may reach this share of its diagonal back
NEAR_GAP = 1.0  # "near": the gap at most this many *mean* diagonals of figure and ground (twice ``BESIDE_GAP``)
FAR_GAP = 2.0  # "far": the gap at least this many mean diagonals
CLEAR = 2 * CONTACT  # "above", "below": the gap's bound in the score; what holds is a gap of at least ``CONTACT``
# (the score's tolerance, ``HOLDS`` + ``SMOOTH`` / 2, takes the rest): not touching
FACING = math.cos(math.radians(45.0))  # orientations: the figure's front within 45 degrees of the wanted direction


def _score_under(c: Context) -> torch.Tensor:
    """``under``: below a downward-facing part of the ground and inside its footprint, standing where the ground
    stands (its lowest level). Sum of: the horizontal distance from the figure's centre to the nearest
    downward-facing ground sample above the figure's top, past ``UNDER_REACH`` figure half-widths (a vertical
    shortfall counts as distance too); the figure's centre outside the ground's footprint; its bottom off the
    floor (above or below it) past contact."""
    fig, ground = c.figure, c.ground.samples
    gp = ground.points.expand(fig.points.shape[0], -1, -1)
    down = c.ground.mask("down").expand(gp.shape[:2])
    horizontal = (gp[..., [0, 2]] - fig.centre[:, None, [0, 2]]).norm(dim=-1)
    below = (c.top()[:, None] - gp[..., 1]).clamp_min(0.0)  # the ground sample lower than the figure's top
    reach = soft_min(horizontal + below, c.tau(), mask=down)
    reach = torch.where(torch.isfinite(reach), reach, FAR * c.unit)
    overhead = c.h(reach - UNDER_REACH * half_width(fig))
    inside = c.h(hull_distance_2d(fig.centre[:, [0, 2]], ground.points[..., [0, 2]]))
    return overhead + inside + c.h((c.bottom() - c.floor).abs() - c.tol())


def _score_beside(c: Context) -> torch.Tensor:
    """``beside`` (next to, behind, in front of): on the ground's floor (the figure's bottom at the ground's
    lowest level), its centre outside the ground's footprint, and a gap to the ground at most ``BESIDE_GAP``
    mean diagonals; contact is not required."""
    fig, ground = c.figure, c.ground.samples
    floor = c.h((c.bottom() - c.floor).abs() - c.tol())
    outside = c.h(-hull_distance_2d(fig.centre[:, [0, 2]], ground.points[..., [0, 2]]))
    gap, mean_diag = _apart(c)
    return floor + outside + c.h(gap - BESIDE_GAP * mean_diag)


def _apart(c: Context) -> tuple[torch.Tensor, torch.Tensor]:
    """(B,) the gap between the figure and the ground's surface (a smooth minimum over the figure's samples), and
    the mean of their diagonals, normalised units."""
    gap, _ = surface_gap(c.figure.points, c.ground)
    return c.finite(soft_min(gap, c.tau())), (c.unit + c.ground.samples.diagonal.expand_as(c.unit)) / 2


def _score_side(c: Context, side: str) -> torch.Tensor:
    """``front``, ``behind``, ``left``, ``right``: ``beside`` the ground on that side of it, in its own frame
    (``axes``: the viewer's where its front cannot be trusted): the figure's centre beyond the ground's extent
    that way (its farthest sample along the side's direction) by more than it is beyond the ground's extent either
    way across (a wedge from the ground's corners: a box level with a sofa's left end and a little in front is on
    its left; one well in front of that end is in front), and its near side beyond that extent too, but for
    ``SIDE_OVERLAP`` of its diagonal (a lamp to the right of a monitor stands clear of it, not behind its edge)."""
    way = toward(side, c.front, c.left)
    across = c.left if side in ("front", "behind") else c.front
    aside = torch.maximum(_beyond(c, across), _beyond(c, -across)).clamp_min(0.0)
    extent = _extent(c, way)
    beyond = (c.figure.centre * way).sum(-1) - extent  # ``_beyond(c, way)``, the extent measured once
    near = (c.figure.points * way[:, None, :]).sum(-1).min(-1).values - extent
    return _score_beside(c) + c.h(aside - beyond) + c.h(-SIDE_OVERLAP * c.unit - near)


def _beyond(c: Context, direction: torch.Tensor) -> torch.Tensor:
    """(B,) how far the figure's centre lies beyond the ground's farthest sample along ``direction`` (B, 3)."""
    return (c.figure.centre * direction).sum(-1) - _extent(c, direction)


def _extent(c: Context, direction: torch.Tensor) -> torch.Tensor:
    """(B,) the ground's farthest sample along ``direction`` (B, 3)."""
    return (c.ground.samples.points * direction[:, None, :]).sum(-1).max(-1).values


def score_above(c: Context) -> torch.Tensor:
    """``above`` (no contact: a painting above a sofa, a lamp over a table; Sr3D's): the figure's bottom higher than
    the ground's top by more than contact (``CLEAR``), their footprints overlapping (``_overlap``)."""
    top = c.ground.samples.points[..., 1].max(-1).values.expand_as(c.unit)
    return c.h(top + CLEAR * c.unit - c.bottom()) + _overlap(c)


def _score_below(c: Context) -> torch.Tensor:
    """``below``: the figure's top lower than the ground's *underside over it* (the lowest ground surface over the
    figure's footprint: within its half-width of its centre's column) by more than contact, their footprints
    overlapping (``_overlap``). Sr3D's "below" (under the ground's bottom) where the ground is compact (a lamp hung
    over a box); under a lifted part of a ground that stands on the floor (a shelf board between its uprights, a
    desk's top) too, where Sr3D's can never hold. A ground with nothing lifted over the figure (a block on the
    floor) leaves no room: the score is then least tucked low against it, and never holds. ``under`` is the
    same place standing on the floor; ``below`` asks no contact with anything."""
    fig = c.figure
    gp = c.ground.samples.points.expand(fig.points.shape[0], -1, -1)
    over = (gp[..., [0, 2]] - fig.centre[:, None, [0, 2]]).norm(dim=-1) <= half_width(fig)[:, None]
    clearance = soft_min(gp[..., 1], c.tau(), mask=over) - c.top()
    clearance = torch.where(torch.isfinite(clearance), clearance, -FAR * c.unit)  # nothing over it
    return c.h(CLEAR * c.unit - clearance) + _overlap(c)


def _overlap(c: Context) -> torch.Tensor:
    """How far the footprints (seen from above) are from overlapping: the figure's centre farther than its own
    half-width from the ground's footprint (its convex hull), figure diagonals, hinged."""
    hull = hull_distance_2d(c.figure.centre[:, [0, 2]], c.ground.samples.points[..., [0, 2]])
    return c.h(hull - half_width(c.figure))


def _score_near(c: Context) -> torch.Tensor:
    """``near``: the gap to the ground at most ``NEAR_GAP`` mean diagonals of the two (a scale-free band: a cup
    near a plate is a few centimetres away, a car near a house a few metres)."""
    gap, mean_diag = _apart(c)
    return c.h(gap - NEAR_GAP * mean_diag)


def _score_far(c: Context) -> torch.Tensor:
    """``far``: the gap to the ground at least ``FAR_GAP`` mean diagonals of the two."""
    gap, mean_diag = _apart(c)
    return c.h(FAR_GAP * mean_diag - gap)


def _score_facing(c: Context, sign: float) -> torch.Tensor:
    """``facing`` (sign 1; Holodeck's "face to") and ``facing_away`` (-1): the figure's own front within 45 degrees
    (``FACING``) of the horizontal direction to the ground's centre, or of the direction away from it (a chair lying
    on its back, its front up, faces nothing). In cosine units (scale-free by nature)."""
    toward = horizontal_unit(c.ground.samples.centre - c.figure.centre)
    return hinge(FACING - sign * (c.heading * toward).sum(-1))


def _score_aligned(c: Context) -> torch.Tensor:
    """``aligned`` (with): the figure's front within 45 degrees of the ground's horizontal front (``axes``; the
    viewer's frame makes it face the viewer). In cosine units."""
    return hinge(FACING - (c.heading * c.front).sum(-1))


def _standing(c: Context) -> torch.Tensor:
    """(B,) how far the figure is from standing on the floor as it is set down: how far it is turned from it
    (``turned``) and how far it stands off the floor (``off_floor``)."""
    return turned(c) + off_floor(c)


def _prefer_side(c: Context, side: RelationName) -> torch.Tensor:
    """``front``, ``behind``, ``left``, ``right``: standing, centred on that side of the ground, a hand's width out
    (``parts.side_place``; the wedge of ``_score_side`` stays the judge of where it holds)."""
    if c.pair is None:
        return torch.zeros_like(c.unit)
    return _standing(c) + parts.side_place(c, parts.find_parts(c.pair).sides[side])


# "beside": the ground's own sides, left first where both are equally usual
LATERAL = (RelationName.LEFT, RelationName.RIGHT)
SECOND_SIDE = 0.05  # ``_prefer_beside``: what the right side costs against the left (a fixed order, not a judgement)


def _prefer_beside(c: Context) -> torch.Tensor:
    """``beside`` (next to): standing at a lateral side of the ground (its left or right, in its frame), centred on
    it, a hand's width out (``parts.side_place``): the nearer of the two, the left first on a tie."""
    if c.pair is None:
        return torch.zeros_like(c.unit)
    sides = parts.find_parts(c.pair).sides
    each = [parts.side_place(c, sides[name]) + i * SECOND_SIDE for i, name in enumerate(LATERAL)]
    return _standing(c) + torch.minimum(*each)


def _where_side(c: Context, side: RelationName) -> str | None:
    return None if c.pair is None else parts.find_parts(c.pair).sides[side].reason


def _where_beside(c: Context) -> str | None:
    return None if c.pair is None else "; ".join(parts.find_parts(c.pair).sides[name].reason for name in LATERAL)


def _prefer_under(c: Context) -> torch.Tensor:
    """``under``: standing, under the middle of the ground (``off_centre``)."""
    return _standing(c) + off_centre(c)


def _prefer_below(c: Context) -> torch.Tensor:
    """``below``: standing on the floor (its bottom's height from the floor, either way, past contact, in figure
    diagonals: a box below a hung lamp stands under it rather than floats or sinks), near the middle."""
    return c.h((c.bottom() - c.floor).abs() - c.tol()) + off_centre(c)


# ``apart``: the gap to the target, in mean diagonals of the two, drawn uniformly in the band of the relation's kind
APART_GAPS = {"side": (0.05, BESIDE_GAP / 2), "near": (0.05, NEAR_GAP / 2),
              "far": (1.1 * FAR_GAP, 1.5 * FAR_GAP)}


ABOVE_CLEAR = (0.1, 0.5)  # ``apart``, "above": the source's bottom this many of its diagonals over the target's top
BELOW_CLEAR = 0.1  # ``beneath``: the source's top at least this many of its diagonals under the point it stands below
# (twice ``CLEAR``: clear of it past the contact tolerance)
def apart(pair: PreparedPair, proposals: Proposals, seed: int, reading: RelationReading,
          log_s: float, count: int) -> Proposals:
    """Sources where a reading without contact puts them (``extend``; the module docstring says where)."""
    position, turn = reading.position, reading.orientation
    kind = reading.records[0].kind
    rng = np.random.default_rng(seed + 41)
    scale = math.exp(log_s)
    target = pair.anchor.points.cpu()
    front, left = target_axes(pair)
    if kind == "side":
        u = toward(position, front, left).expand(count, 3)
    elif position == "beside":  # the ground's lateral sides, alternately (``_prefer_beside``)
        u = torch.cat([toward(LATERAL[i % 2], front, left) for i in range(count)])
    else:
        angle = torch.as_tensor(rng.uniform(0, 2 * math.pi, count), dtype=torch.float32)
        u = torch.stack([angle.sin(), torch.zeros_like(angle), angle.cos()], -1)
    resting = random_resting(proposals, rng, count)
    if turn is None or kind == "vertical":
        heading = rng.uniform(0, 2 * math.pi, count)
    else:  # the source's front (azimuth about +Y, from +Z) to the wanted direction
        want = {"facing": -u, "facing_away": u, "aligned": front.expand(count, 3)}[turn]
        own = quaternion_to_matrix(resting) @ torch.as_tensor(pair.source_front, dtype=torch.float32)
        heading = (torch.atan2(want[:, 0], want[:, 2]) - torch.atan2(own[:, 0], own[:, 2])).numpy()
    q = yawed(resting, heading)
    rotated = torch.einsum("bij,nj->bni", quaternion_to_matrix(q), pair.source_subset(LEAN_POINTS).cpu()) * scale
    source_diagonal = pair.source_diagonal * scale
    if position == "above":  # over a point of the target's top, clear of it
        top = torch.as_tensor(surface_regions(pair)[2]["top"], dtype=torch.long)
        over = target[top if len(top) else torch.arange(len(target))]
        anchor = over[torch.as_tensor(rng.integers(len(over), size=count))].clone()
        anchor[:, 1] = target[:, 1].max() + torch.as_tensor(rng.uniform(*ABOVE_CLEAR, count)) * source_diagonal
    else:  # on the floor, out from the target's extent along u, by a gap in the band
        across = torch.stack([u[:, 2], torch.zeros(count), -u[:, 0]], -1)
        reach = (target @ u.T).max(0).values + (-(rotated * u[:, None, :]).sum(-1)).max(1).values
        lateral = kind == "side" or position == "beside"
        gap = torch.as_tensor(rng.uniform(*APART_GAPS["side" if lateral else position if kind == "distance"
                                                      else "near"], count), dtype=torch.float32)
        beside = target @ across.T  # (M, B): the target's extent across u
        lo, high = beside.min(0).values, beside.max(0).values
        level = lo + (high - lo) * torch.as_tensor(rng.uniform(0.25, 0.75, count) if lateral
                                                   else np.full(count, 0.5), dtype=torch.float32)
        anchor = u * (reach + gap * (source_diagonal + 2 * pair.target_radius) / 2)[:, None] + across * level[:, None]
        anchor[:, 1] = pair.floor
    return kept_where_put(pair, proposals, q, anchor, log_s, position)


def beneath(pair: PreparedPair, proposals: Proposals, seed: int, reading: RelationReading | None,
            log_s: float, count: int) -> Proposals | None:
    """Sources standing on the floor under a down-facing point of the target lifted high enough for them, more of
    them near the middle of its footprint (``near_footprint_middle``) (``extend``; the module docstring says
    where); None where no point is."""
    points, _, regions, density = surface_regions(pair)
    under = regions["bottom"]
    rng = np.random.default_rng(seed + 43)
    scale = math.exp(log_s)
    resting = random_resting(proposals, rng, count)
    q = yawed(resting, rng.uniform(0, 2 * math.pi, count))
    rising = torch.einsum("bij,nj->bni", quaternion_to_matrix(q), pair.source_subset(LEAN_POINTS).cpu())[..., 1]
    heights = (rising.amax(1) - rising.amin(1)) * scale
    reach = pair.source_diagonal / 2 * scale  # the source's widest half-width, any way it is turned
    column = cKDTree(points[:, [0, 2]]).query_ball_point(points[under][:, [0, 2]], r=reach, workers=1)
    # (U,) the room under each down-facing point: its column's lowest target surface (as wide as the source: the
    # score's footprint) over the floor
    room = np.array([points[near, 1].min() for near in column]) - pair.floor
    need = heights.numpy().astype(np.float64) + BELOW_CLEAR * pair.source_diagonal * scale  # (B,)
    fits = room[None, :] >= need[:, None]  # (B, U)
    keep = np.flatnonzero(fits.any(1))
    if not len(keep):
        return None
    weights = density[under][None, :] * fits[keep] * near_footprint_middle(points[under])[None, :]
    pick = [under[rng.choice(len(under), p=w / w.sum())] for w in weights]
    anchor = torch.as_tensor(points[pick], dtype=torch.float32)
    anchor[:, 1] = pair.floor
    label = "below" if reading is None else reading.position
    return kept_where_put(pair, proposals, q[torch.as_tensor(keep)], anchor, log_s, label)


def near_footprint_middle(points: np.ndarray) -> np.ndarray:
    """(N,) a drawing weight for points of a ground: 1, and more near the middle of its footprint
    (``parts.near_middle`` of the offset in its half-extents), where the usual place is."""
    xz = points[:, [0, 2]]
    low, high = xz.min(0), xz.max(0)
    offset = (xz - (low + high) / 2) / np.maximum((high - low) / 2, 1e-9)
    return 1.0 + parts.near_middle(np.linalg.norm(offset, axis=1))



def _between_frame(grounds: list[torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """(u, v, gap, corridor) of two grounds' samples (M, 3): ``u`` the horizontal unit direction from the first's
    centre to the second's, ``v`` across it (horizontal); ``gap`` (2,) where the first ends and the second begins
    along ``u`` (their facing sides); ``corridor`` (2,) the span across ``u`` both grounds share (where neither
    does, the span between their centres)."""
    a, b = grounds[0], grounds[1]
    u = horizontal_unit(b.mean(0) - a.mean(0))
    v = torch.stack([u[2], torch.zeros_like(u[0]), -u[0]])
    gap = torch.stack([(a @ u).max(), (b @ u).min()])
    low, high = torch.maximum((a @ v).min(), (b @ v).min()), torch.minimum((a @ v).max(), (b @ v).max())
    if low > high:
        low, high = torch.sort(torch.stack([a.mean(0) @ v, b.mean(0) @ v])).values
    return u, v, gap, torch.stack([low, high])


def _score_between(c: Context) -> torch.Tensor:
    """``between`` (two grounds: "between the sofa and the armchair"): on the floor, clear of both (past contact, as
    ``above`` keeps: ``CLEAR``), the figure wholly in the gap between the grounds' facing sides along the line joining
    their centres, and its centre within the corridor they share across that line. With fewer than two grounds
    named it cannot hold: ``FAR``."""
    if len(c.grounds) < 2:
        return torch.full_like(c.unit, FAR)
    u, v, gap, corridor = _between_frame(c.grounds)
    along = c.figure.points @ u  # (B, N)
    inside = c.h(gap[0] - soft_min(along, c.tau())) + c.h(soft_max(along, c.tau()) - gap[1])
    across = c.figure.centre @ v
    lateral = c.h(corridor[0] - across) + c.h(across - corridor[1])
    floor = c.h((c.bottom() - c.floor).abs() - c.tol())
    clear, _ = _apart(c)
    return floor + inside + lateral + c.h(CLEAR * c.unit - clear)


def _prefer_between(c: Context) -> torch.Tensor:
    """``between``: the middle of the gap and of the corridor (``OFF_CENTRE`` x the figure's centre's distance
    from there, in figure diagonals)."""
    if len(c.grounds) < 2:
        return torch.zeros_like(c.unit)
    u, v, gap, corridor = _between_frame(c.grounds)
    middle = u * gap.mean() + v * corridor.mean()
    offset = (c.figure.centre - middle) * torch.tensor([1.0, 0.0, 1.0], device=u.device)
    return OFF_CENTRE * offset.norm(dim=-1) / c.unit


def between(pair: PreparedPair, proposals: Proposals, seed: int, reading: RelationReading,
            log_s: float, count: int) -> Proposals | None:
    """Sources standing on the floor in the gap between the pair's two grounds (``PreparedPair.grounds``): along
    the line joining them in the middle half of the gap, across it in the middle half of their shared corridor,
    turned about +Y at random, kept where they are put; None with fewer than two grounds."""
    if len(pair.grounds) < 2:
        return None
    rng = np.random.default_rng(seed + 43)
    u, v, gap, corridor = (t.cpu() for t in _between_frame([g.points.cpu() for g in pair.grounds]))
    along = gap[0] + (gap[1] - gap[0]) * torch.as_tensor(rng.uniform(0.25, 0.75, count), dtype=torch.float32)
    across = corridor[0] + (corridor[1] - corridor[0]) * torch.as_tensor(rng.uniform(0.25, 0.75, count),
                                                                         dtype=torch.float32)
    anchor = along[:, None] * u + across[:, None] * v
    anchor[:, 1] = pair.floor
    resting = random_resting(proposals, rng, count)
    q = yawed(resting, rng.uniform(0, 2 * math.pi, count))
    return kept_where_put(pair, proposals, q, anchor, log_s, "between")

_ON_SIDE = {side: f"standing {where}, centred on that side, a hand's width away" for side, where in (
    (RelationName.FRONT, "in front of the ground"), (RelationName.BEHIND, "behind the ground"),
    (RelationName.LEFT, "to the ground's left"), (RelationName.RIGHT, "to the ground's right"))}
R = RelationName
SPECS: dict[RelationName, Spec] = {
    R.BESIDE: Spec(R.BESIDE, Judge(_score_beside, _prefer_beside), apart,
                   usual="standing at the ground's left or right side (the left first), centred on it, a hand's width"
                         " away", where=_where_beside),
    R.UNDER: Spec(R.UNDER, Judge(_score_under, _prefer_under), beneath,
                  usual="standing under the middle of the part overhead"),
    **{side: Spec(side, Judge(partial(_score_side, side=side), partial(_prefer_side, side=side)), apart,
                  usual=_ON_SIDE[side], where=partial(_where_side, side=side)) for side in _ON_SIDE},
    R.ABOVE: Spec(R.ABOVE, Judge(score_above), apart, usual="over the ground's top, clear of it"),
    R.BELOW: Spec(R.BELOW, Judge(_score_below, _prefer_below), beneath,
                  usual="on the floor under the ground's middle"),
    R.NEAR: Spec(R.NEAR, Judge(_score_near), apart, usual="on the floor close to the ground"),
    R.FAR: Spec(R.FAR, Judge(_score_far), apart, usual="on the floor away from the ground"),
    R.FACING: Spec(R.FACING, Judge(partial(_score_facing, sign=1.0)), apart, usual="its front toward the ground"),
    R.FACING_AWAY: Spec(R.FACING_AWAY, Judge(partial(_score_facing, sign=-1.0)), apart,
                        usual="its front away from the ground"),
    R.ALIGNED: Spec(R.ALIGNED, Judge(_score_aligned), apart, usual="its front along the ground's front"),
    R.BETWEEN: Spec(R.BETWEEN, Judge(_score_between, _prefer_between), between,
                    usual="on the floor in the middle of the gap between the two grounds"),
}
del R
