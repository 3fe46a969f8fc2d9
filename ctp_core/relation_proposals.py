"""Proposals that satisfy the prompt's relation by construction where the search's regions do not reach it.

``proposals.propose`` draws from regions (top, side, bottom, cavity, gaps, drops, floor) with the source in its
own resting frames; some relations need a pose none of them makes. Measured on the dev cases (the proposals
where ``predicates.relation_score`` holds, docs/benchmarks.md "Relation predicates"): "lean" had none of 142
(cur-s04: a stick leaning against a box): every proposal either stands upright beside the box or lies on it.

``lean``: the source standing on its longest principal axis (either end up, any turn about +Y), tilted by
``LEAN_TILTS`` about the horizontal axis along a side of the target, so its top tips toward the target; its
lowest point on the floor the target stands on, just outside a side sample (the "side" region's samples,
their outward normal made horizontal), then moved straight toward the target until it touches
(``proposals.settle``'s "straight" approach). Added only where the relation is "lean" with the source as the
figure and ``config.relation`` is on: ``extend`` returns the proposals unchanged otherwise.

``in``: the source standing in the target's most enclosed up-facing places (the floors of its cavities: the
share of horizontal directions around a point that meet the target, ``predicates.enclosure``, weighting the
draw), half on its longest principal axis (a candle in a holder's cup, a pencil in a mug), half in its own
resting frames (a hot dog in its bun), lowered onto the point. The regions' cavity proposals centre the source
on a point inside the target's hull: a candle standing in a shallow cup on top of a tall holder has its centre
above the rim (pb3d-candle_stick: 1 of the 111 proposals held "in" where the reference stands).

Not done (docs/relations.md lists them): "hang" (a ring threaded on a thin part), "under" (the floor under a
down-facing part), "beside" (the floor just outside the footprint): the regions already give some poses where
those hold on the dev cases.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ctp_core import predicates
from ctp_core.config import AlignConfig
from ctp_core.objective import sample_spacing
from ctp_core.pose import Poses, quaternion_product, quaternion_to_matrix
from ctp_core.proposals import APPROACHES, Proposals, Site, place, surface_regions
from ctp_core.scene import PreparedPair

LEAN_TILTS = (15.0, 30.0, 45.0)  # degrees from the source's frame toward the target
LEAN_SHARE = 0.25  # lean proposals, as a share of ``search.candidates``
LEAN_POINTS = 128  # source samples for the tilted source's extent
CONTAINED_SHARE = 0.25  # "in" proposals, as a share of ``search.candidates``
ENCLOSURE_BATCH = 64  # up-facing points whose enclosure is measured at once (memory: batch x samples x rays)


def extend(pair: PreparedPair, config: AlignConfig, proposals: Proposals, relation: str | None,
           source_is_figure: bool, seed: int) -> Proposals:
    """``proposals`` plus those that satisfy ``relation`` by construction (see the module docstring)."""
    build = {"lean": lean, "in": contained}.get(relation or "")
    if not config.relation or not source_is_figure or build is None or proposals.rotations is None:
        return proposals
    extra = build(pair, config, proposals, seed)
    if extra is None or not len(extra.poses):
        return proposals
    sites = Site(*(torch.cat([a, b]) for a, b in zip(vars(proposals.sites).values(), vars(extra.sites).values(),
                                                     strict=True)))
    return Proposals(Poses.cat([proposals.poses, extra.poses]), proposals.region + extra.region, sites,
                     proposals.rotations, proposals.index)


def lean(pair: PreparedPair, config: AlignConfig, proposals: Proposals, seed: int) -> Proposals | None:
    """Tilted sources standing on the floor against the target's sides (``extend``); None without side samples."""
    points, normals, regions, _ = surface_regions(pair)
    side = regions["side"]
    horizontal = normals[side] * np.array([1.0, 0.0, 1.0])
    length = np.linalg.norm(horizontal, axis=1)
    side, horizontal = side[length > 0.5], horizontal[length > 0.5] / length[length > 0.5, None]
    if not len(side):
        return None
    rng = np.random.default_rng(seed + 23)
    count = max(1, math.ceil(LEAN_SHARE * config.search.candidates))
    pick = rng.integers(len(side), size=count)
    n = torch.as_tensor(horizontal[pick], dtype=torch.float32)
    up = torch.tensor([0.0, 1.0, 0.0]).expand(count, 3)
    axis = torch.nn.functional.normalize(torch.linalg.cross(n, up), dim=-1)  # tilts +Y toward -n (the target)
    angle = torch.as_tensor(np.radians(rng.choice(LEAN_TILTS, size=count)), dtype=torch.float32)
    tilt = torch.cat([torch.cos(angle / 2)[:, None], axis * torch.sin(angle / 2)[:, None]], dim=1)
    q = quaternion_product(tilt, _long_axis_up(pair, rng, count))
    log_s = float(proposals.poses.log_s[0])
    local = pair.source_subset(LEAN_POINTS).cpu()
    rotated = torch.einsum("bij,nj->bni", quaternion_to_matrix(q), local) * math.exp(log_s)
    behind = (-(rotated * n[:, None, :]).sum(-1)).max(dim=1).values  # extent toward the target
    floor = float(pair.target_vertices[:, 1].min())
    start = torch.as_tensor(points[side[pick]], dtype=torch.float32) + n * (behind + 1e-3 * pair.target_radius)[:, None]
    start[:, 1] = floor - rotated[..., 1].min(dim=1).values + 1e-3 * pair.target_radius
    return _lowered(pair, proposals, q, start, n, False, log_s, "lean")


