"""Held against the ground: ``attach``, ``hold``, ``wrap``, ``hang``, ``lean``."""

from __future__ import annotations

import math

import numpy as np
import torch

from ctp_core.contact import Proposals, surface_regions
from ctp_core.geometry.pose import quaternion_product, quaternion_to_matrix
from ctp_core.pairs import PreparedPair, per_pair
from ctp_core.reading.records import RelationName
from ctp_core.reading.relation import RelationReading
from ctp_core.relations import parts, thin
from ctp_core.relations.apart import FACING
from ctp_core.relations.building import LEAN_POINTS, long_axis_up, lowered, quaternion_onto, target_axes, yaw_turn
from ctp_core.relations.measures import (
    FAR,
    OFF_CENTRE,
    Context,
    features,
    hinge,
    off_centre,
    off_floor,
    soft_max,
    soft_min,
    surface_gap,
    toward,
)
from ctp_core.relations.spec import Bound, Judge, Spec

WRAP_SHARE = 0.3  # "wrap": at least this share of the figure touching (the relation table's contact is 0.6)
LEAN_RISE = 0.25  # "lean": the side contact at least this far above the figure's bottom (lying flat: ~0)
HANG_DROP = 0.05  # "hang": the centre of mass at least this far below the contact's mean height
FIXED = 0.5  # ``preference`` "hang": hung under a down-facing surface (fixed to a ceiling) rather than resting on


def _score_attach(c: Context) -> torch.Tensor:
    """``attach``: in contact with the ground's surface (glued, mounted, clipped: a face or a foot)."""
    return c.touching()


def _score_hold(c: Context) -> torch.Tensor:
    """``hold``: in contact with the ground, at its side surfaces (a hand closes around a handle from the side),
    not set on top of it: the figure's centre below the ground's top."""
    ground_top = c.ground.samples.points[..., 1].max(-1).values
    return c.touching("wall") + c.h(c.figure.centre[:, 1] - ground_top)


def _score_wrap(c: Context) -> torch.Tensor:
    """``wrap``: around a part of the ground: at least ``WRAP_SHARE`` of the figure's samples touching it (a
    smooth count)."""
    gap, _ = surface_gap(c.figure.points, c.ground)
    share = torch.sigmoid((c.reach()[:, None] - gap) / c.tau()).mean(-1)
    return c.touching() + hinge(WRAP_SHARE - share)


def _score_hang(c: Context) -> torch.Tensor:
    """``hang``: in contact with the ground, the contact at the figure's upper part: the centre of mass at least
    ``HANG_DROP`` below the highest touching sample (a ring hangs from a peg through it; resting on top of the
    peg, its centre is above every contact)."""
    fig = c.figure
    gap, _ = surface_gap(fig.points, c.ground)
    touching = gap <= c.reach()[:, None]
    nearest = gap <= gap.min(-1, keepdim=True).values  # no contact: the nearest sample stands for it
    height = soft_max(fig.points[..., 1], c.tau(), mask=(touching | nearest).detach())
    return c.touching() + c.h(fig.centre[:, 1] - height + HANG_DROP * c.unit)


def _borne(c: Context) -> torch.Tensor:
    """(B,) how far the figure is from hanging freely from ground that bears it, in figure diagonals: its centre
    ``HANG_DROP`` below its highest sample touching an up-facing ground surface (a peg's or a hook's top, a
    branch: it rests there) and *plumb*: straight below that sample, as a hung thing swings to rest (a ring
    hooked over a wall's top edge with its centre out in front is not). Touching only a down-facing surface
    there (a lamp under a ceiling) it needs a fixing the geometry cannot see: ``FIXED`` more. ``FAR`` where it
    touches neither (only sides: flat against a wall)."""
    fig, reach = c.figure, c.reach()[:, None]
    out = torch.full_like(c.unit, FAR)
    for which, extra in (("down", FIXED), ("up", 0.0)):  # near the surface, not merely behind a sample's plane
        gap, along = surface_gap(fig.points.detach(), c.ground, which)
        bearing = (gap <= reach) & (along >= -reach)
        borne = bearing.any(-1)
        highest = fig.points[..., 1].detach().masked_fill(~bearing, -torch.inf).argmax(-1)
        support = fig.points[torch.arange(len(highest)), highest]  # (B, 3); any sample where nothing bears it
        hung = c.h(fig.centre[:, 1] - support[:, 1] + HANG_DROP * c.unit)
        plumb = (fig.centre[:, [0, 2]] - support[:, [0, 2]]).norm(dim=-1) / c.unit
        out = torch.where(borne, torch.minimum(out, hung + plumb + extra), out)
    return out


