"""The three terms of the objective (../shared/docs/method.md, "Objective"), batched over restarts.

All points are in the normalised frame. Each function returns one value per restart, shape (B,), so the
optimiser can sum for the backward pass and still rank restarts.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from ctp_core.geometry import field as fields
from ctp_core.geometry import nearest


def clip_view_loss(image_embeddings: torch.Tensor, goal_embeddings: torch.Tensor) -> torch.Tensor:
    """(B, C) -cos(e_img, e_goal) per view; L_clip is its mean over the views (``Scorer.clip_term``), each view
    alone what ``coarse_to_fine.agreement_views`` compares (the guide's say: ``search.chance``).

    image_embeddings (B, C, D); goal_embeddings (D,) for a text or image prompt, or (B, C, D) for a
    per-view goal (the oracle guide). Both are expected L2-normalised; we normalise again so a
    caller's rounding (bf16) cannot push |cos| past 1.
    """
    img = torch.nn.functional.normalize(image_embeddings.float(), dim=-1)
    goal = torch.nn.functional.normalize(goal_embeddings.float(), dim=-1)
    return -((img * goal).sum(-1) if goal.dim() == 3 else img @ goal)


COVER = 64  # ``SurfaceIndex.cover``: the samples a far point's distance is first bounded by


class SurfaceIndex:
    """Surface samples with outward normals and a KD-tree, built once per run in a frame where the surface
    never moves: the target's in the normalised frame, the source's in its local frame."""

    def __init__(self, points: torch.Tensor, normals: torch.Tensor,
                 objects_field: Callable[[], fields.Field] | None = None):
        self.points = points  # (M, 3) the surface's frame
        self.normals = normals  # (M, 3) outward unit normals
        self.tree = nearest.Tree(points.detach().cpu().numpy())
        self.part: Part | None = None  # where its samples are rows of a larger index (``part_of``)
        # where the samples are objects' own (a target's), their fields read as one (``field``)
        self._objects_field = objects_field
        self._field: fields.Field | None = None
        self._own: fields.DistanceField | None = None
        self._cover: tuple[np.ndarray, float] | None = None

    @property
    def cover(self) -> tuple[np.ndarray, float]:
        """(C, 3) ``COVER`` of the samples (every ``M / C``-th) and how far any sample is from the nearest of them:
        a point's distance to the samples is at most its distance to these and at least that less the radius (a
        bound for far points, whose exact search is slow), made on first use and kept."""
        if self._cover is None:
            data = self.tree.data
            few = data[:: max(1, len(data) // COVER)]
            self._cover = few, float(nearest.Tree(few).query(data)[0].max())
        return self._cover

    @property
    def field(self) -> fields.Field:
        """The samples' distance field (``geometry.field``), made on first use and kept: what the objective's
        terms read where ``LossConfig.distances`` is ``field``. A target's samples are its objects' and their field
        is the objects' own fields read as one (``objects_field``: each object's is built once per scene), else it
        is built from these samples (``own_field``)."""
        if self._objects_field is None:
            return self.own_field
        if self._field is None:  # ordinary tensors even where first asked under inference mode (a screen)
            with torch.inference_mode(False):
                self._field = self._objects_field()
        return self._field

    @property
    def own_field(self) -> fields.DistanceField:
        """The field of these samples themselves, built on first use and kept."""
        if self._own is None:
            as_np = lambda t: t.detach().cpu().numpy().astype(np.float64)  # noqa: E731
            with torch.inference_mode(False):
                self._own = fields.build(self.tree, as_np(self.points), as_np(self.normals), device=self.points.device)
        return self._own

    def neighbours(self, queries: torch.Tensor, k: int) -> torch.Tensor:
        """Indices (..., k) of the k nearest target samples to each query point (no gradient)."""
        _, idx = self.nearest(_flat(queries), k)
        return _indices(idx, queries, min(k, self.points.shape[0]))

    def nearest(self, flat: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """(Q, k) distances and indices of the k nearest samples to each of ``flat`` (Q, 3) float64 points."""
        k = min(k, self.points.shape[0])
        dist, idx = self.tree.query(flat, k=k)
        return dist.reshape(len(flat), k), idx.reshape(len(flat), k)

    def part_of(self, whole: SurfaceIndex, rows: np.ndarray, others: list[np.ndarray]) -> bool:
        """Mark this index's samples as the rows ``rows`` of ``whole`` (a scene's grounds among all of its objects),
        the whole's other samples split into ``others`` (row arrays, one per object, each bounded by its own box):
        what ``neighbours_of`` then asks of the whole, this index answers wherever it can. Only where the samples are
        the whole's rows bit for bit and none repeats (so that both trees measure the same distances and no two
        samples tie); returns whether it was marked."""
        rows = np.asarray(rows, dtype=np.int64)
        data = whole.tree.data
        if (len(np.unique(rows)) != len(rows) or not np.array_equal(self.tree.data, data[rows])
                or len(np.unique(self.tree.data, axis=0)) != len(rows)):
            return False
        boxes = np.array([[data[r].min(0), data[r].max(0)] for r in others if len(r)]).reshape(-1, 2, 3)
        self.part = Part(whole, rows, boxes)
        return True


@dataclass(frozen=True)
class Part:
    """A ``SurfaceIndex`` whose samples are rows of a larger one (``SurfaceIndex.part_of``)."""

    whole: SurfaceIndex
    rows: np.ndarray  # (M,) int64: the whole's row of each of the part's samples
    boxes: np.ndarray  # (P, 2, 3) float64: the lowest and highest corner of each other object's samples


PART_MARGIN = 1e-9  # relative: how much farther than the part's k-th nearest every other object must be


def neighbours_of(part: SurfaceIndex, whole: SurfaceIndex, queries: torch.Tensor, k: int
                  ) -> tuple[torch.Tensor, torch.Tensor]:
    """The k nearest samples of ``part`` and of ``whole`` to each query point ((..., k) indices of each, no
    gradient), the question soft-ICP (the grounds) and the penetration term (every object) ask of the same posed
    samples. One search where they are the same index. Where ``part`` is marked a part of ``whole``
    (``SurfaceIndex.part_of``), the whole is searched only for the points that another object's box comes as near
    to as the part's k-th nearest sample: for every other point no sample of another object is as near as any of
    its part's k nearest, so the whole's k nearest are the part's (the same samples at the same distances, in the
    same order: the answer of a search of the whole, without it). A source placed on its ground is far from most
    other objects: most of its points are answered by the part alone. The box is the only test: a box that comes
    that near mostly holds a sample that does (on the dev scenes, asking the other objects for their nearest sample
    first would spare under a tenth of the whole's searches, for a search of its own)."""
    flat = _flat(queries)
    if part is whole:
        _, idx = whole.nearest(flat, k)
        same = _indices(idx, queries, idx.shape[1])
        return same, same
    dist, idx = part.nearest(flat, k)
    mine = _indices(idx, queries, idx.shape[1])
    link = part.part
    if link is None or link.whole is not whole or idx.shape[1] != min(k, whole.points.shape[0]):
        return mine, whole.neighbours(queries, k)
    out = link.rows[idx]
    if len(link.boxes):
        reach = dist[:, -1] ** 2 * (1 + PART_MARGIN)  # squared: what every other sample must be farther than
        # each point's squared distance to each other object's box: no sample of that object is nearer
        gap = np.maximum(np.maximum(link.boxes[None, :, 0] - flat[:, None], flat[:, None] - link.boxes[None, :, 1]),
                         0.0)
        near = ((gap**2).sum(-1) <= reach[:, None]).any(1)
        if near.any():
            _, out[near] = whole.nearest(flat[near], k)
    return mine, _indices(out, queries, out.shape[1])


def _flat(queries: torch.Tensor) -> np.ndarray:
    """(Q, 3) float64 query points, as the KD-trees are asked."""
    return queries.detach().reshape(-1, 3).cpu().numpy().astype(np.float64)


def _indices(idx: np.ndarray, queries: torch.Tensor, k: int) -> torch.Tensor:
    """(Q, k) neighbour indices as a long tensor shaped (..., k) like ``queries``, on their device."""
    return torch.as_tensor(idx.reshape(queries.shape[:-1] + (k,)), device=queries.device).long()


def soft_icp(source: torch.Tensor, index: SurfaceIndex, ratio: float, sigma: float, k: int,
             idx: torch.Tensor | None = None) -> torch.Tensor:
    """Fractional soft-ICP: attach the fraction ``ratio`` of the source that is already closest (0: none).

    source (B, N, 3) posed samples. For each source point d_i = min_j |v_i - u_j|; keep the
    K = floor(ratio * N) smallest (the selection carries no gradient), then
    L = 1/K sum_{i in W} sum_j softmax_j(-E_ij / 2 sigma^2) E_ij with E_ij = |v_i - u_j|^2.
    The softmax runs over the k nearest target samples instead of all M (memory B*N*k, not B*N*M);
    with k >= M it is the dense formula exactly. ``idx`` (B, N, k): the neighbours when the caller has them.
    """
    n = source.shape[1]
    if ratio <= 0:  # attach nothing: "a ball under the table" need not touch it (the relation places it)
        return source.new_zeros(source.shape[0])
    keep = max(1, int(np.floor(ratio * n)))
    idx = index.neighbours(source, k) if idx is None else idx  # (B, N, k)
    u = index.points[idx]  # (B, N, k, 3)
    sq = ((source[:, :, None, :] - u) ** 2).sum(-1)  # (B, N, k)
    with torch.no_grad():
        nearest = sq.min(dim=-1).values
        chosen = nearest.topk(keep, dim=1, largest=False).indices  # (B, K)
    sq = torch.gather(sq, 1, chosen[..., None].expand(-1, -1, sq.shape[-1]))
    alpha = torch.softmax(-sq / (2 * sigma**2), dim=-1)
    return (alpha * sq).sum(-1).mean(dim=1)


def signed_depth(source: torch.Tensor, index: SurfaceIndex, sigma: float | torch.Tensor, k: int,
                 idx: torch.Tensor | None = None) -> torch.Tensor:
    """(B, N) signed depth of each source point below the target surface (positive inside).

    The distance along the target's outward normal at a softmax-weighted nearest target point (width
    ``sigma``). Inside/outside comes from the target normals: ``pairs`` orients them outward (trimesh winding
    fix); for an open surface "inside" means behind the surface's oriented side. ``idx`` (B, N, k): the
    neighbours when the caller has them already. ``sigma``: a float, or (B, 1, 1) for one width per pose.
    """
    idx = index.neighbours(source, k) if idx is None else idx  # (B, N, k)
    u = index.points[idx]
    nrm = index.normals[idx]
    diff = u - source[:, :, None, :]  # from source point to target point
    sq = (diff**2).sum(-1)
    alpha = torch.softmax(-sq / (2 * sigma**2), dim=-1)
    return (alpha * (diff * nrm).sum(-1)).sum(-1)


def closest_fraction(distance: torch.Tensor, ratio: float) -> torch.Tensor:
    """(B,) soft-ICP at its closest-point limit (its width to 0) from each posed source sample's distance (B, N) to
    the target (``geometry.field``): the mean squared distance of the fraction ``ratio`` of the samples that are
    closest (the selection carries no gradient; 0 attaches nothing)."""
    if ratio <= 0:
        return distance.new_zeros(distance.shape[0])
    keep = max(1, int(np.floor(ratio * distance.shape[1])))
    with torch.no_grad():
        chosen = distance.topk(keep, dim=1, largest=False).indices
    return (torch.gather(distance, 1, chosen) ** 2).mean(dim=1)


def depth_penalty(depth: torch.Tensor, margin: float) -> torch.Tensor:
    """(B,) mean of max(0, depth - margin) over the source samples' depths (B, N) inside the target (the reference
    drops the margin; we keep it)."""
    return torch.relu(depth - margin).mean(dim=1)


def penetration(source: torch.Tensor, index: SurfaceIndex, sigma: float, margin: float, k: int,
                idx: torch.Tensor | None = None) -> torch.Tensor:
    """``depth_penalty`` of the source samples (B, N, 3) at their ``signed_depth`` (``idx``: their neighbours, where
    the caller has them)."""
    return depth_penalty(signed_depth(source, index, sigma, k, idx=idx), margin)


def below_floor(source: torch.Tensor, floor: float, margin: float) -> torch.Tensor:
    """(B,) the floor's share of the penetration: the mean over source samples (B, N, 3) of their depth under the
    plane y = ``floor`` past ``margin``, as ``penetration`` charges depth inside the target."""
    return torch.relu(floor - source[..., 1] - margin).mean(dim=1)


def enclosed_penetration(points: torch.Tensor, inside: torch.Tensor, source: SurfaceIndex, scale: torch.Tensor,
                         area_ratio: torch.Tensor, sigma: float, margin: float, k: int) -> torch.Tensor:
    """(B,) the other half of the penetration: target samples inside the posed source.

    ``penetration`` sees only source samples inside the target, so a source straddling a thin wall (a ball
    through a mug's side) has most of its samples outside, on either side of the wall, and is barely charged;
    the wall's own samples inside the source are. ``points`` (B, K, 3): target samples near each pose, in that
    pose's source local frame; ``inside`` (B, K) which of them count; ``scale`` (B,) the pose's scale (local
    -> normalised lengths). The depth (normalised units) past ``margin`` is summed with the weight of the area
    each sample stands for, over the posed source's area (``area_ratio``, (B,)): the same mean over the source's
    surface that ``penetration`` takes, so the two halves add up. Only the samples that count are looked up (the
    others' depth is 0 and counts 0 times: the sum is the same, term for term).
    """
    counted = inside.bool()
    width = (sigma / scale)[:, None].expand_as(inside)[counted]  # each counted sample's softmax width, local units
    depth = torch.zeros_like(inside)
    depth[counted] = signed_depth(points[counted][None], source, width.reshape(1, -1, 1), k)[0]
    depth = depth * scale[:, None]
    return (torch.relu(depth - margin) * inside).sum(1) * area_ratio
