import math

import pytest
import torch

from ctp_core.config import CameraConfig
from ctp_core.render.cameras import Cameras, evaluation_views, orbit, sample_training_views, view_to_pixels


def _orbit(az, el, dist=3.0, fov=45.0, size=64, at=(0.0, 0.0, 0.0)):
    """One row of cameras around ``at`` from lists of azimuths/elevations."""
    n = len(az)
    full = lambda v: torch.full((1, n), float(v))  # noqa: E731
    return orbit(torch.tensor([at]), torch.tensor([az], dtype=torch.float32), torch.tensor([el], dtype=torch.float32),
                 full(dist), full(fov), size)


def test_orbit_conventions():
    cams = _orbit([0, 90, 180, 0], [0, 0, 0, 60], dist=2.0, at=(0.1, -0.2, 0.3))
    offset = cams.eye[0] - cams.at[0]
    assert torch.allclose(offset[0], torch.tensor([0.0, 0.0, 2.0]), atol=1e-5)  # azimuth 0: +Z side
    assert torch.allclose(offset[1], torch.tensor([2.0, 0.0, 0.0]), atol=1e-5)  # ccw from above: +X next
    assert torch.allclose(offset[2], torch.tensor([0.0, 0.0, -2.0]), atol=1e-5)
    assert offset[3, 1] == pytest.approx(2.0 * math.sin(math.radians(60)), abs=1e-5)  # above the look-at
    assert torch.allclose(offset.norm(dim=-1), torch.full((4,), 2.0))


def test_world_to_view_is_rigid_and_looks_down_minus_z():
    cams = _orbit([0, 37, 200, 300], [10, -25, 45, 80], dist=2.5, at=(0.3, 0.1, -0.4))
    m = cams.world_to_view()[0]
    rot = m[:, :3, :3]
    assert torch.allclose(rot @ rot.transpose(-1, -2), torch.eye(3).expand(4, 3, 3), atol=1e-5)
    assert torch.allclose(torch.linalg.det(rot), torch.ones(4), atol=1e-5)
    eye_view = (m @ torch.cat([cams.eye[0], torch.ones(4, 1)], -1)[..., None])[..., :3, 0]
    at_view = (m @ torch.cat([cams.at[0], torch.ones(4, 1)], -1)[..., None])[..., :3, 0]
    assert torch.allclose(eye_view, torch.zeros(4, 3), atol=1e-5)
    assert torch.allclose(at_view, torch.tensor([0.0, 0.0, -2.5]).expand(4, 3), atol=1e-5)
    # Camera y is the world up direction tilted into the image plane: it never points downward.
    assert (rot[:, 1, 1] > 0).all()


def _project(cams: Cameras, points: torch.Tensor) -> torch.Tensor:
    """Normalised frame -> camera frame -> pixel x, pixel y, depth, as the rasterizer composes them."""
    return view_to_pixels(cams.to_view(points), cams.focal_px(), cams.image_size)


def test_project_centre_right_and_up():
    cams = _orbit([0, 120], [20, -10], dist=3.0, fov=50.0, size=80, at=(0.2, 0.3, 0.1))
    view = cams.world_to_view()[0]
    right, up = view[:, 0, :3], view[:, 1, :3]  # camera axes in the normalised frame
    pts = torch.stack([cams.at[0], cams.at[0] + 0.1 * right, cams.at[0] + 0.1 * up], dim=1)  # (C, 3, 3)
    pix = _project(cams, pts[None])[0]
    assert torch.allclose(pix[:, 0], torch.tensor([40.0, 40.0, 3.0]).expand(2, 3), atol=1e-4)
    focal = 40.0 / math.tan(math.radians(25.0))
    assert torch.allclose(pix[:, 1, 0] - 40.0, torch.full((2,), 0.1 * focal / 3.0), atol=1e-3)  # right: x grows
    assert torch.allclose(40.0 - pix[:, 2, 1], torch.full((2,), 0.1 * focal / 3.0), atol=1e-3)  # up: row shrinks


def test_top_down_view_is_finite():
    cams = _orbit([0], [90])
    assert torch.isfinite(cams.world_to_view()).all()
    assert torch.allclose(_project(cams, torch.zeros(1, 1, 1, 3))[0, 0, 0, :2], torch.tensor([32.0, 32.0]))


def _spherical(cams: Cameras):
    offset = cams.eye - cams.at
    dist = offset.norm(dim=-1)
    elevation = torch.rad2deg(torch.asin(offset[..., 1] / dist))
    azimuth = torch.rad2deg(torch.atan2(offset[..., 0], offset[..., 2])) % 360
    return azimuth, elevation, dist


def test_training_views_deterministic_and_in_range():
    cfg = CameraConfig(views=64, elevation_deg=(15.0, 55.0), elevation_beta=(1.0, 5.0), distance=(3.0, 3.5),
                       fov_deg=(30.0, 60.0), image_size=96)
    look_at = torch.linspace(-0.5, 0.5, 32 * 3).reshape(32, 3)  # 32 rows x 64 views = 2048 draws
    sample = lambda seed: sample_training_views(look_at, cfg, 0.81, torch.Generator().manual_seed(seed))  # noqa: E731
    a, b, c = sample(3), sample(3), sample(4)
    assert torch.equal(a.eye, b.eye) and torch.equal(a.fov_deg, b.fov_deg)
    assert not torch.allclose(a.eye, c.eye)
    assert a.eye.shape == (32, 64, 3) and a.image_size == 96
    assert torch.allclose(a.at, look_at[:, None].expand(32, 64, 3))
    azimuth, elevation, dist = _spherical(a)
    assert azimuth.min() >= 0 and azimuth.max() < 360 and azimuth.std() > 90  # spread over the circle
    assert elevation.min() >= 15 - 1e-3 and elevation.max() <= 55 + 1e-3
    assert dist.min() >= 3.0 * 0.81 - 1e-4 and dist.max() <= 3.5 * 0.81 + 1e-4
    assert a.fov_deg.min() >= 30 and a.fov_deg.max() <= 60
    # Beta(1, 5) has mean 1/6: elevations crowd near the low end (sd of this mean ~0.003).
    fraction = (elevation - 15) / 40
    assert fraction.mean().item() == pytest.approx(1 / 6, abs=0.02)


def test_evaluation_views_fixed():
    cfg = CameraConfig(eval_views=4, eval_elevation_deg=30.0, eval_distance=3.2, eval_fov_deg=45.0)
    cams = evaluation_views(torch.zeros(3, 3), cfg)
    azimuth, elevation, dist = _spherical(cams)
    assert cams.eye.shape == (3, 4, 3)
    assert torch.allclose(azimuth[0], torch.tensor([0.0, 90.0, 180.0, 270.0]), atol=1e-3)
    assert torch.allclose(elevation, torch.full((3, 4), 30.0), atol=1e-4)
    assert torch.allclose(dist, torch.full((3, 4), 3.2), atol=1e-5)
    assert torch.equal(cams.fov_deg, torch.full((3, 4), 45.0))