def _score_lean(c: Context) -> torch.Tensor:
    """``lean``: touching a side of the ground (a sideways-facing surface) at least ``LEAN_RISE`` above the
    figure's bottom, while that bottom is on the floor (a board lying flat against a box's foot only touches
    at the floor)."""
    fig = c.figure
    gap, _ = surface_gap(fig.points, c.ground, "wall")
    raised = fig.points[..., 1] >= (c.bottom() + LEAN_RISE * c.unit)[:, None]
    side = c.h(c.finite(soft_min(gap, c.tau(), mask=raised)) - c.reach())
    return side + c.h((c.bottom() - c.floor).abs() - c.tol())


LEAN_ORDER = 0.1  # ``_prefer_lean``: what a side costs per place in the order of the sides a person leans on


def _prefer_lean(c: Context) -> torch.Tensor:
    """``lean``: heavy end down (the figure's centre low between its bottom and its top, as a share of its height,
    whatever its tilt: a rake on its head, a guitar on its body), nearly upright (1 less its height in its
    diagonals: leaning a little, not lying half down), standing on the floor (``off_floor``), against a side a
    person reaches (``parts.GroundSide.accessible``: not the back of a ground with a front, which stands against a
    wall), centred on it (``parts.side_place``, touching: no gap term): the nearest such side's, in ``lean_order``
    (the side the prompt names, where it names one: "against the back of"); the middle of the ground's footprint
    (``off_centre``) where the source is the ground."""
    if c.pair is None:
        return off_centre(c)
    low = (c.figure.centre[:, 1] - c.bottom()) / (c.top() - c.bottom()).clamp_min(1e-9)
    sides = parts.find_parts(c.pair).sides
    named = c.reading.side if c.reading is not None else None  # "against the back of": that side only
    order = (named,) if named in sides else lean_order(c.pair.front_trusted)
    each = [parts.side_place(c, sides[name], gap=False) + i * LEAN_ORDER for i, name in enumerate(order)]
    steep = 1.0 - (c.top() - c.bottom()) / c.unit
    return low + steep + off_floor(c) + torch.stack(each).min(0).values


def lean_order(trusted: bool) -> tuple[RelationName, ...]:
    """The sides a person leans a thing on, first first: a ground with a front of its own is used from it (drawers,
    doors, a seat) and stands with its back to a wall, so its left and right, then its front; one without (a drum,
    a post) from the side the viewer sees first, then the others."""
    R = RelationName
    return (R.LEFT, R.RIGHT, R.FRONT) if trusted else (R.FRONT, R.LEFT, R.RIGHT, R.BEHIND)


def _where_lean(c: Context) -> str | None:
    if c.pair is None:
        return None
    order = lean_order(c.pair.front_trusted)
    return f"the {', then the '.join(order)}; " + "; ".join(s.reason for s in parts.find_parts(c.pair).sides.values())


def _prefer_hang(c: Context) -> torch.Tensor:
    """``hang``: hung freely from what bears it (``_borne``), under the middle of a bar where the ground has bars
    (``parts.bar_place``: a towel rail's middle, not its end, nor the wall plate behind it), else at the middle of
    the ground along its length (``along_middle``). Where it hangs weighs at most half what its bearing is short
    of ``FAR``: every pose borne at all stays before one that is not (a ring fixed under a wall's underside far
    from the peg before one flat against the wall)."""
    borne = _borne(c)
    bars = parts.thin_parts(c.pair).bars if c.pair is not None else ()
    place = parts.bar_place(c, bars) if bars else along_middle(c)
    return borne + torch.where(borne < FAR, torch.minimum(place, (FAR - borne) / 2), torch.zeros_like(borne))


def _where_hang(c: Context) -> str | None:
    if c.pair is None or not (found := parts.thin_parts(c.pair)).bars:
        return None
    longest = found.bars[0].describe(found.unit, found.floor).removeprefix("a bar: ")
    return f"hung freely under the middle of one of its {len(found.bars)} bar(s) (the longest: {longest})"


def along_middle(c: Context) -> torch.Tensor:
    """(B,) ``OFF_CENTRE`` x the distance of the figure's centre from the middle of the ground's footprint along
    its longer horizontal extent (x or z), in half that extent."""
    gp = c.ground.samples.points[..., [0, 2]]
    low, high = gp.min(1).values, gp.max(1).values  # (B or 1, 2)
    axis = int((high - low)[0].argmax())
    half = ((high - low)[:, axis] / 2).clamp_min(1e-9)
    return OFF_CENTRE * (c.figure.centre[:, 2 * axis] - (low + high)[:, axis] / 2).abs() / half


