"""A surface's distance field: the distance to its nearest sample and the signed depth behind it, on a grid.

The objective's geometric terms ask, for every posed source sample of every candidate and restart, how far the
nearest target sample is and how deep behind the target's oriented surface the point lies. A k-nearest search per
point (``losses.SurfaceIndex``) answers exactly but costs most of a placement; a grid built once per surface
answers the same two questions by trilinear interpolation (``torch.nn.functional.grid_sample``), batched over
any number of points, differentiable in the points, on CPU or GPU.

Two levels keep the build cheap: a coarse grid over the whole box, and a fine one whose nodes are computed only in
a band around the surface (where the terms' values and gradients matter); elsewhere the fine grid holds the
coarse grid's interpolation. Each node's values are those of its nearest sample (``nodes``): its distance, and
the depth along that sample's outward normal (positive behind the surface: inside a closed one), the sample-based
measure ``losses.signed_depth`` takes with a narrow width. Outside the grid's box a point is outside the surface:
its distance grows and its depth falls by its distance to the box.

Several surfaces read as one (``FieldUnion``: a scene's placed objects) answer with the nearest surface's distance
and its depth, each object's field built alone once and read through a shift and a scale (``DistanceField.scaled``):
a scene's normalised frame moves and scales as objects are added, its objects' own fields do not change.

Frames: the grid lives in the frame of the samples it was built from (the target upright frame for a target's
object, ``scaled`` into the normalised frame; the source local frame for a source); points are given in that frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import torch
import torch.nn.functional as F

from ctp_core.geometry import nearest

COARSE = 32  # nodes per side of the coarse grid
FINE = 128  # nodes per side of the fine grid (only its band is computed)
PAD = 0.08  # of the samples' box's longest side: the grid's margin around the samples
BAND = 1.5  # fine cells beyond a coarse cell's reach: how far from the surface fine nodes are computed


class Field(Protocol):
    """What the objective's terms read of a surface: its distance and depth at points (``DistanceField.sample``)."""

    def sample(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]: ...


@dataclass(frozen=True)
class DistanceField:
    """Distance and signed depth on a cubic grid, fine near the surface (build with ``build``)."""

    origin: torch.Tensor  # (3,) the grid's lowest corner, the samples' frame
    size: float  # the grid's side, the samples' frame
    values: torch.Tensor  # (1, 2, R, R, R): distance, depth; indexed [x, y, z]

    def sample(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(distance, depth), each shaped like ``points``' leading dimensions, at ``points`` (..., 3) in the
        samples' frame; differentiable in ``points``."""
        lead = points.shape[:-1]
        got, out = self._read(self.values, points)
        return (got[0] + out).reshape(lead), (got[1] - out).reshape(lead)

    def scaled(self, scale: float, shift: np.ndarray) -> DistanceField:
        """The same field in the frame ``scale * p + shift`` of its own (a uniform scale and a shift, no turn): its box
        moved and its distances and depths scaled with it, so it reads there what it reads here."""
        offset = torch.as_tensor(np.asarray(shift), dtype=self.origin.dtype, device=self.origin.device)
        return DistanceField(self.origin * scale + offset, self.size * scale, self.values * scale)

    def interior(self, count: int) -> torch.Tensor:
        """(P, 3) up to ``count`` fine nodes well inside a closed surface (deeper than two fine cells), evenly spread
        through its volume, the samples' frame; empty for a shell thinner than that. Behind an open surface (a
        sheet) is its whole back side: no inside to ask for."""
        cell = self.size / (self.values.shape[-1] - 1)
        inside = torch.nonzero(self.values[0, 1] > 2 * cell)
        pick = torch.linspace(0, len(inside) - 1, min(count, len(inside))).round().long()
        return self.origin + inside[pick].to(self.origin) * cell

    def _read(self, grid: torch.Tensor, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(channels, Q) trilinear readings of ``grid`` (1, channels, R, R, R) spanning the field's box at
        ``points`` (..., 3), each clamped into the box, and (Q,) each point's distance to the box (0 within)."""
        flat = points.reshape(-1, 3)
        low = self.origin.to(flat)
        inside = torch.minimum(torch.maximum(flat, low), low + self.size)
        unit = (inside - low) * (2.0 / self.size) - 1.0
        # grid_sample reads (x, y, z) as (W, H, D): the grids are stored [x, y, z] = (D, H, W)
        at = unit.flip(-1).reshape(1, -1, 1, 1, 3)
        got = F.grid_sample(grid.to(flat), at, mode="bilinear", align_corners=True)[0, :, :, 0, 0]
        return got, (flat - inside).norm(dim=-1)


@dataclass(frozen=True)
class FieldUnion:
    """Surfaces' fields in one frame read as one surface: at each point the nearest one's distance and its depth
    (behind the nearest surface, as one field of all their samples measures it, ``nodes``)."""

    members: tuple[DistanceField, ...]

    def sample(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(distance, depth) as ``DistanceField.sample``; differentiable in ``points``."""
        if len(self.members) == 1:
            return self.members[0].sample(points)
        distance, depth = (torch.stack(readings) for readings in zip(*(m.sample(points) for m in self.members),
                                                                     strict=True))
        nearest = distance.argmin(dim=0, keepdim=True)
        return distance.gather(0, nearest)[0], depth.gather(0, nearest)[0]


def nodes(tree: nearest.Tree, points: np.ndarray, normals: np.ndarray, at: np.ndarray,
          within: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
    """(distance, depth) at ``at`` (Q, 3): to the nearest sample, and along its outward normal (positive behind).
    ``within``: how near most points' nearest sample is (a band's nodes): the search is bounded by it first (it visits
    less of the tree), then the points it left are searched unbounded; the answer is the same."""
    dist, idx = tree.query(at, upper=within)
    missed = ~np.isfinite(dist)
    if missed.any():
        dist[missed], idx[missed] = tree.query(at[missed])
    depth = ((points[idx] - at) * normals[idx]).sum(-1)
    return dist, depth


def build(tree: nearest.Tree, points: np.ndarray, normals: np.ndarray,
          device: torch.device | str = "cpu") -> DistanceField:
    """The field of the samples ``points`` (M, 3) with outward ``normals`` (M, 3), whose KD-tree is ``tree``; its
    tensors on ``device``."""
    low, high = points.min(0), points.max(0)
    size = float((high - low).max()) * (1 + 2 * PAD)
    origin = (low + high) / 2 - size / 2
    axis = np.linspace(0.0, size, COARSE)
    coarse = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3) + origin
    values = np.stack(nodes(tree, points, normals, coarse)).reshape(1, 2, COARSE, COARSE, COARSE)
    # in the field's own precision: the grid is kept in float32
    fine = F.interpolate(torch.as_tensor(values, dtype=torch.float32), size=(FINE,) * 3, mode="trilinear",
                         align_corners=True)[0].numpy()
    # a fine node is computed where the surface may come within BAND fine cells of it. The distance changes by at
    # most its change in place, so the coarse interpolation overstates it by at most the weighted mean distance to
    # the cell's corners, which the root of the weighted mean square bounds: half a coarse cell's diagonal
    reach = math.sqrt(3) / 2 * size / (COARSE - 1) + BAND * size / (FINE - 1)
    where = np.nonzero(fine[0] < reach)
    at = np.stack(where, -1) * (size / (FINE - 1)) + origin
    fine[0][where], fine[1][where] = nodes(tree, points, normals, at, within=2 * reach)
    return DistanceField(torch.as_tensor(origin, dtype=torch.float32, device=device), size,
                         torch.as_tensor(fine, device=device)[None])
