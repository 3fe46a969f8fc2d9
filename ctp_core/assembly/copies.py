"""Several of a kind in one run: ``count`` copies of the source, arranged.

``place_copies(target, source, prompt, config, count=..., arrangement=...)`` places the copies one after another
(greedy): copy k sees the target and copies 1..k-1 as one scene (``assemble.scene_of``), so the penetration term
and the renders of copy k see the copies before it, and its relation is judged against the target (a stack's
copy against the copy under it). Greedy rather than joint because each copy is then exactly one placement of the
engine, judged as a single placement is, at a cost linear in the count; a joint search would need poses of
several sources in one batch, which the objective does not have.

Arrangements (``reading.counts.ARRANGEMENTS``; ``auto``: the prompt's cue, else ``scatter``):
- ``scatter`` (on, in, anything): each copy is an ``align`` run on the scene so far; of its distinct placements
  (``AlignResult.alternatives``) the first whose relation holds and that keeps ``SPACING`` from the earlier copies
  is taken.
- ``around``: evenly spaced azimuths about the target's centre (normalised frame: +Y up), the first at the
  target's front; each copy stands on the floor the target stands on, ``GAP`` outside the target's extent that
  way (farther where neighbours would touch), its front turned to the target; judged ``beside+facing`` whatever
  the prompt's words.
- ``row``: side by side along the target's longest horizontal side, ``GAP`` apart, centred on it; dropped onto
  its top (``adjust``'s ``drop``) when the relation rests on or goes in it, else on the floor along its front.
- ``stack``: each copy dropped onto the one before, the first onto the target's top centre; copy k > 1 is judged
  ``on`` the copy under it.
The slot arrangements are measured and judged by ``adjust.adjust`` (the search's settling, its penetration and
the relation's verdict), not searched: the arrangement fixes where each copy goes.

Frames: every copy's transform is source file -> target file (the target file frame is the scene frame).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import trimesh

from ctp_core import priors
from ctp_core.assembly.assemble import Placed, scene_of
from ctp_core.config import AUTO, AlignConfig
from ctp_core.errors import Canceled
from ctp_core.geometry import frames, once
from ctp_core.guide import selection
from ctp_core.progress import CancelCheck, ProgressCallback
from ctp_core.reading import counts
from ctp_core.reading.counts import MAX_COPIES, CountReading, choose, one_copy
from ctp_core.reading.records import RelationName
from ctp_core.reading.relation import RelationReading

if TYPE_CHECKING:
    from ctp_core.align import AlignResult
    from ctp_core.pairs import PreparedPair

__all__ = ["Copies", "Copy", "place_copies", "placed_copies", "set_metrics"]

GAP = 0.1  # source diagonals between neighbours in a row and between a copy and the target (around)
SPACING = 0.05  # scatter: the gap kept between copies where a placement allows it, source diagonals
ON = RelationReading(RelationName.ON)  # a stack's copy on the copy under it

CopyCallback = Callable[[int, int], None]


@dataclass
class Copy:
    """One copy: its node name, where it is (source file -> target file), what it is judged against and how."""

    name: str
    source_to_target: np.ndarray  # (4, 4)
    on: str  # the object its relation is judged against
    relation: dict[str, Any] | None  # predicates.RelationVerdict.to_dict(); None without a relation
    seconds: float
    how: str  # "search" (an align run) or "slot" (the arrangement's place, settled and measured)
    penetration: float | None = None  # slot: ``adjust``'s sunk (penetration over the source diagonal)
    result: AlignResult | None = None  # scatter: the run


@dataclass
class Copies:
    """The copies of one run, the set's measures and what the prompt was read as."""

    target: trimesh.Trimesh
    source: trimesh.Trimesh
    target_name: str
    source_name: str
    prompt: str | None
    one_prompt: str | None  # what each copy is read and guided by (``reading.counts.one_copy``)
    config: AlignConfig
    arrangement: str
    counted: CountReading  # what the prompt said of the number and the arrangement
    reading: RelationReading | None  # the relation each copy is judged by (a stack's later copies: ``on``)
    copies: list[Copy] = field(default_factory=list)
    metrics: dict[str, Any] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    preview: np.ndarray | None = None  # (V, H, W, 3) uint8 views of the whole set
    guide: str = "none"
    guide_why: str = ""

    @property
    def count(self) -> int:
        return len(self.copies)

    def placed(self) -> list[Placed]:
        """The target (identity) and every copy, in placing order."""
        return placed_copies(self.target, self.target_name, self.source,
                             [(c.name, c.source_to_target) for c in self.copies])

    def scene(self) -> trimesh.Scene:
        """The target and one named node per copy (``<source>_1`` ...), target file frame."""
        return scene_of(self.placed())


