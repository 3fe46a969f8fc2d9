"""Losses on cases whose answer is known analytically."""

import numpy as np
import pytest
import torch

from ctp_core import losses


def _plane(n: int = 21, z: float = 0.0) -> losses.SurfaceIndex:
    """A grid of target samples on the plane z = const with outward normal +z."""
    g = torch.linspace(-1, 1, n)
    xx, yy = torch.meshgrid(g, g, indexing="ij")
    pts = torch.stack([xx.flatten(), yy.flatten(), torch.full((n * n,), z)], dim=1)
    nrm = torch.zeros_like(pts)
    nrm[:, 2] = 1
    return losses.SurfaceIndex(pts, nrm)


def _dense_soft_icp(src: torch.Tensor, tgt: torch.Tensor, ratio: float, sigma: float) -> torch.Tensor:
    """The method.md formula with the full N_S x N_T matrix (independent of the k-NN implementation)."""
    out = []
    for b in range(src.shape[0]):
        e = torch.cdist(src[b], tgt) ** 2
        d = e.min(dim=1).values
        keep = max(1, int(np.floor(ratio * src.shape[1])))
        w = torch.argsort(d)[:keep]
        alpha = torch.softmax(-e[w] / (2 * sigma**2), dim=1)
        out.append((alpha * e[w]).sum(1).mean())
    return torch.stack(out)


def test_soft_icp_single_target_point_is_squared_distance():
    index = losses.SurfaceIndex(torch.zeros(1, 3), torch.tensor([[0.0, 0.0, 1.0]]))
    src = torch.tensor([[[0.3, 0.0, 0.0], [0.0, 0.4, 0.0]]])
    value = losses.soft_icp(src, index, ratio=1.0, sigma=0.1, k=8)
    assert value.item() == pytest.approx((0.09 + 0.16) / 2, rel=1e-5)


def test_soft_icp_ratio_keeps_only_the_closest_fraction():
    index = losses.SurfaceIndex(torch.zeros(1, 3), torch.tensor([[0.0, 0.0, 1.0]]))
    src = torch.tensor([[[0.1, 0, 0], [0.2, 0, 0], [0.3, 0, 0], [0.4, 0, 0]]])
    half = losses.soft_icp(src, index, ratio=0.5, sigma=0.1, k=1)
    assert half.item() == pytest.approx((0.01 + 0.04) / 2, rel=1e-5)


@pytest.mark.parametrize("ratio", [1.0, 0.3])
def test_soft_icp_equals_dense_formula_when_k_covers_all_targets(ratio):
    gen = torch.Generator().manual_seed(0)
    tgt = torch.randn(40, 3, generator=gen)
    src = torch.randn(3, 25, 3, generator=gen) * 0.7 + 0.2
    index = losses.SurfaceIndex(tgt, torch.nn.functional.normalize(torch.randn(40, 3, generator=gen), dim=1))
    knn = losses.soft_icp(src, index, ratio=ratio, sigma=0.3, k=40)
    dense = _dense_soft_icp(src, tgt, ratio, 0.3)
    torch.testing.assert_close(knn, dense, rtol=1e-5, atol=1e-6)


def test_soft_icp_gradient_pulls_toward_target():
    index = _plane()
    src = torch.tensor([[[0.0, 0.0, 0.5]]], requires_grad=True)
    losses.soft_icp(src, index, ratio=1.0, sigma=0.1, k=16).sum().backward()
    assert src.grad[0, 0, 2] > 0  # descending moves the point down to the plane


def test_penetration_depth_and_margin():
    index = _plane()
    inside = torch.tensor([[[0.0, 0.0, -0.1], [0.3, 0.2, -0.1]]])
    outside = torch.tensor([[[0.0, 0.0, 0.2], [0.1, 0.1, 0.05]]])
    depth = losses.penetration(inside, index, sigma=0.05, margin=0.0, k=16)
    assert depth.item() == pytest.approx(0.1, abs=1e-4)
    with_margin = losses.penetration(inside, index, sigma=0.05, margin=0.04, k=16)
    assert with_margin.item() == pytest.approx(0.06, abs=1e-4)
    assert losses.penetration(outside, index, sigma=0.05, margin=0.0, k=16).item() == 0.0