LEAN_TILTS = (15.0, 30.0, 45.0)  # degrees from the source's frame toward the target
HOOK_FACING = 0.5  # a hook point's normal: at least this cosine toward the source's centre
HOOK_REACH = 0.1  # a hook point: at least this many source diagonals from the source's centre


def lean(pair: PreparedPair, proposals: Proposals, seed: int, reading: RelationReading | None,
         log_s: float, count: int) -> Proposals | None:
    """Tilted sources standing on the floor against the target's sides (``extend``), more of them near the middle
    of the sides a person reaches (``parts.near_side_middles``); None without side samples."""
    points, normals, regions, _ = surface_regions(pair)
    side = regions["side"]
    horizontal = normals[side] * np.array([1.0, 0.0, 1.0])
    length = np.linalg.norm(horizontal, axis=1)
    side, horizontal = side[length > 0.5], horizontal[length > 0.5] / length[length > 0.5, None]
    if reading is not None and reading.side is not None:  # only the named side's faces
        front, left = target_axes(pair)
        way = toward(reading.side, front, left)[0].numpy().astype(np.float64)
        facing = horizontal @ way >= FACING
        side, horizontal = side[facing], horizontal[facing]
    if not len(side):
        return None
    rng = np.random.default_rng(seed + 23)
    usual = parts.near_side_middles(parts.find_parts(pair), points[side], horizontal)
    pick = rng.choice(len(side), size=count, p=usual / usual.sum())
    n = torch.as_tensor(horizontal[pick], dtype=torch.float32)
    up = torch.tensor([0.0, 1.0, 0.0]).expand(count, 3)
    axis = torch.nn.functional.normalize(torch.linalg.cross(n, up), dim=-1)  # tilts +Y toward -n (the target)
    angle = torch.as_tensor(np.radians(rng.choice(LEAN_TILTS, size=count)), dtype=torch.float32)
    tilt = torch.cat([torch.cos(angle / 2)[:, None], axis * torch.sin(angle / 2)[:, None]], dim=1)
    q = quaternion_product(tilt, long_axis_up(pair, rng, count))
    local = pair.source_subset(LEAN_POINTS).cpu()
    rotated = torch.einsum("bij,nj->bni", quaternion_to_matrix(q), local) * math.exp(log_s)
    behind = (-(rotated * n[:, None, :]).sum(-1)).max(dim=1).values  # extent toward the target
    floor = pair.floor
    start = torch.as_tensor(points[side[pick]], dtype=torch.float32) + n * (behind + 1e-3 * pair.target_radius)[:, None]
    start[:, 1] = floor - rotated[..., 1].min(dim=1).values + 1e-3 * pair.target_radius
    return lowered(pair, proposals, q, start, n, False, log_s, "lean")


def hung(pair: PreparedPair, proposals: Proposals, seed: int, reading: RelationReading | None,
         log_s: float, count: int) -> Proposals | None:
    """Sources hung by a hook point on a thin up-facing part of the target (``extend``), more of them on a bar near
    its middle (``parts.near_bar_middles``); None where the source has no hook point or no up-facing part of the
    target is thin enough to pass into one."""
    local, plumb, hooks, clearance = hook_points(pair)
    clearance = clearance * math.exp(log_s)
    points, _, top, thickness, density, spacing = peg_thickness(pair)
    fits = thickness < (clearance.max() if len(hooks) else 0.0)
    if not fits.any():
        return None
    rng = np.random.default_rng(seed + 31)
    weights = density[top] * fits * parts.near_bar_middles(parts.thin_parts(pair), points[top])
    pick = rng.choice(len(top), size=count, p=weights / weights.sum())
    hook = np.array([rng.choice(hooks[clearance > thickness[i]]) for i in pick])
    down = np.array([0.0, -1.0, 0.0])
    q = torch.cat([quaternion_product(yaw_turn(rng.uniform(0, 2 * math.pi)), quaternion_onto(plumb[h], down)[None])
                   for h in hook])
    hook_posed = torch.einsum("bij,bj->bi", quaternion_to_matrix(q), torch.as_tensor(local[hook], dtype=torch.float32))
    start = torch.as_tensor(points[top[pick]], dtype=torch.float32) - hook_posed * math.exp(log_s)
    start[:, 1] += spacing
    up = torch.tensor([0.0, 1.0, 0.0]).expand(count, 3)
    return lowered(pair, proposals, q, start, up, False, log_s, "hang")