def placed_copies(target: trimesh.Trimesh, target_name: str, source: trimesh.Trimesh,
                  copies: list[tuple[str, np.ndarray]]) -> list[Placed]:
    """The target (identity) and each (name, source file -> target file) copy of ``source``: a scene's objects
    (``assemble.scene_of``; the target file frame is the scene frame)."""
    base = Placed(target_name, target, frames.Similarity(np.eye(4), frames.SCENE, frames.SCENE))
    return [base, *(Placed(name, source, frames.Similarity(np.asarray(m, dtype=np.float64), frames.SOURCE_FILE,
                                                           frames.SCENE)) for name, m in copies)]


@once.scene()  # each copy's run and check asks the same of the target and the earlier copies
def place_copies(target: trimesh.Trimesh, source: trimesh.Trimesh, prompt: str | None, config: AlignConfig, *,
                 count: int | None = None, arrangement: str = AUTO, target_name: str = "target",
                 source_name: str = "source", guide=None, on_event: ProgressCallback | None = None,
                 on_copy: CopyCallback | None = None, should_cancel: CancelCheck | None = None,
                 choice: selection.GuideChoice | None = None) -> Copies:
    """Place ``count`` copies of ``source`` (file frames) by ``arrangement`` (see the module); ``on_copy(k, n)`` is
    called as copy k of n starts. The guide is chosen and loaded once for all copies; what every copy's run asks of
    the target and the copies before it again is made once (``once``)."""
    from ctp_core import adjust, orientation, pairs
    from ctp_core.align import align

    started = time.perf_counter()
    n, kind, counted = choose(prompt, count, arrangement, source_name)
    one = one_copy(prompt, kind)
    if choice is None and config.model == AUTO and selection.asks_model(config):
        choice = selection.choose()  # once for every copy
    resolved, chosen = selection.resolve(config, image=False, choice=choice)
    if guide is None and resolved.loss.lambda_clip > 0:
        from ctp_core.guide.loaders import guide_for

        guide = guide_for(resolved)
    prior = priors.resolve_priors(priors.get_provider(config.hparams_provider), target_name, source_name, one or "")
    base = pairs.prepare_pair(target, source, samples=config.loss.samples, seed=config.seed, device="cpu",
                              canonicalise=config.upright, **orientation.configured(config))
    # around is the arrangement's own relation whatever the prompt's words ("chairs by the table", --arrangement)
    judged = counts.AROUND if kind == "around" else prior.reading
    out = Copies(target, source, target_name, source_name, prompt, one, config, kind, counted, judged,
                 guide=chosen.guide, guide_why=chosen.why)
    names = _names(source_name, target_name, n)
    slots = None if kind in ("scatter", "stack") else _slots(base, kind, n, judged)
    for k in range(n):
        if on_copy is not None:
            on_copy(k + 1, n)
        t0 = time.perf_counter()
        placed = out.placed()
        if kind == "scatter":
            result = align(scene_of(placed), source, one, config, on=target_name, target_name=target_name,
                           source_name=source_name, guide=guide, on_event=on_event, should_cancel=should_cancel,
                           choice=choice, pictures=False)
            pick = _spaced(result, out)
            result = result.alternative(pick)
            copy = Copy(names[k], result.source_to_target, target_name, result.relation, 0.0, "search", result=result)
        else:
            on = names[k - 1] if kind == "stack" and k > 0 else target_name
            slot = _stack_slot(base) if kind == "stack" else slots[k]
            settle = "drop" if kind == "stack" or (kind == "row" and _on_top(judged)) else "none"
            if should_cancel is not None and should_cancel():
                raise Canceled("the run was cancelled")
            # a stack's copy settles on the copy under it alone: sampled with the whole scene, a thin copy's top
            # is too coarse to rest on (the copy ends hovering); the scene's up stays the target's
            ground = scene_of(placed if on == target_name else [placed[-1]])
            done = adjust.adjust(ground, source, slot, config, settle=settle, on=on,
                                 reading=judged if on == target_name else ON, upright=base.target_upright.rotation)
            copy = Copy(names[k], done.source_to_target, on, done.relation, 0.0, "slot",
                        penetration=done.penetration)
        copy.seconds = round(time.perf_counter() - t0, 3)
        out.copies.append(copy)
    placing = time.perf_counter()
    out.metrics = set_metrics(source, [c.source_to_target for c in out.copies], [c.relation for c in out.copies])
    out.preview = pairs.preview(scene_of(out.placed()[:-1]), source, out.copies[-1].source_to_target)
    seconds = [c.seconds for c in out.copies]
    out.timings = {"place_s": round(placing - started, 3), "per_copy_s": seconds,
                   "mean_copy_s": round(float(np.mean(seconds)), 3),
                   "metrics_s": round(time.perf_counter() - placing, 3),
                   "total_s": round(time.perf_counter() - started, 3)}
    return out