def test_penetration_gradient_pushes_out():
    index = _plane()
    src = torch.tensor([[[0.0, 0.0, -0.2]]], requires_grad=True)
    losses.penetration(src, index, sigma=0.05, margin=0.0, k=16).sum().backward()
    assert src.grad[0, 0, 2] < 0  # descending raises the point out of the target


def test_clip_loss_fixed_and_per_view_goals():
    emb = torch.nn.functional.normalize(torch.randn(2, 3, 8), dim=-1)
    assert torch.allclose(losses.clip_view_loss(emb, emb), torch.full((2, 3), -1.0), atol=1e-6)
    text = torch.nn.functional.normalize(torch.randn(8), dim=0)
    torch.testing.assert_close(losses.clip_view_loss(emb, text), -(emb @ text))


def _wall_pair():
    """A thin wall (2 x 2 x 0.02, its faces at z = +-0.01) and a ball of radius 0.3, prepared as a run prepares."""
    import trimesh

    from ctp_core.config import AlignConfig
    from ctp_core.config.schedule import phases
    from ctp_core.objective import Scorer
    from ctp_core.pairs import prepare_pair

    wall = trimesh.creation.box(extents=(2.0, 2.0, 0.02))
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    pair = prepare_pair(wall, ball, samples=3000, seed=0, canonicalise=False)
    config = AlignConfig.from_preset("descent", penetration="forbid", loss={"lambda_clip": 0.0})
    return pair, Scorer(pair, config, contact_ratio=0.3), phases(config, allow_penetration=False)[-1]


def _ball_at(pair, z: float):
    from ctp_core.geometry.pose import Poses

    radius = 0.3 * pair.target_to_normalised.scale  # the ball's radius in the normalised frame
    return Poses(torch.tensor([[0.0, 0.0, z * radius]]), torch.tensor([[1.0, 0.0, 0.0, 0.0]]), torch.zeros(1))


def test_a_ball_through_a_thin_wall_is_charged_by_the_wall_samples_inside_it():
    """Through the wall's middle almost every ball sample lies outside the 0.02-thick wall, so the source-side
    half alone barely sees it; the wall samples inside the ball do. Resting on the wall costs (almost) nothing."""
    pair, scorer, phase = _wall_pair()
    cfg = scorer.config.loss
    through, resting = _ball_at(pair, 0.0), _ball_at(pair, 1.0 + 0.01 / 0.3)
    from ctp_core.geometry.pose import apply_pose

    def source_half(poses):
        pts = apply_pose(pair.source_samples, poses.t, poses.q, poses.log_s)
        return float(losses.penetration(pts, pair.index, cfg.sigma_pen, cfg.c_pen, cfg.icp_neighbours)[0])

    diag = 2 * pair.source_radius  # the ball's AABB diagonal, 2 sqrt(3) r
    assert source_half(through) / diag < 0.005  # the blind spot this half has
    # exactly: the disc's two faces, depth r - rho, over the ball's area: r / 6, i.e. 0.048 AABB diagonals
    assert float(scorer.enclosed(through)[0]) / diag == pytest.approx(1 / (12 * 3**0.5), rel=0.15)
    assert float(scorer.geometry(through, phase).sunk[0]) > 0.04
    assert float(scorer.geometry(resting, phase).sunk[0]) < 0.001


def test_the_enclosed_half_pushes_a_ball_out_of_a_wall():
    """Its gradient moves a ball sunk a third of its radius into the wall's top face back up (+z)."""
    pair, scorer, _ = _wall_pair()
    poses = _ball_at(pair, 0.7)
    t = poses.t.clone().requires_grad_(True)
    from ctp_core.geometry.pose import Poses

    scorer.enclosed(Poses(t, poses.q, poses.log_s)).sum().backward()
    assert t.grad[0, 2] < 0 and abs(float(t.grad[0, 2])) > 10 * float(t.grad[0, :2].abs().max())


def test_holding_excludes_a_pose_that_intersects():
    """The relation's tier (``ordering.holding``): a pose where the relation holds but that is sunk into the
    target past ``SUNK`` ranks with the poses where it fails."""
    from ctp_core.objective import Terms
    from ctp_core.search.ordering import SUNK, holding

    terms = Terms.zeros(3).but(rel=torch.tensor([0.0, 0.0, 0.5]), sunk=torch.tensor([0.0, 2 * SUNK, 0.0]))
    assert holding(terms).tolist() == [True, False, False]


