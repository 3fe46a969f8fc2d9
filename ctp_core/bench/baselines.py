"""The paper's baselines, from the same protocol starts as ctp (../shared/docs/method.md, "Baselines").

- ``b1``, shrinkwrap: Blender's shrinkwrap constraint on the source as a rigid body, i.e. move the
  source's centre to the nearest target surface point, then push it out along that point's outward
  normal until no source sample is inside the target. Single start, no text.
- ``b2``: b1 from several starts, the one that scores best with the guide wins (``harness`` passes
  the same guide ctp gets).

Poses are 4x4 source file frame -> target file frame similarities.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import trimesh

from ctp_core import metrics, pairs
from ctp_core.geometry import proximity, sampling

PUSH_STEPS = 20  # each push clears the deepest sample; a non-convex contact may need a few
PUSH_MARGIN = 1e-3  # extra clearance per push, relative to the target's longest side


def _moved(pose: np.ndarray, shift: np.ndarray) -> np.ndarray:
    out = pose.copy()
    out[:3, 3] += shift
    return out


def shrinkwrap(target: trimesh.Trimesh, source: trimesh.Trimesh, starts: Sequence[np.ndarray], *,
               samples: int = 1000, seed: int = 0) -> list[np.ndarray]:
    """b1 from each start: snap the source centre to the nearest target surface point, then push out.

    "Inside" is the target's winding number above 1/2 (``metrics.winding_numbers``) at ``samples``
    source surface points, so open, multi-part targets work; the target is re-wound outward first.
    """
    outward = pairs.outward(target)
    points = sampling.surface_samples(source, samples, seed)[0]
    centre = source.bounds.mean(axis=0)
    margin = PUSH_MARGIN * float(target.extents.max())
    poses = []
    for start in starts:
        start = np.asarray(start, dtype=np.float64)
        posed_centre = start[:3, :3] @ centre + start[:3, 3]
        nearest, _, face = proximity.closest_points(outward, posed_centre[None])
        normal = outward.face_normals[face[0]]
        pose = _moved(start, nearest[0] - posed_centre)
        for _ in range(PUSH_STEPS):
            posed = points @ pose[:3, :3].T + pose[:3, 3]
            inside = metrics.winding_numbers(outward, posed) > 0.5
            if not inside.any():
                break
            depth = proximity.closest_points(outward, posed[inside])[1].max()
            pose = _moved(pose, normal * (depth + margin))
        poses.append(pose)
    return poses


def best_of(poses: Sequence[np.ndarray], score: Callable[[np.ndarray], float]) -> tuple[int, list[float]]:
    """Index of the highest-scoring pose and all scores (b2's selection)."""
    scores = [float(score(p)) for p in poses]
    return int(np.argmax(scores)), scores