def _names(source_name: str, target_name: str, n: int) -> list[str]:
    """``<source>_1`` ... ``<source>_n``, made unique against the target's name."""
    stem = source_name if all(f"{source_name}_{k}" != target_name for k in range(1, n + 1)) else f"{source_name}_copy"
    return [f"{stem}_{k}" for k in range(1, n + 1)]


def _spaced(result: AlignResult, out: Copies) -> int:
    """The alternative a scatter copy takes: the first (the answer first) whose relation holds and that keeps
    ``SPACING`` from every earlier copy; else the one that holds and keeps the widest gap; else the answer
    (``ordering.spaced_key``)."""
    import torch

    from ctp_core.search import ordering

    if not out.copies or not result.alternatives:
        return 0
    points = _surface(out.source)
    diagonal = _diagonal(out.source)
    earlier = [_posed(out.source, c.source_to_target) for c in out.copies]  # one mesh each: its queries cached
    gaps, holds = [], []
    for alt in result.alternatives:
        posed = trimesh.transform_points(points, np.asarray(alt["source_to_target"]))
        gaps.append(min(_gap(mesh, posed) for mesh in earlier) / diagonal)
        holds.append(alt["relation"] is None or bool(alt["relation"]["holds"]))
    key = ordering.spaced_key(torch.tensor(holds), torch.tensor(gaps, dtype=torch.float64), SPACING)
    return key.argmin()


def _surface(mesh: trimesh.Trimesh, count: int = 400) -> np.ndarray:
    from ctp_core.geometry import sampling

    return sampling.surface_samples(mesh, count, seed=5)[0]


def _posed(mesh: trimesh.Trimesh, matrix: np.ndarray) -> trimesh.Trimesh:
    return mesh.copy().apply_transform(np.asarray(matrix, dtype=np.float64))


def _gap(mesh: trimesh.Trimesh, points: np.ndarray) -> float:
    """The smallest distance from ``points`` to ``mesh``'s surface (0 where they touch or cross it)."""
    from ctp_core.geometry import proximity

    return float(proximity.min_distance(mesh, points))


def _diagonal(mesh: trimesh.Trimesh) -> float:
    return float(np.linalg.norm(mesh.extents))


