"""``measures.hull_distance_2d`` (one batch over poses) against a plain per-pose reference built here on
scipy's ConvexHull: the same distances, the same gradients, on random footprints with masks, lines and empty
ones."""

import numpy as np
import pytest
import torch
from scipy.spatial import ConvexHull, QhullError

from ctp_core.relations.measures import FAR, hull_distance_2d


def reference(query: torch.Tensor, points: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
    """Each pose alone: the largest signed distance past the hull's edge lines (normals away from the mean)."""
    out = []
    for i in range(len(query)):
        pts = points[i if len(points) > 1 else 0]
        if mask is not None:
            pts = pts[mask[i if len(mask) > 1 else 0]]
        if len(pts) == 0:
            out.append(torch.tensor(FAR * 1e3))
            continue
        try:
            simplices = ConvexHull(pts.detach().double().numpy()).simplices if len(pts) >= 3 else None
        except QhullError:
            simplices = None
        if simplices is None:
            out.append((pts - query[i]).norm(dim=-1).min())
            continue
        a, c = pts[simplices[:, 0]], pts[simplices[:, 1]]
        normal = torch.stack([(c - a)[:, 1], -(c - a)[:, 0]], -1)
        normal = normal / normal.norm(dim=-1, keepdim=True)
        normal = normal * torch.sign(((a - pts.mean(0)) * normal).sum(-1)).detach()[:, None]
        out.append(((query[i] - a) * normal).sum(-1).max())
    return torch.stack(out)


@pytest.mark.parametrize("shared", [False, True])
def test_batched_hull_distance_matches_each_pose_alone(shared: bool) -> None:
    generator = torch.Generator().manual_seed(3)
    batch, count = 9, 40
    points = torch.rand(1 if shared else batch, count, 2, generator=generator) * 2 - 1
    mask = None if shared else torch.rand(batch, count, generator=generator) > 0.4
    if mask is not None:
        points[0, :, 1] = 0.5 * points[0, :, 0]  # the first footprint a line: no 2-D hull
        mask[1] = False  # nothing kept: no support at all
        mask[2, 3:] = False  # a few points
    query = (torch.rand(batch, 2, generator=generator) * 3 - 1.5).requires_grad_(True)
    points.requires_grad_(True)
    got = hull_distance_2d(query, points, mask)
    want = reference(query, points, mask)
    torch.testing.assert_close(got, want, rtol=1e-6, atol=1e-6)
    if not shared:
        assert float(got[1].detach()) == pytest.approx(FAR * 1e3)
    inside = got < 0
    assert inside.any() and (~inside).any()  # queries on both sides of their hulls
    grads = torch.autograd.grad(got.sum(), (query, points))
    expected = torch.autograd.grad(want.sum(), (query, points))
    for g, e in zip(grads, expected, strict=True):
        torch.testing.assert_close(g, e, rtol=1e-5, atol=1e-6)


def test_one_mask_row_serves_every_pose() -> None:
    generator = torch.Generator().manual_seed(5)
    points = torch.rand(4, 30, 2, generator=generator)
    mask = torch.rand(1, 30, generator=generator) > 0.3
    query = torch.rand(4, 2, generator=generator)
    torch.testing.assert_close(hull_distance_2d(query, points, mask), reference(query, points, mask))
    assert np.isfinite(hull_distance_2d(query, points, mask).numpy()).all()
