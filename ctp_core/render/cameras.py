"""Perspective pinhole cameras, batched over restarts (B) and views (C).

Frames: camera positions, look-at points and the up vector are in the *normalised* frame (target AABB
centred, longest side 2, up = +Y). ``world_to_view`` maps the normalised frame to the *camera* frame,
OpenGL-style: x right, y up, the camera looks down -z, so a point in front of it has z < 0.

Pixels: images are square, ``image_size`` pixels on a side. Pixel coordinates are continuous with the
origin at the top-left corner of the image: x grows to the right, y grows downwards (row 0 is the top),
and the centre of pixel (row r, column c) is at (c + 0.5, r + 0.5). The optical axis hits the image
centre (image_size / 2, image_size / 2).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import scipy.special
import torch
from torch import Tensor

from ctp_core.config import CameraConfig


@dataclass
class Cameras:
    """B x C look-at cameras sharing one square image size."""

    eye: Tensor  # (B, C, 3) normalised frame
    at: Tensor  # (B, C, 3) normalised frame
    fov_deg: Tensor  # (B, C) vertical field of view
    image_size: int
    up: Tensor | None = None  # (B, C, 3) normalised frame; None means +Y

    def world_to_view(self) -> Tensor:
        """(B, C, 4, 4) rigid transform, normalised frame -> camera frame."""
        back = _unit(self.eye - self.at)  # camera +z points from the look-at back to the eye
        up = self.up if self.up is not None else _axis(back, 1, 1.0)
        right = torch.linalg.cross(up, back, dim=-1)
        # Looking straight along `up` leaves `right` undefined; fall back to -Z as the up hint there, which
        # makes a top-down view from an orbit at azimuth 0 keep its image orientation.
        degenerate = right.norm(dim=-1, keepdim=True) < 1e-6
        right = _unit(torch.where(degenerate, torch.linalg.cross(_axis(back, 2, -1.0), back, dim=-1), right))
        true_up = torch.linalg.cross(back, right, dim=-1)
        rot = torch.stack([right, true_up, back], dim=-2)  # rows: camera axes in normalised coordinates
        out = torch.zeros(rot.shape[:-2] + (4, 4), dtype=rot.dtype, device=rot.device)
        out[..., :3, :3] = rot
        out[..., :3, 3] = -(rot @ self.eye[..., None])[..., 0]
        out[..., 3, 3] = 1.0
        return out

    def focal_px(self) -> Tensor:
        """(B, C) focal length in pixels from the vertical field of view."""
        return (self.image_size / 2) / torch.tan(torch.deg2rad(self.fov_deg) / 2)

    def to_view(self, points: Tensor) -> Tensor:
        """Points (B, C, N, 3), or (B, 1, N, 3) shared by the views, normalised frame -> camera frame."""
        m = self.world_to_view().to(points.dtype)
        return points @ m[..., :3, :3].transpose(-1, -2) + m[..., None, :3, 3]

    def expand(self, batch: int) -> Cameras:
        """(1, C) cameras shared by ``batch`` rows, as (batch, C) views (no copy)."""
        grow = lambda t: t.expand(batch, *t.shape[1:])  # noqa: E731
        return replace(self, eye=grow(self.eye), at=grow(self.at), fov_deg=grow(self.fov_deg),
                       up=None if self.up is None else grow(self.up))

    def rows(self, lo: int, hi: int) -> Cameras:
        """Rows lo:hi of the batch (the cameras of some of the restarts or candidates)."""
        return self.take(slice(lo, hi))

    def take(self, index: Tensor | slice) -> Cameras:
        """Rows ``index`` ((N,) or a slice) of the batch, repeats allowed (each candidate the cameras of its
        group)."""
        up = None if self.up is None else self.up[index]
        return replace(self, eye=self.eye[index], at=self.at[index], fov_deg=self.fov_deg[index], up=up)

    def to(self, device: torch.device | str) -> Cameras:
        up = self.up.to(device) if self.up is not None else None
        return replace(self, eye=self.eye.to(device), at=self.at.to(device), fov_deg=self.fov_deg.to(device), up=up)


def view_to_pixels(view: Tensor, focal_px: Tensor, image_size: int) -> Tensor:
    """Camera-frame points (B, C, N, 3) -> (B, C, N, 3): pixel x, pixel y, depth = -z.

    Points at or behind the camera plane get meaningless pixel coordinates; callers test the depth.
    """
    depth = -view[..., 2]
    f = focal_px[..., None] / depth
    centre = image_size / 2
    return torch.stack([centre + f * view[..., 0], centre - f * view[..., 1], depth], dim=-1)


def orbit(look_at: Tensor, azimuth_deg: Tensor, elevation_deg: Tensor, distance: Tensor, fov_deg: Tensor,
          image_size: int) -> Cameras:
    """Cameras on spheres around ``look_at`` (B, 3); the other arguments are (B, C).

    Azimuth 0 puts the eye on the +Z side of the look-at, looking towards -Z; azimuth grows
    counter-clockwise seen from above (+Y), so azimuth 90 is on the +X side. Elevation > 0 is above.
    """
    az, el = torch.deg2rad(azimuth_deg), torch.deg2rad(elevation_deg)
    offset = torch.stack([torch.cos(el) * torch.sin(az), torch.sin(el), torch.cos(el) * torch.cos(az)], dim=-1)
    at = look_at[:, None, :].expand_as(offset)
    return Cameras(eye=at + distance[..., None] * offset, at=at, fov_deg=fov_deg, image_size=image_size)


def sample_training_views(look_at: Tensor, cfg: CameraConfig, zoom: float, generator: torch.Generator) -> Cameras:
    """cfg.views random views per row of ``look_at`` (B, 3), as in ../shared/docs/method.md, "Cameras".

    Azimuth U[0, 360), elevation lo + (hi - lo) * Beta(a, b), distance U(cfg.distance) * zoom, fov
    U(cfg.fov_deg). The draws come only from ``generator`` (torch.distributions cannot take one), so a
    seeded generator gives the same views on any device.
    """
    shape = (look_at.shape[0], cfg.views)
    u = torch.rand((4, *shape), generator=generator, dtype=torch.float64, device=generator.device).cpu()
    a, b = cfg.elevation_beta
    beta = torch.from_numpy(scipy.special.betaincinv(a, b, u[1].numpy()))  # inverse-CDF Beta draw

    def span(bounds: tuple[float, float], x: Tensor) -> Tensor:
        return (bounds[0] + (bounds[1] - bounds[0]) * x).to(look_at.device, look_at.dtype)

    return orbit(look_at, span((0.0, 360.0), u[0]), span(cfg.elevation_deg, beta),
                 span(cfg.distance, u[2]) * zoom, span(cfg.fov_deg, u[3]), cfg.image_size)


def evaluation_views(look_at: Tensor, cfg: CameraConfig) -> Cameras:
    """cfg.eval_views fixed views per row of ``look_at`` (B, 3), azimuths evenly spaced from 0."""
    shape = (look_at.shape[0], cfg.eval_views)
    full = lambda value: torch.full(shape, float(value), dtype=look_at.dtype, device=look_at.device)  # noqa: E731
    azimuth = torch.arange(cfg.eval_views, dtype=look_at.dtype, device=look_at.device) * (360.0 / cfg.eval_views)
    return orbit(look_at, azimuth.expand(shape), full(cfg.eval_elevation_deg), full(cfg.eval_distance),
                 full(cfg.eval_fov_deg), cfg.image_size)


FIRST_AZIMUTH = 30.0  # degrees: the first framing view's (a preview's first image; the viewer's frame, ``predicates``)


def framing_cameras(vertices: torch.Tensor, views: int, image_size: int, elevation_deg: float = 30.0,
                    fov_deg: float = 40.0) -> Cameras:
    """Fixed orbit views that frame all of ``vertices`` (previews and metrics, not training).

    ``vertices`` (V, 3) gives (1, views) cameras; (B, V, 3) gives (B, views), each framing its own set.
    """
    batched = vertices if vertices.dim() == 3 else vertices[None]
    lo, hi = batched.min(1).values, batched.max(1).values
    centre, radius = (lo + hi) / 2, (hi - lo).norm(dim=1) / 2
    distance = (radius / np.sin(np.radians(fov_deg) / 2) * 1.05)[:, None].expand(-1, views)
    azimuth = torch.arange(views, dtype=torch.float32, device=vertices.device) * (360.0 / views) + FIRST_AZIMUTH
    full = lambda v: torch.full((len(batched), views), float(v), device=vertices.device)  # noqa: E731
    return orbit(centre, azimuth.expand(len(batched), -1), full(elevation_deg), distance, full(fov_deg), image_size)


def _unit(v: Tensor) -> Tensor:
    return v / v.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def _axis(like: Tensor, i: int, sign: float) -> Tensor:
    """A signed coordinate axis broadcast to the shape of ``like`` (..., 3)."""
    v = torch.zeros(3, dtype=like.dtype, device=like.device)
    v[i] = sign
    return v.expand_as(like)
