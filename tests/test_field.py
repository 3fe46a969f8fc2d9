"""The distance field (``geometry.field``) against a brute-force nearest-sample search (``torch.cdist``, no KD-tree)."""

import math

import numpy as np
import pytest
import torch

from ctp_core import losses
from ctp_core.geometry import field as fields


def _sphere(count: int = 2000, radius: float = 1.0) -> losses.SurfaceIndex:
    """Evenly spread samples on a sphere (a Fibonacci lattice) with outward normals."""
    i = np.arange(count) + 0.5
    polar, turn = np.arccos(1 - 2 * i / count), np.pi * (1 + 5**0.5) * i
    unit = np.stack([np.cos(turn) * np.sin(polar), np.sin(turn) * np.sin(polar), np.cos(polar)], 1)
    return losses.SurfaceIndex(torch.as_tensor(unit * radius, dtype=torch.float32),
                               torch.as_tensor(unit, dtype=torch.float32))


def _brute(index: losses.SurfaceIndex, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(distance, depth) to the nearest sample by a full distance matrix: along its normal, positive behind."""
    dist, nearest = torch.cdist(points, index.points).min(dim=1)
    depth = ((index.points[nearest] - points) * index.normals[nearest]).sum(-1)
    return dist, depth


def _cell(field: fields.DistanceField) -> float:
    return field.size / (fields.FINE - 1)


def test_distance_near_the_surface_is_the_nearest_samples_within_a_fine_cell():
    index = _sphere()
    gen = torch.Generator().manual_seed(0)
    direction = torch.nn.functional.normalize(torch.randn(3000, 3, generator=gen), dim=1)
    points = direction * (1 + 0.1 * (torch.rand(3000, 1, generator=gen) - 0.5))  # within 0.05 of the surface
    distance, depth = index.field.sample(points)
    exact_distance, exact_depth = _brute(index, points)
    cell = _cell(index.field)
    # a 1-Lipschitz function read trilinearly is off by at most the cell's diagonal
    assert (distance - exact_distance).abs().max() <= math.sqrt(3) * cell
    assert (depth - exact_depth).abs().median() <= 0.1 * cell


@pytest.mark.parametrize("shape", ["sphere", "scatter"])
def test_every_fine_node_within_the_band_holds_its_nearest_samples_values(shape):
    """Fine nodes are computed where the coarse grid's reading cannot rule out a sample within ``BAND`` fine cells
    (``field.build``'s reach): every node truly that near holds its nearest sample's distance and depth, not an
    interpolation, on a sphere and on samples scattered through a box (where the coarse reading errs most)."""
    gen = torch.Generator().manual_seed(1)
    if shape == "sphere":
        index = _sphere(300)
    else:
        normals = torch.nn.functional.normalize(torch.randn(300, 3, generator=gen), dim=1)
        index = losses.SurfaceIndex(torch.rand(300, 3, generator=gen) * torch.tensor([2.0, 1.0, 0.5]), normals)
    field = index.field
    cell, nodes = _cell(field), fields.FINE
    axis = torch.arange(nodes, dtype=torch.float64) * cell
    grid = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3) + field.origin.double()
    stored = field.values[0].reshape(2, -1).double()
    points, normals = index.points.double(), index.normals.double()
    checked = 0
    for start in range(0, len(grid), 1 << 16):
        at = grid[start:start + (1 << 16)]
        dist, nearest = torch.cdist(at, points).min(dim=1)
        near = dist < fields.BAND * cell
        depth = ((points[nearest] - at) * normals[nearest]).sum(-1)
        got = stored[:, start:start + (1 << 16)]
        assert torch.allclose(got[0][near], dist[near], atol=1e-5 * field.size)
        assert torch.allclose(got[1][near], depth[near], atol=1e-5 * field.size)
        checked += int(near.sum())
    assert checked > 1000


def test_depth_tells_inside_from_outside_a_closed_surface():
    index = _sphere()
    gen = torch.Generator().manual_seed(1)
    direction = torch.nn.functional.normalize(torch.randn(500, 3, generator=gen), dim=1)
    _, inside = index.field.sample(direction * 0.8)
    _, outside = index.field.sample(direction * 1.2)
    assert inside.min() > 0.15 and inside.max() < 0.25
    assert outside.max() < -0.15


def test_beyond_the_box_the_distance_grows_and_the_depth_falls_with_the_gap():
    index = _sphere()
    field = index.field
    corner = field.origin + field.size  # the box's highest corner
    near, far = corner + 0.1, corner + 1.1
    d_near, s_near = field.sample(near[None])
    d_far, s_far = field.sample(far[None])
    gap = math.sqrt(3)  # the two points are 1 apart along each axis
    assert float(d_far - d_near) == pytest.approx(gap, rel=1e-5)
    assert float(s_near - s_far) == pytest.approx(gap, rel=1e-5)


def test_the_distances_gradient_points_away_from_the_surface():
    index = _sphere()
    points = torch.tensor([[0.0, 1.1, 0.0], [0.0, 0.0, -0.9], [0.75, 0.75, 0.0]], requires_grad=True)
    distance, _ = index.field.sample(points)
    distance.sum().backward()
    outward = torch.nn.functional.normalize(points.detach(), dim=1)
    sign = torch.tensor([1.0, -1.0, 1.0])  # outside: away from the centre; inside: toward it
    cosine = torch.nn.functional.cosine_similarity(points.grad, outward * sign[:, None], dim=1)
    assert (cosine > 0.9).all()


def test_a_field_scaled_and_shifted_reads_what_one_built_there_reads():
    """An object's field built once (a scene's target upright frame) and read in another frame a scale and a shift
    away (each step's normalised frame) answers as the field built from the samples moved there."""
    index = _sphere()
    scale, shift = 0.37, np.array([0.5, -1.25, 2.0])
    there = losses.SurfaceIndex(index.points * scale + torch.as_tensor(shift, dtype=torch.float32), index.normals)
    gen = torch.Generator().manual_seed(3)
    points = (torch.rand(4000, 3, generator=gen) * 2.6 - 1.3) * scale + torch.as_tensor(shift, dtype=torch.float32)
    moved = index.field.scaled(scale, shift)
    for read, built in zip(moved.sample(points), there.field.sample(points), strict=True):
        torch.testing.assert_close(read, built, atol=1e-5 * scale, rtol=1e-4)


def test_objects_read_as_one_answer_with_the_nearest_surface():
    """Two balls' own fields read as one (``FieldUnion``) give each point the nearer ball's distance and depth: as
    the brute-force search of both balls' samples does near either surface, inside either ball and between them."""
    a, b = _sphere(2000), _sphere(1000, radius=0.5)
    offset = torch.tensor([2.0, 0.0, 0.0])
    both = losses.SurfaceIndex(torch.cat([a.points, b.points + offset]), torch.cat([a.normals, b.normals]))
    union = fields.FieldUnion((a.field, b.field.scaled(1.0, offset.numpy())))
    gen = torch.Generator().manual_seed(4)
    direction = torch.nn.functional.normalize(torch.randn(1000, 3, generator=gen), dim=1)
    points = torch.cat([direction * 0.97, direction * 0.48 + offset, torch.tensor([[1.3, 0.0, 0.0], [1.4, 0.3, 0.0]])])
    distance, depth = union.sample(points)
    exact_distance, exact_depth = _brute(both, points)
    cell = _cell(a.field)
    assert (distance - exact_distance).abs().max() <= math.sqrt(3) * cell
    assert (depth - exact_depth).abs().median() <= 0.1 * cell
    assert (depth[:2000] > 0).all() and (depth[2000:] < 0).all()  # inside either ball; between them, outside both
    assert torch.equal(fields.FieldUnion((a.field,)).sample(points)[0], a.field.sample(points)[0])


def test_closest_fraction_is_the_mean_square_of_the_nearest_share():
    distance = torch.tensor([[0.4, 0.1, 0.3, 0.2], [1.0, 1.0, 1.0, 0.0]])
    value = losses.closest_fraction(distance, 0.5)
    torch.testing.assert_close(value, torch.tensor([(0.01 + 0.04) / 2, 0.5]))
    assert losses.closest_fraction(distance, 0.0).abs().sum() == 0


def test_the_field_and_the_k_nearest_search_charge_the_same_penetration():
    """A ball half sunk into a larger one: both ways of reading the depth charge about the same."""
    index = _sphere(4000)
    ball = _sphere(800, radius=0.3).points + torch.tensor([0.0, 1.0, 0.0])
    samples = losses.penetration(ball[None], index, sigma=0.01, margin=0.0, k=32)
    read = losses.depth_penalty(index.field.sample(ball[None])[1], 0.0)
    assert float(samples) > 0.05
    assert float(read) == pytest.approx(float(samples), rel=0.05)


def test_interior_points_lie_deep_inside_a_closed_surface():
    field = _sphere(3000).field
    inner = field.interior(200)
    assert len(inner) == 200
    assert float(inner.norm(dim=1).max()) < 1 - 1.5 * _cell(field)
    assert len(_sphere(3000, radius=0.02).field.interior(200)) > 0  # the grid follows the surface's size


def test_a_copy_where_an_identical_one_stands_is_charged_for_its_inside():
    """Both surface halves of the penetration read about 0 for a ball placed on its twin; its inside does not."""
    import trimesh

    from ctp_core import objective, pairs
    from ctp_core.config import AlignConfig, schedule
    from ctp_core.relations import predicates

    ground = trimesh.creation.box((1.0, 0.1, 1.0))
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.1)
    here = np.eye(4)
    here[:3, 3] = (0.2, 0.15, 0.0)
    scene = trimesh.Scene()
    scene.add_geometry(ground, node_name="table", geom_name="table")
    scene.add_geometry(ball.copy().apply_transform(here), node_name="ball_1", geom_name="ball_1")
    assert pairs.twins(ball.copy().apply_transform(here), ball) and not pairs.twins(ground, ball)
    config = AlignConfig.from_preset("test", seed=0, loss={"lambda_clip": 0.0})
    pair = pairs.prepare_pair(scene, ball, samples=1500, seed=0, on="table")
    assert pair.twins is not None
    scorer = objective.Scorer(pair, config, contact_ratio=0.1)
    beside = here.copy()
    beside[:3, 3] = (-0.2, 0.15, 0.0)
    poses = [predicates.poses_of(pair.local_to_normalised(m)) for m in (here, beside)]
    on_twin, apart = (float(scorer.interior(p, pair.twins)[0]) for p in poses)
    assert apart == 0.0
    radius = 0.1 * pair.target_to_normalised.scale
    assert on_twin > 0.2 * radius
    phase = schedule.phases(config, allow_penetration=False)[-1]
    assert float(scorer.geometry(poses[0], phase).pen[0]) >= on_twin
    sheet = trimesh.creation.box((0.2, 0.2, 0.01))
    sheet.update_faces(sheet.face_normals[:, 1] < 0.5)  # its top gone: open
    scene.add_geometry(sheet.copy().apply_transform(beside), node_name="sheet_1", geom_name="sheet_1")
    assert pairs.prepare_pair(scene, sheet, samples=500, seed=0, on="table").twins is None  # no inside to ask


def test_a_bounded_node_search_answers_as_the_brute_force_does_near_and_far():
    """``nodes`` with ``within`` (a band's bound) searches the points it leaves again, unbounded: near and far points
    get the nearest sample's distance and depth either way."""
    index = _sphere(500)
    generator = torch.Generator().manual_seed(2)
    at = torch.randn(400, 3, generator=generator) * 1.5  # inside, near the surface and far out
    data = index.points.double().numpy()
    dist, depth = fields.nodes(index.tree, data, index.normals.double().numpy(), at.double().numpy(), within=0.05)
    want_dist, want_depth = _brute(index, at)
    assert (want_dist > 0.05).sum() > 100 and (want_dist <= 0.05).sum() > 0  # both kinds were asked
    np.testing.assert_allclose(dist, want_dist.numpy(), atol=1e-5)
    np.testing.assert_allclose(depth, want_depth.numpy(), atol=1e-5)
