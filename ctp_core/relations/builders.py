"""Proposals that satisfy the prompt's relation by construction where the search's regions do not reach it.

``proposals.propose`` draws from regions (top, side, bottom, cavity, gaps, drops, floor) with the source in its
own resting frames; some relations need a pose none of them makes: a stick leaning against a box is neither
standing upright beside the box nor lying on it, and no region tilts it (docs/relations.md, "Where poses are judged
by it").

``lean``: the source standing on its longest principal axis (either end up, any turn about +Y), tilted by
``LEAN_TILTS`` about the horizontal axis along a side of the target, so its top tips toward the target; its
lowest point on the floor the target stands on, just outside a side sample (the "side" region's samples,
their outward normal made horizontal), then moved straight toward the target until it touches
(``contact.settle``'s "straight" approach). A reading that names the side leant on ("against the back of the
sofa": ``lean+behind``) draws only the side samples facing that way (``predicates.toward``; within 45 degrees).

``in``: the source standing in the target's most enclosed up-facing places (the floors of its cavities: the
share of horizontal directions around a point that meet the target, ``predicates.enclosure``, weighting the
draw), half on its longest principal axis (a candle in a holder's cup, a pencil in a mug), half in its own
resting frames (a hot dog in its bun), lowered onto the point. The regions' cavity proposals centre the source
on a point inside the target's hull: a candle standing in a shallow cup on top of a tall holder has its centre
above the rim, where no cavity point is.

``hang``: the source hung by a *hook point* on an up-facing point of a *thin* part of the target (a peg, a
branch, a rail), turned as it would hang: its centre straight below the hook point (any turn about +Y), the
hook point just above the target's point, then lowered into contact. A hook point is a sample whose normal
faces along its plumb line (toward the source's centre: the inside of a ring's loop, a hook's bend, a hanger's
crook) and whose plumb line meets the source again beyond it (the loop closes under it); the part fits when
the target's vertical thickness under its point (down to its next down-facing surface) is less than that
clearance. The regions approach the target from outside, so a ring never comes to be threaded on a peg: it
ends against the wall's side or hooked over its top edge.

``penetrate``: the source driven end first into the target: on its longest principal axis along the inward
normal of a surface sample that does not face down, ``PIERCE_DEPTH`` of its length in, raised where it would
pass below the floor; not settled (it is meant to intersect). The regions settle every proposal free of the
target, so what holds "penetrate" among them lies half sunk along a surface rather than standing in it.

The directional relations (``apart``): beside the target on the named side of it (``front``, ``behind``, ``left``,
``right``, in its own frame or the viewer's, ``predicates.axes``), ``near`` or ``far`` from it, or turned to it
alone (``facing``, ...): the source in its resting frames on the floor the target stands on, out from the
target's extent along the side's direction (any direction for near, far and orientations) by a gap in the
relation's band, level with the target across that direction (sides; its centre elsewhere); turned about +Y at
random, or so that its own front (``PreparedPair.source_front``) points as the reading's orientation says
(toward the target, away from it, along the target's front). ``above``: the source over a point of the target's
top surface, its bottom clear above the target's top. ``below`` (``beneath``): the source standing on the floor
under a down-facing point of the target lifted off it (a hung lamp's underside, a shelf board's, a desk top's), its
top clear by ``BELOW_CLEAR`` of the lowest target surface in that column (as wide as the source, as the score's
footprint); where nothing the target has is lifted high enough for the source (a block standing on the floor),
none are made. Kept where they are put (free of the target by construction: the
approach "none"; those that meet another part of it are dropped): the regions settle every proposal into contact.

Each kind is made only where it is the prompt's relation (its position, the first of a reading of two) with the
source as the figure and ``config.relation`` is on, in place of as many region proposals (``extend``); otherwise
the proposals are unchanged. ``BUILDERS`` names each relation's builder (a relation without one has none).

Not done (docs/relations.md lists them): "under" (the floor under a down-facing part), "beside" (the floor
just outside the footprint): the floor region already gives poses where those hold.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import torch
from scipy.spatial import cKDTree

from ctp_core.config import AlignConfig, share_of
from ctp_core.contact import APPROACHES, Proposals, Site, place, surface_regions
from ctp_core.geometry.pose import Poses, quaternion_product, quaternion_to_matrix
from ctp_core.pairs import PreparedPair, per_pair
from ctp_core.relations import predicates
from ctp_core.relations.vocabulary import RelationReading

LEAN_TILTS = (15.0, 30.0, 45.0)  # degrees from the source's frame toward the target
SHARE = 0.25  # a relation's own proposals, as a share of ``search.candidates`` (in place of the regions')
LEAN_POINTS = 128  # source samples for the tilted source's extent
ENCLOSURE_BATCH = 64  # up-facing points whose enclosure is measured at once (memory: batch x samples x rays)
PIERCE_DEPTH = (0.1, 0.5)  # "penetrate": how much of its length the source is driven in, uniform in this range
HOOK_FACING = 0.5  # a hook point's normal: at least this cosine toward the source's centre
HOOK_REACH = 0.1  # a hook point: at least this many source diagonals from the source's centre
# ``apart``: the gap to the target, in mean diagonals of the two, drawn uniformly in the band of the relation's kind
APART_GAPS = {"side": (0.05, predicates.BESIDE_GAP / 2), "near": (0.05, predicates.NEAR_GAP / 2),
              "far": (1.1 * predicates.FAR_GAP, 1.5 * predicates.FAR_GAP)}
ABOVE_CLEAR = (0.1, 0.5)  # ``apart``, "above": the source's bottom this many of its diagonals over the target's top
BELOW_CLEAR = 0.1  # ``beneath``: the source's top at least this many of its diagonals under the point it stands below
# (twice ``predicates.CLEAR``: clear of it past the contact tolerance)


def own_count(config: AlignConfig) -> int:
    """How many poses a relation's builder proposes: ``SHARE`` of ``search.candidates`` (``config.share_of``)."""
    return share_of(config.search.candidates, SHARE)