@per_pair
def hook_points(pair: PreparedPair) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The source's hook points (see the module docstring): its feature samples (source local frame), their plumb
    lines, the hook points' indices and their clearance (``_clearance``, source local units; only the finite
    ones: a loop or bend closes under them)."""
    feat = features(pair)
    local, normals = feat.source_points.cpu().double().numpy(), feat.source_normals.cpu().double().numpy()
    toward = feat.source_centre.cpu().double().numpy() - local
    reach = np.linalg.norm(toward, axis=1)
    plumb = toward / np.maximum(reach, 1e-12)[:, None]  # hung by a point, the centre settles straight below it
    diagonal = float(np.linalg.norm(np.ptp(local, axis=0)))
    hooks = np.flatnonzero(((normals * plumb).sum(1) > HOOK_FACING) & (reach > HOOK_REACH * diagonal))
    clearance = _clearance(local, plumb, hooks, feat.source_spacing)
    finite = np.isfinite(clearance)
    return local, plumb, hooks[finite], clearance[finite]


@per_pair
def peg_thickness(pair: PreparedPair) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """Where a hook point can take the target: its samples and their normals (normalised frame), the up-facing
    ones' indices, the target's vertical thickness under each (``thin.thickness``), the samples' density weights
    and spacing."""
    points, normals, regions, density = surface_regions(pair)
    spacing = pair.sample_spacing(len(points))
    top = regions["top"]
    return points, normals, top, thin.thickness(points, normals, top, spacing)[0], density, spacing


def _clearance(local: np.ndarray, plumb: np.ndarray, hooks: np.ndarray, spacing: float) -> np.ndarray:
    """(H,) how far each hook point's plumb line (toward the source's centre) runs inside the source's loop
    before it meets the source again (another sample within ``spacing`` of the line, beyond it): how thick a
    part hung in the hook can be; inf where the line meets nothing (no loop or bend closes under it)."""
    rel = local[None, :, :] - local[hooks, None, :]  # (H, N, 3)
    along = (rel * plumb[hooks, None, :]).sum(-1)
    off = np.sqrt(np.clip((rel**2).sum(-1) - along**2, 0.0, None))
    on_line = (along > 2 * spacing) & (off <= spacing)
    return np.where(on_line, along, np.inf).min(1)


CREST = math.radians(20.0)  # ``hang``: a sample's normal within this of straight up sees the part's whole thickness


def hang_bound(pair: PreparedPair) -> float | None:
    """``hang``: the smallest log scale at which some hook point's loop (``hook_points``: its
    clearance, source local units) takes the thinnest part of the target, so that a loop can pass over a peg at
    all: the vertical thickness (``peg_thickness``, normalised frame) under the samples facing within ``CREST`` of
    straight up (a round peg's crest, a rail's flat: the part's whole thickness; on a peg's slopes the column under
    a sample is thinner than the part); None without a hook point or such a sample with an underside."""
    _, _, hooks, clearance = hook_points(pair)
    _, normals, top, thickness, _, _ = peg_thickness(pair)
    thickness = thickness[np.isfinite(thickness) & (normals[top, 1] >= math.cos(CREST))]
    if not len(hooks) or not len(thickness):
        return None
    return math.log(float(thickness.min()) / max(float(clearance.max()), 1e-30))


def _takes_the_peg(pair: PreparedPair, seed: int, around: float, span: float) -> Bound | None:
    limit = hang_bound(pair)
    return None if limit is None else Bound("hang: its loop takes the peg", limit, "lower")


R = RelationName
SPECS: dict[RelationName, Spec] = {
    R.ATTACH: Spec(R.ATTACH, Judge(_score_attach), usual="anywhere on the ground's surface"),
    R.HOLD: Spec(R.HOLD, Judge(_score_hold), usual="at the ground's side, below its top"),
    R.WRAP: Spec(R.WRAP, Judge(_score_wrap), usual="around a part of the ground"),
    R.HANG: Spec(R.HANG, Judge(_score_hang, _prefer_hang), hung, _takes_the_peg,
                 "hung freely below what bears it, its centre under the hook, at the middle of the bar",
                 where=_where_hang),
    R.LEAN: Spec(R.LEAN, Judge(_score_lean, _prefer_lean), lean,
                 usual="heavy end down, against a side a person reaches (not the back of furniture), centred on it",
                 where=_where_lean),
}
del R
