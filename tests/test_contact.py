"""Settling's bounded nearest-sample search (``contact.nearest_two``) answers as one unbounded search does wherever
settling reads it: each pose's nearest distance and that point's nearest sample, and every point inside the target's
box, on poses near, inside, straddling the box and far away."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from ctp_core import contact
from ctp_core.geometry import sampling
from ctp_core.losses import SurfaceIndex


def _index(mesh: trimesh.Trimesh) -> SurfaceIndex:
    points, normals = sampling.surface_samples(mesh, 3000, 0)
    return SurfaceIndex(torch.as_tensor(points, dtype=torch.float32), torch.as_tensor(normals, dtype=torch.float32))


def _poses(rng: np.random.Generator, count: int, per: int) -> torch.Tensor:
    """(count, per, 3) clouds of ``per`` points a source's size (0.6) wide, at distances from the target's middle
    spread over four decades (inside it, at its surface, beside it, a hundred radii away)."""
    centres = rng.normal(size=(count, 3))
    centres *= (10.0 ** rng.uniform(-1.5, 2.0, size=count) / np.linalg.norm(centres, axis=1))[:, None]
    cloud = rng.uniform(-0.3, 0.3, size=(count, per, 3))
    return torch.as_tensor(centres[:, None, :] + cloud, dtype=torch.float32)


@pytest.mark.parametrize("mesh", [
    trimesh.creation.box([2.0, 0.1, 0.3]),  # a rail: long and thin, far points abound
    trimesh.creation.torus(major_radius=0.8, minor_radius=0.2),  # a ring: a box with a hole in the middle
], ids=["rail", "ring"])
def test_the_bounded_search_answers_as_the_unbounded_one_wherever_it_is_read(mesh):
    index = _index(mesh)
    posed = _poses(np.random.default_rng(0), 400, 64)
    low, high = index.points.min(0).values - 0.05, index.points.max(0).values + 0.05
    within = ((posed >= low) & (posed <= high)).all(-1)
    dist, idx = contact.nearest_two(index, posed, within, near=0.25)

    full, which = index.tree.query(posed.reshape(-1, 3).numpy().astype(np.float64), k=2)
    full = torch.as_tensor(full[:, 0].reshape(posed.shape[:2]), dtype=posed.dtype)
    which = torch.as_tensor(which.reshape(*posed.shape[:2], 2))
    gap, nearest = dist.min(1)
    true_gap, true_nearest = full.min(1)
    rows = torch.arange(len(posed))
    assert torch.equal(gap, true_gap)
    assert torch.equal(idx[rows, nearest, 0], which[rows, true_nearest, 0])
    assert torch.equal(dist[within], full[within]) and torch.equal(idx[within], which[within])
    # the far poses are what the bound is for: some of them are far, and none was left without a nearest point
    assert (true_gap > 10).any() and torch.isfinite(gap).all()