def extend(pair: PreparedPair, config: AlignConfig, proposals: Proposals, reading: RelationReading | None,
           seed: int) -> Proposals:
    """``proposals`` with those that satisfy the ``reading`` by construction (its position's ``BUILDERS`` entry; see
    the module docstring) in place of as many of theirs, spread evenly over them (the caller's start kept): the
    relation's proposals take their share of ``search.candidates`` rather than adding to it, so the search costs
    what it does without them."""
    if reading is None or not reading.known or not reading.source_is_figure or not config.relation:
        return proposals
    build = BUILDERS.get(reading.position)
    if build is None or proposals.rotations is None:
        return proposals
    # one build per scale the regions' proposals take (scale mode with a guide: every rung of the ladder, so the
    # guide judges the relation's own poses at each size, not at the centre alone), sharing the relation's count
    scales = list(dict.fromkeys(proposals.poses.log_s.tolist()))
    count = share_of(max(1, config.search.candidates // len(scales)), SHARE)  # ``own_count`` of each rung's share
    built = [build(pair, proposals, seed + i, reading, log_s, count) for i, log_s in enumerate(scales)]
    built = [extra for extra in built if extra is not None and len(extra.poses)]
    if not built:
        return proposals
    proposals = proposals.select(_thinned(proposals.region, sum(len(extra.poses) for extra in built)))
    parts = [proposals, *built]
    sites = Site(*(torch.cat(columns) for columns in zip(*(vars(part.sites).values() for part in parts), strict=True)))
    return Proposals(Poses.cat([part.poses for part in parts]), [r for part in parts for r in part.region], sites,
                     proposals.rotations, proposals.index)


def _thinned(region: list[str], drop: int) -> list[int]:
    """Indices of proposals ``region`` less ``drop`` of them, evenly spread (each region keeps its share), the
    caller's start ("init") always kept; at least one."""
    kept = [i for i, r in enumerate(region) if r != "init"]
    count = max(1, len(kept) - drop)
    chosen = {kept[int(k)] for k in np.linspace(0, len(kept) - 1, count).round()} if kept else set()
    return sorted(chosen | {i for i, r in enumerate(region) if r == "init"})


def lean(pair: PreparedPair, proposals: Proposals, seed: int, reading: RelationReading | None,
         log_s: float, count: int) -> Proposals | None:
    """Tilted sources standing on the floor against the target's sides (``extend``); None without side samples."""
    points, normals, regions, _ = surface_regions(pair)
    side = regions["side"]
    horizontal = normals[side] * np.array([1.0, 0.0, 1.0])
    length = np.linalg.norm(horizontal, axis=1)
    side, horizontal = side[length > 0.5], horizontal[length > 0.5] / length[length > 0.5, None]
    if reading is not None and reading.side is not None:  # only the named side's faces
        front, left = _target_axes(pair)
        way = predicates.toward(reading.side, front, left)[0].numpy().astype(np.float64)
        facing = horizontal @ way >= predicates.FACING
        side, horizontal = side[facing], horizontal[facing]
    if not len(side):
        return None
    rng = np.random.default_rng(seed + 23)
    pick = rng.integers(len(side), size=count)
    n = torch.as_tensor(horizontal[pick], dtype=torch.float32)
    up = torch.tensor([0.0, 1.0, 0.0]).expand(count, 3)
    axis = torch.nn.functional.normalize(torch.linalg.cross(n, up), dim=-1)  # tilts +Y toward -n (the target)
    angle = torch.as_tensor(np.radians(rng.choice(LEAN_TILTS, size=count)), dtype=torch.float32)
    tilt = torch.cat([torch.cos(angle / 2)[:, None], axis * torch.sin(angle / 2)[:, None]], dim=1)
    q = quaternion_product(tilt, _long_axis_up(pair, rng, count))
    local = pair.source_subset(LEAN_POINTS).cpu()
    rotated = torch.einsum("bij,nj->bni", quaternion_to_matrix(q), local) * math.exp(log_s)
    behind = (-(rotated * n[:, None, :]).sum(-1)).max(dim=1).values  # extent toward the target
    floor = pair.floor
    start = torch.as_tensor(points[side[pick]], dtype=torch.float32) + n * (behind + 1e-3 * pair.target_radius)[:, None]
    start[:, 1] = floor - rotated[..., 1].min(dim=1).values + 1e-3 * pair.target_radius
    return _lowered(pair, proposals, q, start, n, False, log_s, "lean")


def contained(pair: PreparedPair, proposals: Proposals, seed: int, reading: RelationReading | None,
              log_s: float, count: int) -> Proposals | None:
    """Sources standing in the target's most enclosed up-facing places (``extend``); None where no up-facing
    point is enclosed at all."""
    points, _, regions, density = surface_regions(pair)
    top = regions["top"]
    if not len(top):
        return None
    lift = predicates.FOOT * pair.source_diagonal * math.exp(log_s)  # the source's foot, as the predicate's
    ground = torch.as_tensor(points, dtype=torch.float32)
    feet = ground[torch.as_tensor(top)] + torch.tensor([0.0, lift, 0.0])
    spacing = pair.sample_spacing(len(points))
    held = torch.cat([predicates.enclosure(chunk, ground[None], spacing, lift)
                      for chunk in feet.split(ENCLOSURE_BATCH)]).numpy().astype(np.float64)
    weights = density[top] * held**4
    if weights.sum() <= 0:
        return None
    rng = np.random.default_rng(seed + 29)
    pick = top[rng.choice(len(top), size=count, p=weights / weights.sum())]
    upright = _long_axis_up(pair, rng, count // 2)
    resting = proposals.rotations[torch.as_tensor(rng.integers(len(proposals.rotations), size=count - len(upright)))]
    q = torch.cat([upright, resting.cpu()])
    up = torch.tensor([0.0, 1.0, 0.0]).expand(count, 3)
    return _lowered(pair, proposals, q, torch.as_tensor(points[pick], dtype=torch.float32), up, True, log_s,
                    "contained")


def hung(pair: PreparedPair, proposals: Proposals, seed: int, reading: RelationReading | None,
         log_s: float, count: int) -> Proposals | None:
    """Sources hung by a hook point on a thin up-facing part of the target (``extend``); None where the source has
    no hook point or no up-facing part of the target is thin enough to pass into one."""
    local, plumb, hooks, clearance = hook_points(pair)
    clearance = clearance * math.exp(log_s)
    points, _, top, thickness, density, spacing = peg_thickness(pair)
    fits = thickness < (clearance.max() if len(hooks) else 0.0)
    if not fits.any():
        return None
    rng = np.random.default_rng(seed + 31)
    weights = density[top] * fits
    pick = rng.choice(len(top), size=count, p=weights / weights.sum())
    hook = np.array([rng.choice(hooks[clearance > thickness[i]]) for i in pick])
    down = np.array([0.0, -1.0, 0.0])
    q = torch.cat([quaternion_product(_yaw(rng.uniform(0, 2 * math.pi)), _turn(plumb[h], down)[None]) for h in hook])
    hook_posed = torch.einsum("bij,bj->bi", quaternion_to_matrix(q), torch.as_tensor(local[hook], dtype=torch.float32))
    start = torch.as_tensor(points[top[pick]], dtype=torch.float32) - hook_posed * math.exp(log_s)
    start[:, 1] += spacing
    up = torch.tensor([0.0, 1.0, 0.0]).expand(count, 3)
    return _lowered(pair, proposals, q, start, up, False, log_s, "hang")


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
    standing = _long_axis_up(pair, rng, count)  # on its long axis, either end up, turned about it
    q = torch.cat([quaternion_product(_turn(up, d)[None], standing[i:i + 1]) for i, d in enumerate(inward)])
    local = pair.source_subset(LEAN_POINTS).cpu()
    rotated = torch.einsum("bij,nj->bni", quaternion_to_matrix(q), local) * math.exp(log_s)
    d = torch.as_tensor(inward, dtype=torch.float32)
    along = (rotated * d[:, None, :]).sum(-1)  # extent along the inward normal
    lead, length = along.max(1).values, along.max(1).values - along.min(1).values
    depth = torch.as_tensor(rng.uniform(*PIERCE_DEPTH, size=count), dtype=torch.float32) * length
    t = torch.as_tensor(points[pick], dtype=torch.float32) - d * (lead - depth)[:, None]
    # not through the floor the target stands on: raised to it where it would pass below (less deep from above)
    t[:, 1] += (pair.floor - (t[:, 1] + rotated[..., 1].min(1).values)).clamp_min(0.0)
    sites = _sites(torch.as_tensor(points[pick], dtype=torch.float32), -d, True)
    return _labelled(pair, proposals, Poses(t, q, torch.full((count,), log_s)), sites, "pierce")


def apart(pair: PreparedPair, proposals: Proposals, seed: int, reading: RelationReading,
          log_s: float, count: int) -> Proposals:
    """Sources where a reading without contact puts them (``extend``; the module docstring says where)."""
    position, turn = reading.position, reading.orientation
    kind = reading.records[0].kind
    rng = np.random.default_rng(seed + 41)
    scale = math.exp(log_s)
    target = pair.anchor.points.cpu()
    front, left = _target_axes(pair)
    if kind == "side":
        u = predicates.toward(position, front, left).expand(count, 3)
    else:
        angle = torch.as_tensor(rng.uniform(0, 2 * math.pi, count), dtype=torch.float32)
        u = torch.stack([angle.sin(), torch.zeros_like(angle), angle.cos()], -1)
    resting = proposals.rotations[torch.as_tensor(rng.integers(len(proposals.rotations), size=count))].cpu()
    if turn is None or kind == "vertical":
        heading = rng.uniform(0, 2 * math.pi, count)
    else:  # the source's front (azimuth about +Y, from +Z) to the wanted direction
        want = {"facing": -u, "facing_away": u, "aligned": front.expand(count, 3)}[turn]
        own = quaternion_to_matrix(resting) @ torch.as_tensor(pair.source_front, dtype=torch.float32)
        heading = (torch.atan2(want[:, 0], want[:, 2]) - torch.atan2(own[:, 0], own[:, 2])).numpy()
    q = torch.cat([quaternion_product(_yaw(float(a)), resting[i:i + 1]) for i, a in enumerate(heading)])
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
        gap = torch.as_tensor(rng.uniform(*APART_GAPS["side" if kind == "side" else position if kind == "distance"
                                                      else "near"], count), dtype=torch.float32)
        beside = target @ across.T  # (M, B): the target's extent across u
        lo, high = beside.min(0).values, beside.max(0).values
        level = lo + (high - lo) * torch.as_tensor(rng.uniform(0.25, 0.75, count) if kind == "side"
                                                   else np.full(count, 0.5), dtype=torch.float32)
        anchor = u * (reach + gap * (source_diagonal + 2 * pair.target_radius) / 2)[:, None] + across * level[:, None]
        anchor[:, 1] = pair.floor
    return _kept(pair, proposals, q, anchor, log_s, position)


def beneath(pair: PreparedPair, proposals: Proposals, seed: int, reading: RelationReading | None,
            log_s: float, count: int) -> Proposals | None:
    """Sources standing on the floor under a down-facing point of the target lifted high enough for them
    (``extend``; the module docstring says where); None where no point is."""
    points, _, regions, density = surface_regions(pair)
    under = regions["bottom"]
    rng = np.random.default_rng(seed + 43)
    scale = math.exp(log_s)
    resting = proposals.rotations[torch.as_tensor(rng.integers(len(proposals.rotations), size=count))].cpu()
    q = torch.cat([quaternion_product(_yaw(float(a)), resting[i:i + 1])
                   for i, a in enumerate(rng.uniform(0, 2 * math.pi, count))])
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
    weights = density[under][None, :] * fits[keep]
    pick = [under[rng.choice(len(under), p=w / w.sum())] for w in weights]
    anchor = torch.as_tensor(points[pick], dtype=torch.float32)
    anchor[:, 1] = pair.floor
    return _kept(pair, proposals, q[torch.as_tensor(keep)], anchor, log_s, "below")


def _kept(pair: PreparedPair, proposals: Proposals, q: torch.Tensor, anchor: torch.Tensor, log_s: float,
          label: str) -> Proposals:
    """Sources turned by ``q`` standing with their bottom's centre at ``anchor``, kept where they are put (the
    approach "none": those that meet the target are dropped), labelled ``label``."""
    count = len(anchor)
    up = torch.tensor([0.0, 1.0, 0.0]).expand(count, 3)
    sites = Site(anchor, up, torch.zeros(count), torch.ones(count, dtype=torch.bool),
                 torch.full((count,), APPROACHES.index("none"), dtype=torch.long))
    placed, free = place(pair, proposals.index, q, sites, log_s)
    return _labelled(pair, proposals, placed, sites.select(free), label)


Builder = Callable[[PreparedPair, Proposals, int, RelationReading, float, int], Proposals | None]
# each relation's own proposals (``extend``), by name as in ``priors.relations.RELATIONS``; a relation not named has
# none (the contact relations the regions reach). Every builder takes the reading; ``apart`` and ``lean`` read more
# of it than its position (the side, the orientation)
BUILDERS: dict[str, Builder] = {
    "lean": lean, "in": contained, "hang": hung, "penetrate": pierced, "below": beneath,
    **dict.fromkeys(("front", "behind", "left", "right", "above", "near", "far", "facing", "facing_away", "aligned"),
                    apart),
}


@per_pair
def hook_points(pair: PreparedPair) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The source's hook points (see the module docstring): its feature samples (source local frame), their plumb
    lines, the hook points' indices and their clearance (``_clearance``, source local units; only the finite
    ones: a loop or bend closes under them)."""
    feat = predicates.features(pair)
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
    ones' indices, the target's vertical thickness under each (``_thickness``), the samples' density weights and
    spacing."""
    points, normals, regions, density = surface_regions(pair)
    spacing = pair.sample_spacing(len(points))
    top = regions["top"]
    return points, normals, top, _thickness(points, top, regions["bottom"], spacing), density, spacing


def _clearance(local: np.ndarray, plumb: np.ndarray, hooks: np.ndarray, spacing: float) -> np.ndarray:
    """(H,) how far each hook point's plumb line (toward the source's centre) runs inside the source's loop
    before it meets the source again (another sample within ``spacing`` of the line, beyond it): how thick a
    part hung in the hook can be; inf where the line meets nothing (no loop or bend closes under it)."""
    rel = local[None, :, :] - local[hooks, None, :]  # (H, N, 3)
    along = (rel * plumb[hooks, None, :]).sum(-1)
    off = np.sqrt(np.clip((rel**2).sum(-1) - along**2, 0.0, None))
    on_line = (along > 2 * spacing) & (off <= spacing)
    return np.where(on_line, along, np.inf).min(1)


def _thickness(points: np.ndarray, top: np.ndarray, bottom: np.ndarray, spacing: float) -> np.ndarray:
    """(T,) the target's vertical thickness under each up-facing sample ``top``: down to the highest down-facing
    sample below it within ``spacing`` of its column (the part's underside); inf where there is none."""
    if not len(bottom):
        return np.full(len(top), np.inf)
    tree = cKDTree(points[bottom][:, [0, 2]])
    out = np.full(len(top), np.inf)
    for k, near in enumerate(tree.query_ball_point(points[top][:, [0, 2]], r=spacing, workers=1)):
        below = points[bottom[near], 1]
        below = below[below < points[top[k], 1]]
        if len(below):
            out[k] = points[top[k], 1] - below.max()
    return out


def _target_axes(pair: PreparedPair) -> tuple[torch.Tensor, torch.Tensor]:
    """(front, left), each (1, 3): the target's own horizontal axes, or the viewer's (``predicates.axes``)."""
    return predicates.axes(torch.as_tensor(pair.target_front, dtype=torch.float32)[None], pair.front_trusted)


def _turn(a: np.ndarray, b: np.ndarray) -> torch.Tensor:
    """(4,) the shortest rotation taking unit vector ``a`` onto unit vector ``b`` (half a turn about an axis
    across ``a`` when they are opposite)."""
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    v, c = np.cross(a, b), float(np.dot(a, b))
    if np.linalg.norm(v) < 1e-9:
        if c > 0:
            return torch.tensor([1.0, 0.0, 0.0, 0.0])
        across = np.cross(a, [0.0, 0.0, 1.0] if abs(a[2]) < 0.9 else [1.0, 0.0, 0.0])
        return torch.as_tensor(np.r_[0.0, across / np.linalg.norm(across)], dtype=torch.float32)
    angle = math.atan2(np.linalg.norm(v), c)
    return torch.as_tensor(np.r_[math.cos(angle / 2), v / np.linalg.norm(v) * math.sin(angle / 2)],
                           dtype=torch.float32)


def _yaw(angle: float) -> torch.Tensor:
    """(1, 4) a turn by ``angle`` about +Y."""
    return torch.tensor([[math.cos(angle / 2), 0.0, math.sin(angle / 2), 0.0]])


def _lowered(pair: PreparedPair, proposals: Proposals, q: torch.Tensor, anchor: torch.Tensor, normal: torch.Tensor,
             on_surface: bool, log_s: float, label: str) -> Proposals:
    """Sources turned by ``q`` moved straight along -``normal`` from ``anchor`` into contact (``contact.place``),
    those that end free of the target, labelled ``label``."""
    sites = _sites(anchor, normal, on_surface)
    placed, free = place(pair, proposals.index, q, sites, log_s)
    return _labelled(pair, proposals, placed, sites.select(free), label)


def _sites(anchor: torch.Tensor, normal: torch.Tensor, on_surface: bool) -> Site:
    """Sites at ``anchor`` approached straight along -``normal``, no gap kept."""
    count = len(anchor)
    return Site(anchor, normal, torch.zeros(count), torch.full((count,), on_surface, dtype=torch.bool),
                torch.full((count,), APPROACHES.index("straight"), dtype=torch.long))


def _labelled(pair: PreparedPair, proposals: Proposals, poses: Poses, sites: Site, label: str) -> Proposals:
    """``poses`` at ``sites`` as proposals labelled ``label`` on the pair's device, sharing ``proposals``'
    orientations and contact samples."""
    device = pair.source_vertices.device
    return Proposals(Poses(poses.t.to(device), poses.q.to(device), poses.log_s.to(device)), [label] * len(poses),
                     sites, proposals.rotations, proposals.index)


def _long_axis_up(pair: PreparedPair, rng: np.random.Generator, count: int) -> torch.Tensor:
    """(count, 4) orientations with the source's longest principal axis along +Y (either way up), each turned
    about +Y at random: a stick, a board or a ladder stands on its end before it is tilted against a side."""
    local = pair.source_subset(LEAN_POINTS).cpu().double().numpy()
    _, _, vt = np.linalg.svd(local - local.mean(0), full_matrices=False)
    axis = vt[0] / np.linalg.norm(vt[0])
    up = np.array([0.0, 1.0, 0.0])
    turns = [quaternion_product(_yaw(rng.uniform(0, 2 * math.pi)), _turn(axis if i % 2 == 0 else -axis, up)[None])
             for i in range(count)]
    return torch.cat(turns) if turns else torch.zeros(0, 4)
