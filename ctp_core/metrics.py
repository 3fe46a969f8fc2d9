"""Evaluation metrics for an arrangement: plain functions over meshes and arrays (no optimiser state).

All inputs are in the *target file frame* unless a function says otherwise: a placed source is the
source file-frame mesh (or points) mapped by a 4x4 ``source_to_target`` (``p_target = M @ [p_source; 1]``).

- ``intersection_over_union``: Vol(A ∩ B) / Vol(A ∪ B), the paper's interpenetration measure. Exact
  booleans (manifold3d) when both meshes bound volumes; otherwise an estimate from generalised winding
  numbers on a grid (``winding_numbers``), because real assets (every PairBench3D mesh) are open,
  self-intersecting piles of parts for which "inside" only has the winding-number meaning.
- ``contact_distance``: how far the objects are from touching, relative to the target's size.
- ``pose_errors``: ADD-S and friends against a reference arrangement.
- ``semantic_score``: mean image-text cosine over fixed views (the paper's CLIP/SigLIP score).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch
import trimesh
from scipy.spatial import cKDTree

from ctp_core.geometry import proximity

SUCCESS_ADDS = 0.1  # ADD-S (relative to the source diagonal) at or below which a pose counts as found
# placement success, rotation-free: the source's centroid within this many source diagonals of its reference
# position, and the intersection ratio at most PLACEMENT_IOU (contact stays its own column: "under" or
# "beside" arrangements need not touch)
PLACEMENT_RADIUS = 0.5
PLACEMENT_IOU = 0.02

# Fixed ray directions for the winding-number estimate: a Fibonacci sphere, turned off the axes so no
# direction runs along the faces of axis-aligned boxes (where ray hits would be ambiguous).
_N_DIRECTIONS = 16
# Rays per intersector call: bounds memory (trimesh's numpy fallback holds every candidate triangle per ray).
_RAYS_PER_CALL = 1 << 14


def _directions(count: int) -> np.ndarray:
    i = np.arange(count) + 0.5
    z = 1.0 - 2.0 * i / count
    phi = np.pi * (1.0 + 5**0.5) * i + 0.1234
    r = np.sqrt(1.0 - z**2)
    d = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
    tilt = trimesh.transformations.euler_matrix(0.31, 0.17, 0.53)[:3, :3]
    return d @ tilt.T


def winding_numbers(mesh: trimesh.Trimesh, points: np.ndarray, directions: int = _N_DIRECTIONS) -> np.ndarray:
    """Generalised winding number of ``mesh`` at each point (N, 3), estimated by signed ray crossings.

    The generalised winding number (Jacobson et al. 2013) equals the signed number of surface
    crossings along a ray, averaged over all ray directions (+1 leaving through a face's front side,
    -1 entering). Averaging over a fixed set of directions is therefore an estimate of it that costs
    a few ray casts per point (embree via trimesh) instead of one solid angle per point and face. It is
    1 inside and 0 outside a closed mesh, sums over overlapping parts, and degrades gracefully (to a
    fraction) near holes of an open one; ``> 0.5`` is "inside".
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    d = _directions(directions)
    per_chunk = max(1, _RAYS_PER_CALL // len(d))
    counts = [_signed_crossings(mesh, points[i:i + per_chunk], d) for i in range(0, len(points), per_chunk)]
    return np.concatenate(counts).reshape(len(points), len(d)).mean(axis=1) if counts else np.zeros(0)


def _signed_crossings(mesh: trimesh.Trimesh, points: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Signed surface crossings of the rays from every point along every direction (flat, point-major)."""
    origins = np.repeat(points, len(d), axis=0)
    rays = np.tile(d, (len(points), 1))
    tri, ray = mesh.ray.intersects_id(origins, rays, multiple_hits=True)[:2]
    sign = np.sign(np.einsum("ij,ij->i", mesh.face_normals[tri], rays[ray]))
    return np.bincount(ray, weights=sign, minlength=len(origins))


def _grid(lo: np.ndarray, hi: np.ndarray, resolution: int) -> tuple[np.ndarray, float]:
    """Cell centres of a ``resolution``^3 grid over the box [lo, hi], and the volume of one cell."""
    axes = [lo[i] + (np.arange(resolution) + 0.5) * (hi[i] - lo[i]) / resolution for i in range(3)]
    points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    return points, float(np.prod(hi - lo)) / resolution**3


def volume(mesh: trimesh.Trimesh, resolution: int = 32) -> float:
    """Enclosed volume: exact for a closed, consistently wound mesh, else a winding-number grid estimate."""
    if mesh.is_volume:
        return float(mesh.volume)
    points, cell = _grid(mesh.bounds[0], mesh.bounds[1], resolution)
    return float((winding_numbers(mesh, points) > 0.5).sum() * cell)


@dataclass(frozen=True)
class Intersection:
    iou: float  # Vol(A ∩ B) / Vol(A ∪ B) in [0, 1]; lower is better
    intersection: float  # Vol(A ∩ B), in the meshes' units cubed
    union: float
    method: Literal["exact", "winding"]  # manifold3d booleans, or the winding-number grid estimate

    def to_dict(self) -> dict:
        return {"iou": self.iou, "intersection_volume": self.intersection, "union_volume": self.union,
                "iou_method": self.method}


def intersection_over_union(a: trimesh.Trimesh, b: trimesh.Trimesh, resolution: int = 32) -> Intersection:
    """Vol(A ∩ B) / Vol(A ∪ B) of two meshes in the same frame.

    Exact (manifold3d) when both bound volumes. Otherwise each volume is estimated on a
    ``resolution``^3 grid over its own bounding box and the intersection on one over the overlap of
    the two boxes (so a small source keeps its resolution next to a large target); "inside" is a
    winding number above 1/2 (``winding_numbers``) and the union is Vol(A) + Vol(B) - Vol(A ∩ B).
    """
    if a.is_volume and b.is_volume:
        inter = trimesh.boolean.intersection([a, b], engine="manifold")
        both = trimesh.boolean.union([a, b], engine="manifold")
        inter_v = float(max(inter.volume, 0.0)) if len(inter.faces) else 0.0  # empty: no mass properties
        union_v = float(both.volume)
        return Intersection(inter_v / union_v if union_v > 0 else 0.0, inter_v, union_v, "exact")
    lo, hi = np.maximum(a.bounds[0], b.bounds[0]), np.minimum(a.bounds[1], b.bounds[1])
    inter_v = 0.0
    if np.all(hi > lo):
        points, cell = _grid(lo, hi, resolution)
        inside = (winding_numbers(a, points) > 0.5) & (winding_numbers(b, points) > 0.5)
        inter_v = float(inside.sum() * cell)
    union_v = volume(a, resolution) + volume(b, resolution) - inter_v
    iou = min(1.0, inter_v / union_v) if union_v > 0 else 0.0
    return Intersection(iou, inter_v, max(union_v, 0.0), "winding")


def contact_distance(target: trimesh.Trimesh, source: trimesh.Trimesh, samples: int = 2000, seed: int = 0) -> float:
    """Closest distance between the two surfaces relative to the target's longest AABB side (0 = touching).

    Estimated from ``samples`` surface points of each mesh against the exact closest point on the
    other (``proximity``: bounded memory), in both directions, so thin features of either object are
    not missed. Interpenetrating
    surfaces give (nearly) 0: this measures attachment, ``intersection_over_union`` measures overlap.
    """
    source_points = trimesh.sample.sample_surface(source, samples, seed=seed)[0]
    target_points = trimesh.sample.sample_surface(target, samples, seed=seed + 1)[0]
    nearest = min(proximity.min_distance(target, source_points), proximity.min_distance(source, target_points))
    return float(nearest / target.extents.max())


def _similarity_parts(m: np.ndarray) -> tuple[float, np.ndarray]:
    scale = float(np.cbrt(abs(np.linalg.det(m[:3, :3]))))
    return scale, m[:3, :3] / scale


def rotation_error_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Geodesic angle between the rotations of two similarity 4x4s (or 3x3s), degrees."""
    ra, rb = _similarity_parts(np.asarray(a, float)[:3, :3])[1], _similarity_parts(np.asarray(b, float)[:3, :3])[1]
    cos = (np.trace(ra @ rb.T) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def _apply(m: np.ndarray, points: np.ndarray) -> np.ndarray:
    return points @ m[:3, :3].T + m[:3, 3]


def add_s(points: np.ndarray, predicted: np.ndarray, reference: np.ndarray) -> float:
    """ADD-S: mean distance from each predicted-posed point to the nearest reference-posed point.

    ``points`` (N, 3) are source surface samples in the source file frame; the result is relative to
    the reference-posed source's AABB diagonal. Nearest-point matching means a symmetric object turned
    onto itself scores 0, as it should (its renders and contacts are the same).
    """
    predicted, reference = np.asarray(predicted, float), np.asarray(reference, float)
    ref_points = _apply(reference, points)
    dist, _ = cKDTree(ref_points).query(_apply(predicted, points))
    return float(dist.mean() / _diagonal(points, reference))


def _diagonal(points: np.ndarray, reference: np.ndarray) -> float:
    return float(np.linalg.norm(np.ptp(points, axis=0)) * _similarity_parts(reference)[0])


def pose_errors(points: np.ndarray, predicted: np.ndarray, reference: np.ndarray) -> dict[str, float | bool]:
    """Pose error of a source_to_target 4x4 against the reference one (both source file -> target file).

    ``adds`` and ``translation_error`` (distance between the posed AABB centres) are relative to the
    reference-posed source diagonal, as is ``centroid_error`` (of the surface samples' centroid),
    ``rotation_error_deg`` is the geodesic angle, ``scale_error`` is
    |ln(s / s_ref)|, and ``success`` is ADD-S <= ``SUCCESS_ADDS``.
    """
    predicted, reference = np.asarray(predicted, float), np.asarray(reference, float)
    centre = (points.min(axis=0) + points.max(axis=0)) / 2
    offset = np.linalg.norm(_apply(predicted, centre[None]) - _apply(reference, centre[None]))
    centroid = points.mean(axis=0, keepdims=True)
    centroid_offset = np.linalg.norm(_apply(predicted, centroid) - _apply(reference, centroid))
    adds = add_s(points, predicted, reference)
    diagonal = _diagonal(points, reference)
    return {
        "adds": adds,
        "translation_error": float(offset / diagonal),
        "centroid_error": float(centroid_offset / diagonal),
        "rotation_error_deg": rotation_error_deg(predicted, reference),
        "scale_error": float(abs(np.log(_similarity_parts(predicted)[0] / _similarity_parts(reference)[0]))),
        "success": bool(adds <= SUCCESS_ADDS),
    }


def placement_success(centroid_error: float, iou: float) -> bool:
    """Rotation-free success: centroid within ``PLACEMENT_RADIUS`` source diagonals, IoU <= ``PLACEMENT_IOU``."""
    return bool(centroid_error <= PLACEMENT_RADIUS and iou <= PLACEMENT_IOU)


def semantic_score(images: torch.Tensor, text_embedding: torch.Tensor, guide) -> float:
    """Mean cosine between each view (V, 3, H, W in [0, 1]) and a unit text embedding, for one encoder.

    ``guide`` is a ``guidance.Guide``; the paper reports this over 8 fixed evaluation views per encoder.
    """
    return float(guide.score(images, text_embedding).mean())
