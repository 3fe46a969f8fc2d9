"""What the relations' builders share: sources stood, lowered or kept where they are put, as proposals
labelled with their relation (normalised frame; poses map the source local frame to it).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ctp_core.contact import APPROACHES, Proposals, Site, place
from ctp_core.geometry.pose import Poses, quaternion_product
from ctp_core.pairs import PreparedPair
from ctp_core.relations.measures import axes

LEAN_POINTS = 128  # source samples for the tilted source's extent


def kept_where_put(pair: PreparedPair, proposals: Proposals, q: torch.Tensor, anchor: torch.Tensor, log_s: float,
          label: str) -> Proposals:
    """Sources turned by ``q`` standing with their bottom's centre at ``anchor``, kept where they are put (the
    approach "none": those that meet the target are dropped), labelled ``label``."""
    count = len(anchor)
    up = torch.tensor([0.0, 1.0, 0.0]).expand(count, 3)
    sites = Site(anchor, up, torch.zeros(count), torch.ones(count, dtype=torch.bool),
                 torch.full((count,), APPROACHES.index("none"), dtype=torch.long))
    placed, free = place(pair, proposals.index, q, sites, log_s)
    return labelled(pair, proposals, placed, sites.select(free), label)


def target_axes(pair: PreparedPair) -> tuple[torch.Tensor, torch.Tensor]:
    """(front, left), each (1, 3): the target's own horizontal axes, or the viewer's (``axes``)."""
    return axes(torch.as_tensor(pair.target_front, dtype=torch.float32)[None], pair.front_trusted)


def quaternion_onto(a: np.ndarray, b: np.ndarray) -> torch.Tensor:
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


def yaw_turn(angle: float) -> torch.Tensor:
    """(1, 4) a turn by ``angle`` about +Y."""
    return torch.tensor([[math.cos(angle / 2), 0.0, math.sin(angle / 2), 0.0]])


def random_resting(proposals: Proposals, rng: np.random.Generator, count: int) -> torch.Tensor:
    """(count, 4) the source's own orientations (``proposals.rotations``: upright, flipped, resting) drawn at
    random, on the CPU."""
    return proposals.rotations[torch.as_tensor(rng.integers(len(proposals.rotations), size=count))].cpu()


def yawed(q: torch.Tensor, angles) -> torch.Tensor:
    """(B, 4) each orientation of ``q`` (B, 4) turned about +Y by its angle of ``angles`` (B radians)."""
    return torch.cat([quaternion_product(yaw_turn(float(a)), q[i:i + 1]) for i, a in enumerate(angles)])


def lowered(pair: PreparedPair, proposals: Proposals, q: torch.Tensor, anchor: torch.Tensor, normal: torch.Tensor,
             on_surface: bool, log_s: float, label: str) -> Proposals:
    """Sources turned by ``q`` moved straight along -``normal`` from ``anchor`` into contact (``contact.place``),
    those that end free of the target, labelled ``label``."""
    sites = straight_sites(anchor, normal, on_surface)
    placed, free = place(pair, proposals.index, q, sites, log_s)
    return labelled(pair, proposals, placed, sites.select(free), label)


def straight_sites(anchor: torch.Tensor, normal: torch.Tensor, on_surface: bool) -> Site:
    """Sites at ``anchor`` approached straight along -``normal``, no gap kept."""
    count = len(anchor)
    return Site(anchor, normal, torch.zeros(count), torch.full((count,), on_surface, dtype=torch.bool),
                torch.full((count,), APPROACHES.index("straight"), dtype=torch.long))


def labelled(pair: PreparedPair, proposals: Proposals, poses: Poses, sites: Site, label: str) -> Proposals:
    """``poses`` at ``sites`` as proposals labelled ``label`` on the pair's device, sharing ``proposals``'
    orientations and contact samples."""
    device = pair.source_vertices.device
    return Proposals(Poses(poses.t.to(device), poses.q.to(device), poses.log_s.to(device)), [label] * len(poses),
                     sites, proposals.rotations, proposals.index)


def long_axis_up(pair: PreparedPair, rng: np.random.Generator, count: int) -> torch.Tensor:
    """(count, 4) orientations with the source's longest principal axis along +Y (either way up), each turned
    about +Y at random: a stick, a board or a ladder stands on its end before it is tilted against a side."""
    local = pair.source_subset(LEAN_POINTS).cpu().double().numpy()
    _, _, vt = np.linalg.svd(local - local.mean(0), full_matrices=False)
    axis = vt[0] / np.linalg.norm(vt[0])
    up = np.array([0.0, 1.0, 0.0])
    turns = [quaternion_product(yaw_turn(rng.uniform(0, 2 * math.pi)),
                                quaternion_onto(axis if i % 2 == 0 else -axis, up)[None]) for i in range(count)]
    return torch.cat(turns) if turns else torch.zeros(0, 4)