def _yaw(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _heading(rotation: np.ndarray, front: np.ndarray) -> float:
    """The azimuth (about +Y, from +Z toward +X) of ``rotation @ front`` seen from above."""
    f = rotation @ front
    return math.atan2(f[0], f[2])


def _turned_to(base: PreparedPair, direction: np.ndarray) -> np.ndarray:
    """(3, 3) source local -> normalised: the source upright (its own up to +Y), its front along ``direction``
    (horizontal)."""
    upright = np.asarray(base.source_upright.rotation, dtype=np.float64)
    want = math.atan2(direction[0], direction[2])
    return _yaw(want - _heading(upright, np.asarray(base.source_front, dtype=np.float64))) @ upright


def _pose(base: PreparedPair, rotation: np.ndarray, centre_xz: np.ndarray, bottom: float) -> np.ndarray:
    """A source file -> target file 4x4 from a rotation (local -> normalised), its centre's (x, z) and the height
    its lowest point is at (normalised frame)."""
    verts = base.source_vertices.double().cpu().numpy() @ rotation.T
    m = np.eye(4)
    m[:3, :3] = rotation
    m[:3, 3] = [centre_xz[0], bottom - verts[:, 1].min(), centre_xz[1]]
    return base.source_to_target(m)


def _on_top(reading: RelationReading | None) -> bool:
    """Whether a row stands on the target's top: its relation rests on it or goes in it (else on the floor)."""
    return reading is not None and (reading.rests or "in" in reading.relations)


def _slots(base: PreparedPair, kind: str, n: int, reading: RelationReading | None) -> list[np.ndarray]:
    """``around`` and ``row``: each copy's place, source file -> target file (see the module)."""
    target = base.target_vertices.double().cpu().numpy()
    floor, top = base.floor, float(target[:, 1].max())
    front = np.asarray(base.target_front, dtype=np.float64) * [1.0, 0.0, 1.0]
    front = front / np.linalg.norm(front) if np.linalg.norm(front) > 1e-6 else np.array([0.0, 0.0, 1.0])
    local = base.source_vertices.double().cpu().numpy()
    diagonal = float(np.linalg.norm(local.max(0) - local.min(0)))
    gap = GAP * diagonal
    if kind == "around":
        directions = [_yaw(2 * math.pi * k / n) @ front for k in range(n)]
        turns = [_turned_to(base, -d) for d in directions]
        widths = [float(np.ptp(local @ r.T @ np.cross([0.0, 1.0, 0.0], d))) for r, d in zip(turns, directions,
                                                                                            strict=True)]
        # neighbours' centres at least a width and a gap apart on the ring: 2 r sin(pi / n) >= w + gap
        ring = (max(widths) + gap) / (2 * math.sin(math.pi / n)) if n > 1 else 0.0
        out = []
        for d, r in zip(directions, turns, strict=True):
            reach = float((target @ d).max()) + float((local @ r.T @ -d).max()) + gap
            out.append(_pose(base, r, max(reach, ring) * d[[0, 2]], floor))
        return out
    # row: along the longest horizontal side, the copies' fronts to the target's front (a shelf's books face out)
    extent = np.ptp(target, axis=0)
    axis = np.array([1.0, 0.0, 0.0]) if extent[0] >= extent[2] else np.array([0.0, 0.0, 1.0])
    out_of = np.cross(axis, [0.0, 1.0, 0.0])
    out_of = out_of if out_of @ front >= 0 else -out_of
    on_top = _on_top(reading)
    rotation = _turned_to(base, out_of if on_top else -out_of)
    turned = local @ rotation.T
    width = float(np.ptp(turned @ axis))
    length = n * width + (n - 1) * gap
    centre = (target.max(0) + target.min(0)) / 2
    if on_top:
        across, height = centre, top + GAP * diagonal  # above the top, then dropped onto it
    else:
        across = centre + out_of * (float((target @ out_of).max() - centre @ out_of)
                                    + float((turned @ -out_of).max()) + gap)
        height = floor
    out = []
    for k in range(n):
        along = -length / 2 + width / 2 + k * (width + gap)
        where = across * [1.0, 0.0, 1.0] + axis * (along + centre @ axis - across @ axis)
        out.append(_pose(base, rotation, where[[0, 2]], height))
    return out


def _stack_slot(base: PreparedPair) -> np.ndarray:
    """A stack's copy: upright, above everything at the target's centre column, to be dropped onto the stack."""
    target = base.target_vertices.double().cpu().numpy()
    local = base.source_vertices.double().cpu().numpy()
    rotation = np.asarray(base.source_upright.rotation, dtype=np.float64)
    centre = (target.max(0) + target.min(0)) / 2
    # high enough to clear the target and any stack of up to MAX_COPIES copies
    height = float(target[:, 1].max()) + MAX_COPIES * float(np.ptp(local @ rotation.T, axis=0)[1]) + 1.0
    return _pose(base, rotation, centre[[0, 2]], height)


def set_metrics(source: trimesh.Trimesh, matrices: list[np.ndarray], verdicts: list[dict[str, Any] | None]
                ) -> dict[str, Any]:
    """The set's measures, from each copy's source file -> target file matrix and verdict: how many copies'
    relations hold, whether any two intersect (IoU over ``metrics.PLACEMENT_IOU``), the largest IoU and the smallest
    gap between two copies (source diagonals)."""
    from ctp_core import metrics

    posed = [_posed(source, m) for m in matrices]
    surface = _surface(source)
    points = [trimesh.transform_points(surface, m) for m in matrices]
    diagonal = _diagonal(source) * frames.Similarity(matrices[0], frames.SOURCE_FILE, frames.TARGET_FILE).scale
    worst_iou, spacing = 0.0, math.inf
    for i in range(len(posed)):
        for j in range(i + 1, len(posed)):
            worst_iou = max(worst_iou, metrics.intersection_over_union(posed[i], posed[j]).iou)
            spacing = min(spacing, _gap(posed[j], points[i]), _gap(posed[i], points[j]))
    judged = [v for v in verdicts if v is not None]
    return {"count": len(matrices), "relation_holds": sum(bool(r["holds"]) for r in judged), "judged": len(judged),
            "all_hold": all(r["holds"] for r in judged) if judged else None,
            "none_intersect": worst_iou <= metrics.PLACEMENT_IOU, "max_iou": round(worst_iou, 5),
            "min_spacing": None if math.isinf(spacing) else round(spacing / diagonal, 5)}