def test_the_enclosed_half_looks_up_only_the_samples_that_count_with_the_same_sum_and_gradient():
    """Every sample's depth through the dense formula, then masked, against ``enclosed_penetration``'s lookup of
    the counted samples alone: equal bit for bit, value and gradient (a pose with none counted included)."""
    g = torch.Generator().manual_seed(0)
    normals = torch.nn.functional.normalize(torch.randn(500, 3, generator=g), dim=-1)
    source = losses.SurfaceIndex(torch.randn(500, 3, generator=g), normals)
    points = torch.randn(6, 64, 3, generator=g)
    inside = (torch.rand(6, 64, generator=g) < 0.3).float()
    inside[2] = 0
    scale, area_ratio = torch.rand(6, generator=g) + 0.5, torch.rand(6, generator=g)
    dense_points, points = points.clone().requires_grad_(True), points.clone().requires_grad_(True)
    depth = losses.signed_depth(dense_points, source, (0.3 / scale).reshape(-1, 1, 1), 32) * scale[:, None]
    dense = (torch.relu(depth - 0.01) * inside).sum(1) * area_ratio
    looked_up = losses.enclosed_penetration(points, inside, source, scale, area_ratio, 0.3, 0.01, 32)
    assert torch.equal(dense, looked_up) and float(dense[2].detach()) == 0 and float(dense.detach().sum()) > 0
    dense.sum().backward()
    looked_up.sum().backward()
    assert torch.equal(dense_points.grad, points.grad)


def _three_objects(shift: float = 0.0) -> tuple[losses.SurfaceIndex, losses.SurfaceIndex, list[np.ndarray]]:
    """Every object's samples (three clusters: a ground and two others) and the ground's alone; its rows and the
    others'."""
    gen = torch.Generator().manual_seed(3)
    parts = [torch.randn(300, 3, generator=gen) * 0.2 + torch.tensor(c) for c in ([0.0, 0, 0], [1.5, 0, 0], [0, 0, 2])]
    normals = torch.nn.functional.normalize(torch.randn(900, 3, generator=gen), dim=1)
    whole = losses.SurfaceIndex(torch.cat(parts), normals)
    ground = losses.SurfaceIndex(parts[0] + shift, normals[:300])
    return whole, ground, [np.arange(0, 300), np.arange(300, 600), np.arange(600, 900)]


def test_a_ground_answers_for_every_object_where_no_other_is_nearer():
    """``neighbours_of``: the ground's search answers the penetration term's question of every object's samples
    where no other object's box is as near as its k-th sample; the whole is searched for the rest only, and both
    answers are those of a search of each, index for index."""
    whole, ground, rows = _three_objects()
    assert ground.part_of(whole, rows[0], rows[1:])
    gen = torch.Generator().manual_seed(4)
    # half around the ground (a source placed on it), half anywhere around all three
    queries = torch.cat([torch.randn(5, 200, 3, generator=gen) * 0.3, torch.rand(5, 200, 3, generator=gen) * 4 - 1], 1)
    asked: list[int] = []
    search = whole.nearest
    whole.nearest = lambda flat, k: (asked.append(len(flat)), search(flat, k))[1]  # type: ignore[method-assign]
    near, idx = losses.neighbours_of(ground, whole, queries, 32)
    whole.nearest = search  # type: ignore[method-assign]
    assert torch.equal(near, ground.neighbours(queries, 32))
    assert torch.equal(idx, whole.neighbours(queries, 32))
    assert len(asked) == 1 and 0 < asked[0] < 2000  # the whole asked only for the points near the other objects


def test_samples_that_are_not_the_wholes_rows_are_no_part_of_it():
    """A ground whose samples differ from the whole's rows (here by 1 mm) is not marked: both are searched."""
    whole, ground, rows = _three_objects(shift=1e-3)
    assert not ground.part_of(whole, rows[0], rows[1:])
    queries = torch.rand(2, 100, 3, generator=torch.Generator().manual_seed(5)) * 4 - 1
    near, idx = losses.neighbours_of(ground, whole, queries, 16)
    assert torch.equal(near, ground.neighbours(queries, 16)) and torch.equal(idx, whole.neighbours(queries, 16))