def contained(pair: PreparedPair, config: AlignConfig, proposals: Proposals, seed: int) -> Proposals | None:
    """Sources standing in the target's most enclosed up-facing places (``extend``); None where no up-facing
    point is enclosed at all."""
    points, _, regions, density = surface_regions(pair)
    top = regions["top"]
    if not len(top):
        return None
    log_s = float(proposals.poses.log_s[0])
    lift = predicates.FOOT * 2 * pair.source_radius * math.exp(log_s)  # the source's foot, as the predicate's
    ground = torch.as_tensor(points, dtype=torch.float32)
    feet = ground[torch.as_tensor(top)] + torch.tensor([0.0, lift, 0.0])
    spacing = sample_spacing(pair, len(points))
    held = torch.cat([predicates.enclosure(chunk, ground[None], spacing, lift)
                      for chunk in feet.split(ENCLOSURE_BATCH)]).numpy().astype(np.float64)
    weights = density[top] * held**4
    if weights.sum() <= 0:
        return None
    rng = np.random.default_rng(seed + 29)
    count = max(1, math.ceil(CONTAINED_SHARE * config.search.candidates))
    pick = top[rng.choice(len(top), size=count, p=weights / weights.sum())]
    upright = _long_axis_up(pair, rng, count // 2)
    resting = proposals.rotations[torch.as_tensor(rng.integers(len(proposals.rotations), size=count - len(upright)))]
    q = torch.cat([upright, resting.cpu()])
    up = torch.tensor([0.0, 1.0, 0.0]).expand(count, 3)
    return _lowered(pair, proposals, q, torch.as_tensor(points[pick], dtype=torch.float32), up, True, log_s,
                    "contained")


def _lowered(pair: PreparedPair, proposals: Proposals, q: torch.Tensor, anchor: torch.Tensor, normal: torch.Tensor,
             on_surface: bool, log_s: float, label: str) -> Proposals:
    """Sources turned by ``q`` moved straight along -``normal`` from ``anchor`` into contact (``proposals.place``),
    those that end free of the target, labelled ``label``."""
    count = len(q)
    sites = Site(anchor, normal, torch.zeros(count), torch.full((count,), on_surface, dtype=torch.bool),
                 torch.full((count,), APPROACHES.index("straight"), dtype=torch.long))
    placed, free = place(pair, proposals.index, q, sites, log_s)
    device = pair.source_vertices.device
    return Proposals(Poses(placed.t.to(device), placed.q.to(device), placed.log_s.to(device)),
                     [label] * len(placed), sites.select(free), proposals.rotations, proposals.index)


def _long_axis_up(pair: PreparedPair, rng: np.random.Generator, count: int) -> torch.Tensor:
    """(count, 4) orientations with the source's longest principal axis along +Y (either way up), each turned
    about +Y at random: a stick, a board or a ladder stands on its end before it is tilted against a side."""
    local = pair.source_subset(LEAN_POINTS).cpu().double().numpy()
    _, _, vt = np.linalg.svd(local - local.mean(0), full_matrices=False)
    axis = vt[0] / np.linalg.norm(vt[0])
    up = np.array([0.0, 1.0, 0.0])
    out = []
    for i in range(count):
        a = axis if i % 2 == 0 else -axis
        v, c = np.cross(a, up), float(np.dot(a, up))
        if np.linalg.norm(v) < 1e-9:  # already along +Y (or -Y: half a turn about X)
            q_up = np.array([1.0, 0.0, 0.0, 0.0]) if c > 0 else np.array([0.0, 1.0, 0.0, 0.0])
        else:
            angle = math.atan2(np.linalg.norm(v), c)
            q_up = np.r_[math.cos(angle / 2), v / np.linalg.norm(v) * math.sin(angle / 2)]
        yaw = rng.uniform(0, 2 * math.pi)
        out.append(np.array([math.cos(yaw / 2), 0.0, math.sin(yaw / 2), 0.0]))
        out[-1] = quaternion_product(torch.as_tensor(out[-1], dtype=torch.float32)[None],
                                     torch.as_tensor(q_up, dtype=torch.float32)[None])[0]
    return torch.stack(out) if out else torch.zeros(0, 4)
