"""The objective L = l_clip*L_clip + l_icp*L_icp(r) + l_pen*L_pen + l_rel*(L_rel + L_stable) of a batch of poses
(../shared/docs/method.md, "Objective", in brief in docs/engine.md; the relation terms: ``predicates``,
docs/relations.md).

One ``Scorer`` per run computes the terms for any batch of poses on any cameras: the search scores hundreds of
candidates with it (forward only), the optimiser its restarts (with the CLIP gradient during steps, forward
only on the fixed evaluation views). The weights are a ``schedule.Phase``'s, so the CLIP weight has one source
(``config.loss.lambda_clip`` through the phase plan); ``combine`` is the one place the terms are summed.

The prompt's relation also *orders* poses before any weighted sum: that order, and how far a guide may override
it (``GuideSay``), is ``ordering``'s.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields, replace
from typing import Protocol

import numpy as np
import torch

from ctp_core import losses, render
from ctp_core.config import AlignConfig
from ctp_core.config.schedule import Phase
from ctp_core.contact import source_diagonal
from ctp_core.geometry.pose import Poses, apply_pose, quaternion_to_matrix
from ctp_core.guide.goals import Goal
from ctp_core.guide.guidance import Guide
from ctp_core.pairs import PreparedPair
from ctp_core.progress import Clock
from ctp_core.reading.relation import RelationReading
from ctp_core.relations import predicates
from ctp_core.render.cameras import Cameras, evaluation_views


class ScaleTerm(Protocol):
    """What a scorer needs of scale mode's plan (``search.scaling.ScalePlan``, a layer above): its term."""

    def term(self, log_s: torch.Tensor, geometric: float = 1.0) -> torch.Tensor: ...


class Say(Protocol):
    """What a scorer needs of the guide's say (``search.ordering.GuideSay``, a layer above): how far the guide may
    override the usual arrangement, 0 to 1."""

    @property
    def amount(self) -> float: ...


SCREEN_POINTS = 256  # ``Scorer.screen``: source samples of the geometric screen before the guide
ENCLOSED_SAMPLES = 512  # target samples a pose's enclosed penetration looks at (its bounding sphere's nearest)


PREFER = 0.1  # ``combine``: weight of ``predicates.preference`` (the usual arrangement) relative to the relation's


def goal_rows(goal_embeddings: torch.Tensor | None, rows: slice | torch.Tensor,
              shared: bool = False) -> torch.Tensor | None:
    """The goal's embeddings for some poses: per-pose (or per-group) ones (N, C, D) at ``rows`` (a slice, or an
    index with repeats: each pose its group's); those of cameras shared by every pose (1, C, D), a fixed goal's
    (D,) or None as they are."""
    if shared or goal_embeddings is None or goal_embeddings.dim() < 3:
        return goal_embeddings
    return goal_embeddings[rows]


@dataclass(frozen=True)
class Terms:
    """The objective's terms of a batch of B poses, each (B,), made together by a ``Scorer``: what the search ranks
    (``ordering``), the refinement improves and the selection chooses by.

    ``icp`` and ``pen``: soft-ICP and penetration (zero where a phase switches them off); ``sunk``: the penetration
    in source diagonals (``ordering.holding``); ``rel``, ``stable``, ``prefer``: the relation's
    (``Scorer.relation_terms``; zeros without a relation); ``clip``: the guide's (zero where nothing is encoded);
    ``objective``: their weighted sum under a phase (``combine``; the optimiser's loss where ``clip`` is zero).
    Where asked: ``scale``, scale mode's term (weighted already); ``clip_views`` (B, C), the guide's term seen by
    each view alone; ``centroid`` (B, 3), the posed samples' centroid (``Scorer.geometry``: the refinement's look-at).
    """

    icp: torch.Tensor
    pen: torch.Tensor
    sunk: torch.Tensor
    rel: torch.Tensor
    stable: torch.Tensor
    prefer: torch.Tensor
    clip: torch.Tensor
    objective: torch.Tensor
    scale: torch.Tensor | None = None
    clip_views: torch.Tensor | None = None
    centroid: torch.Tensor | None = None

    def map(self, fn: Callable[[torch.Tensor], torch.Tensor]) -> Terms:
        """``fn`` of every term there is (a copy, a device, a selection)."""
        return Terms(**{f.name: None if (v := getattr(self, f.name)) is None else fn(v) for f in fields(self)})

    def select(self, index: torch.Tensor | slice | list[int]) -> Terms:
        """The terms of the poses at ``index``."""
        return self.map(lambda v: v[index])

    def where(self, mask: torch.Tensor, other: Terms) -> Terms:
        """Each pose's terms from this batch where ``mask`` (B,), else from ``other``'s."""
        def pick(name: str) -> torch.Tensor | None:
            mine, theirs = getattr(self, name), getattr(other, name)
            if mine is None or theirs is None:
                return None
            shape = (-1,) + (1,) * (mine.dim() - 1)
            return torch.where(mask.reshape(shape), mine, theirs)

        return Terms(**{f.name: pick(f.name) for f in fields(self)})

    def row(self, i: int, names: Sequence[str]) -> dict[str, float]:
        """Pose ``i``'s terms ``names`` by name, as reports list them."""
        return {name: float(getattr(self, name)[i]) for name in names}

    def but(self, **changes: torch.Tensor | None) -> Terms:
        """These terms with ``changes`` (``dataclasses.replace``)."""
        return replace(self, **changes)

    @staticmethod
    def zeros(count: int) -> Terms:
        """``count`` poses' terms, every one zero: no pose's (``count`` 0), or what a caller fills in."""
        zero = torch.zeros(count)
        return Terms(icp=zero, pen=zero, sunk=zero, rel=zero, stable=zero, prefer=zero, clip=zero, objective=zero)

    @staticmethod
    def cat(parts: Sequence[Terms]) -> Terms:
        """One batch of ``parts``' poses in order (a term missing from any part is missing from it)."""
        def joined(name: str) -> torch.Tensor | None:
            values = [getattr(p, name) for p in parts]
            return None if any(v is None for v in values) else torch.cat(values)

        return Terms(**{f.name: joined(f.name) for f in fields(Terms)})


def combine(terms: Terms, phase: Phase, *, clip: torch.Tensor | None = None) -> torch.Tensor:
    """The weighted sum, one value per pose: the only place the weights meet the terms (``scale`` in scale mode,
    weighted already: ``scaling.ScalePlan.term``). ``clip``: the guide's term to count instead of ``terms.clip``
    (zeros: the geometry's objective alone)."""
    clip = terms.clip if clip is None else clip
    out = phase.lambda_clip * clip + phase.lambda_icp * terms.icp + phase.lambda_pen * terms.pen
    if terms.scale is not None:
        out = out + terms.scale
    if phase.lambda_rel:
        out = out + phase.lambda_rel * (terms.rel + terms.stable + PREFER * terms.prefer)
    return out


def geometric_objective(terms: Terms, phase: Phase) -> torch.Tensor:
    """The objective without the guide's term: what orders poses where the geometry alone chooses."""
    return combine(terms, phase, clip=torch.zeros_like(terms.objective))


@dataclass
class _Tally:
    count: int = 0  # images the guide encoded


class Scorer:
    """The objective's terms for any batch of poses; counts every image the guide encodes in ``clip_images``."""

    def __init__(self, pair: PreparedPair, config: AlignConfig, contact_ratio: float, guide: Guide | None = None,
                 goal: Goal | None = None, clock: Clock | None = None, *, reading: RelationReading | None = None,
                 scale: ScaleTerm | None = None, say: Say | None = None):
        self.pair, self.config, self.contact_ratio = pair, config, contact_ratio
        self.scale = scale  # scale mode: the ``scale`` term's plan (None: rigid, no term)
        # the prompt's relation where it judges poses (None: unknown, or ``config.relation`` off: zero terms)
        self.reading = reading if config.relation else None
        self.say = say  # the guide's say as the search measured it (None: not measured, trusted): ``with_say``
        self.guide, self.goal = guide, goal
        self.use_clip = goal is not None and guide is not None and config.loss.lambda_clip > 0
        self.clock = clock or Clock()
        self._images = _Tally()
        self._eval: tuple[Cameras, torch.Tensor] | None = None

    def with_say(self, say: Say | None) -> Scorer:
        """This scorer under the search's ``say`` (what it encodes, how much the usual arrangement weighs:
        ``guided``, ``preference_weight``); it shares the clock and the count of encoded images."""
        twin = copy.copy(self)
        twin.say, twin._eval = say, None
        return twin

    @property
    def clip_images(self) -> int:
        """Images the guide encoded, by this scorer and every ``with_say`` twin of it."""
        return self._images.count

    @clip_images.setter
    def clip_images(self, count: int) -> None:
        self._images.count = count

    @property
    def guided(self) -> bool:
        """Whether scoring encodes images: a guide, and one the search has not found without signal (``GuideSay``
        override 0: its scores spread no more than its noise). Once it has, the guide ranks nothing (the
        geometry does, ``ordering.rank_key``), so its images are not encoded: the rest of the search, the
        refinement's gradient and the selection's views run on the geometry alone."""
        return self.use_clip and (self.say is None or self.say.amount > 0)

    def geometry(self, poses: Poses, phase: Phase, points: int | None = None) -> Terms:
        """The geometry's ``Terms`` (``clip`` zero; its ``objective`` the geometry's alone, the refinement's loss):
        soft-ICP and penetration (zero when the phase switches it off), the penetration in source diagonals, the
        relation's terms, the ``scale`` term in scale mode and the posed centroid. ``points``: on that many of the
        source's samples (``PreparedPair.source_subset``) instead of all."""
        pts, icp, pen, sunk = self._surfaces(poses, phase, points)
        rel, stable, prefer = self.relation_terms(poses)
        zero = torch.zeros_like(icp)
        scale = None if self.scale is None else self.scale.term(poses.log_s, self.preference_weight)
        out = Terms(icp=icp, pen=pen, sunk=sunk, rel=rel, stable=stable, prefer=prefer, clip=zero, objective=zero,
                    scale=scale, centroid=pts.mean(dim=1))
        return out.but(objective=combine(out, phase))

    def sunk(self, poses: Poses, phase: Phase) -> torch.Tensor:
        """(B,) the penetration in source diagonals (``Terms.sunk``) alone: what a check of a placed pose reads
        (``adjust.adjust``), without the relation's terms."""
        return self._surfaces(poses, phase, None)[3]

    def _surfaces(self, poses: Poses, phase: Phase, points: int | None
                  ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """``geometry``'s terms of the two surfaces: the posed samples (B, N, 3), soft-ICP, the penetration (both
        halves, the twins' inside, the solid floor) and the penetration in source diagonals."""
        cfg = self.config.loss
        samples = self.pair.source_samples if points is None else self.pair.source_subset(points)
        with self.clock.time("geometry"):
            pts = apply_pose(samples, poses.t, poses.q, poses.log_s)
            icp, pen = (self._from_fields(pts, phase) if cfg.distances == "field"
                        else self._from_samples(pts, phase))
            if phase.lambda_pen > 0:
                pen = pen + self.enclosed(poses)
                if self.pair.twins is not None:
                    pen = pen + self.interior(poses, self.pair.twins)
                if self.pair.solid_floor:  # a scene's floor is solid: nothing placed goes under it
                    pen = pen + losses.below_floor(pts, self.pair.scene_floor, cfg.c_pen)
            sunk = pen.detach() / source_diagonal(self.pair, poses).to(pen.device)
        return pts, icp, pen, sunk

    def _from_fields(self, pts: torch.Tensor, phase: Phase) -> tuple[torch.Tensor, torch.Tensor]:
        """(soft-ICP at its closest-point limit, penetration) of posed samples (B, N, 3) from the grounds' and the
        target's distance fields (one reading where they are the same surface); penetration zero where the phase
        switches it off."""
        anchor, index = self.pair.anchor, self.pair.index
        distance, depth = anchor.field.sample(pts) if self.contact_ratio > 0 else (None, None)
        icp = (losses.closest_fraction(distance, self.contact_ratio) if distance is not None
               else pts.new_zeros(pts.shape[0]))
        if phase.lambda_pen <= 0:
            return icp, torch.zeros_like(icp)
        if depth is None or anchor is not index:
            _, depth = index.field.sample(pts)
        return icp, losses.depth_penalty(depth, self.config.loss.c_pen)

    def _from_samples(self, pts: torch.Tensor, phase: Phase) -> tuple[torch.Tensor, torch.Tensor]:
        """(soft-ICP, penetration) of posed samples (B, N, 3) from their k nearest samples; penetration zero where
        the phase switches it off. Where both terms ask, one search answers both: the same one where soft-ICP
        pulls toward the whole target (a single pair), the grounds' where they answer for every object
        (``losses.neighbours_of``)."""
        cfg = self.config.loss
        both = self.contact_ratio > 0 and phase.lambda_pen > 0
        near, idx = (losses.neighbours_of(self.pair.anchor, self.pair.index, pts, cfg.icp_neighbours) if both
                     else (None, None))
        icp = losses.soft_icp(pts, self.pair.anchor, self.contact_ratio, phase.sigma_icp, cfg.icp_neighbours,
                              idx=near)
        if phase.lambda_pen <= 0:
            return icp, torch.zeros_like(icp)
        return icp, losses.penetration(pts, self.pair.index, cfg.sigma_pen, cfg.c_pen, cfg.icp_neighbours, idx=idx)

    def screen(self, poses: Poses, phase: Phase) -> Terms:
        """The geometry's terms and objective (``clip`` 0) on ``SCREEN_POINTS`` of the source's samples, forward
        only: enough to tell where the relation holds and which poses intersect (the relation's own features are
        fewer still), at a fraction of the cost. The search screens every proposal with it before the guide
        sees any (``coarse_to_fine.encoder_shortlist``)."""
        with torch.inference_mode():
            terms = self._score(poses, phase, None, None, None, encode=False, points=SCREEN_POINTS)
        return terms.map(lambda v: v.clone().cpu())

    def enclosed(self, poses: Poses) -> torch.Tensor:
        """(B,) ``losses.enclosed_penetration``: the target samples within each posed source's bounding sphere
        (at most ``ENCLOSED_SAMPLES``, nearest its centre), taken into its local frame."""
        pair, cfg = self.pair, self.config.loss
        scale = poses.log_s.exp()
        count = min(ENCLOSED_SAMPLES, len(pair.index.points))
        centres = poses.t.detach().cpu().numpy().astype(np.float64)
        dist, idx = pair.index.tree.query(centres, k=count)
        dist, idx = dist.reshape(len(poses), count), idx.reshape(len(poses), count)
        reach = scale.detach().cpu().numpy()[:, None] * pair.source_radius
        inside = torch.as_tensor(dist <= reach, dtype=torch.float32, device=poses.t.device)
        if not bool(inside.any()):
            return torch.zeros(len(poses), device=poses.t.device)
        near = pair.index.points[torch.as_tensor(idx, device=poses.t.device)] - poses.t[:, None]
        local = torch.einsum("bji,bkj->bki", quaternion_to_matrix(poses.q), near) / scale[:, None, None]
        area_ratio = pair.sample_spacing(len(pair.index.points)) ** 2 / (pair.source_area * scale**2)
        # with the fields, each counted sample's nearest source sample (the depth a field's node holds, read
        # exactly): the few target samples within a source cost less to look up than its field does to build
        k = 1 if cfg.distances == "field" else cfg.icp_neighbours
        return losses.enclosed_penetration(local, inside, pair.source_surface, scale, area_ratio, cfg.sigma_pen,
                                           cfg.c_pen, k)

    def interior(self, poses: Poses, twins: losses.SurfaceIndex) -> torch.Tensor:
        """(B,) the penetration's share where the target holds the source's mesh again (``PreparedPair.twins``:
        earlier copies): the mean depth inside them of points inside the posed source (``PreparedPair.source_inside``).
        Both surface halves miss a copy put where an identical one stands (every sample on the other's surface,
        depth 0); its inside is deep in the other."""
        inner = self.pair.source_inside
        if not len(inner):
            return torch.zeros(len(poses), device=poses.t.device)
        _, depth = twins.field.sample(apply_pose(inner, poses.t, poses.q, poses.log_s))
        return losses.depth_penalty(depth, self.config.loss.c_pen)

    def relation_terms(self, poses: Poses) -> predicates.RelationTerms:
        """``rel``: how far each pose is from the prompt's relation (``predicates.relation_score``, figure
        diagonals, 0 where it holds); ``stable``: its centre of mass off its support (``predicates.stable``), for
        the relations that rest on something besides the resting ones (``on``, ``stand``, ... include it in
        their score already); ``prefer``: ``predicates.preference`` x ``preference_weight``; zeros without a
        relation. Differentiable (a refinement term)."""
        with self.clock.time("relation"):
            out = predicates.terms(self.pair, poses, self.reading)
        return out._replace(prefer=out.prefer * self.preference_weight)

    @property
    def preference_weight(self) -> float:
        """How much ``predicates.preference`` (the usual arrangement among poses where the relation holds) counts:
        fully without a guide, and with one as much as its ``GuideSay`` says it cannot tell poses apart (1 less its
        override): a guide with signal is the judge of where (a cup on a table's corner when the picture says
        so); one without must not leave it to soft-ICP, which favours corners."""
        if not self.use_clip or self.say is None:
            return 1.0
        return 1.0 - self.say.amount

    def embed_goal(self, cameras: Cameras) -> torch.Tensor:
        """The goal's embeddings for these cameras; a per-view goal (the oracle) encodes one image per view."""
        with self.clock.time("clip"):
            embeddings = self.goal.embeddings(cameras)
        if embeddings.dim() == 3:
            self.clip_images += embeddings.shape[0] * embeddings.shape[1]
        return embeddings

    def clip_term(self, poses: Poses, cameras: Cameras, goal_embeddings: torch.Tensor | None = None,
                  weight: float = 0.0, *, views: bool = False) -> torch.Tensor:
        """L_clip per pose ((B,); ``views``: (B, C), each view's alone). With ``weight`` > 0 (and grad enabled),
        ``weight * L_clip`` is back-propagated through the renderer to the poses; otherwise forward only."""
        pair, guide = self.pair, self.guide
        grad = weight > 0 and torch.is_grad_enabled()
        with self.clock.time("render"):
            verts = pair.scene_vertices(apply_pose(pair.source_vertices, poses.t, poses.q, poses.log_s))
            images = render.render(pair.mesh, verts, cameras)
        batch, views = images.shape[:2]
        if goal_embeddings is None:
            goal_embeddings = self.embed_goal(cameras)
        with self.clock.time("clip"):
            leaf = images.detach().requires_grad_(grad) if grad else images
            emb = guide.encode_images(leaf.reshape(batch * views, *images.shape[2:])).reshape(batch, views, -1)
            each = losses.clip_view_loss(emb, goal_embeddings)
            value = each.mean(dim=-1)
            if grad:
                (image_grad,) = torch.autograd.grad(value.sum() * weight, leaf)
        self.clip_images += batch * views
        if grad:
            with self.clock.time("render"):
                images.backward(image_grad)
        return (each if views else value).detach()

    def score(self, poses: Poses, phase: Phase, cameras: Cameras, goal_embeddings: torch.Tensor | None = None,
              batch: int | None = None, *, encode: bool = True, views: bool = False) -> Terms:
        """Every term and the objective of ``poses`` on ``cameras``, forward only, ``batch`` poses per call.

        ``cameras`` are (1, C) shared by every pose (a per-view goal is then encoded once for all) or
        (len(poses), C) per pose; ``goal_embeddings`` are the goal's, precomputed: for shared cameras, or
        (len(poses), C, D) per pose (poses that share cameras share their goal's images: the tile stage).
        ``encode`` False (or a run not ``guided``): the geometry's terms only, ``clip`` 0, nothing rendered.
        ``views``: where it encodes, also ``clip_views`` (B, C), the guide's term seen by each view alone.
        """
        with torch.inference_mode():
            out = self._score(poses, phase, cameras, goal_embeddings, batch, encode and self.guided, views=views)
        return out.map(torch.clone)  # normal tensors, usable outside inference mode

    def _score(self, poses: Poses, phase: Phase, cameras: Cameras | None, goal_embeddings: torch.Tensor | None,
               batch: int | None, encode: bool, points: int | None = None,
               views: bool = False) -> Terms:
        """``score``'s work, without inference mode or copies; ``cameras`` may be None where nothing is encoded,
        ``points``: the geometry on that many source samples (``geometry``)."""
        shared = cameras is not None and cameras.fov_deg.shape[0] == 1
        if encode and shared and goal_embeddings is None:
            goal_embeddings = self.embed_goal(cameras)
        step = batch or len(poses)
        parts: list[Terms] = []
        for lo in range(0, len(poses), step):
            chunk = poses.select(slice(lo, lo + step))
            terms = self.geometry(chunk, phase, points).but(centroid=None)
            if encode:
                cams = cameras.expand(len(chunk)) if shared else cameras.rows(lo, lo + step)
                each = self.clip_term(chunk, cams, goal_rows(goal_embeddings, slice(lo, lo + step), shared), views=True)
                terms = terms.but(clip=each.mean(dim=-1), clip_views=each if views else None)
            parts.append(terms)
        out = Terms.cat(parts)
        return out.but(objective=combine(out, phase))

    def evaluation_cameras(self) -> tuple[Cameras, torch.Tensor | None]:
        """The fixed selection views (1, C) around the target centre and the goal's embeddings there, made once."""
        if self._eval is None:
            origin = torch.zeros(1, 3, device=self.pair.source_vertices.device)
            cams = evaluation_views(origin, self.config.camera)
            goal_embeddings = None
            if self.guided:
                with torch.inference_mode():
                    goal_embeddings = self.embed_goal(cams)
                goal_embeddings = goal_embeddings.clone()
            self._eval = (cams, goal_embeddings)
        return self._eval

    def evaluate(self, poses: Poses, phase: Phase, clip: torch.Tensor | None = None) -> Terms:
        """The selection objective on the fixed evaluation views, for any number of poses. ``clip``: the guide's
        term of these poses on these views, already known (a phase starts from the poses the last one ended
        with evaluated): only the geometry is computed again, under this phase's weights."""
        with self.clock.time("eval"):
            cams, goal_embeddings = self.evaluation_cameras()
            if clip is None:
                return self.score(poses, phase, cams, goal_embeddings)
            out = self.score(poses, phase, cams, encode=False).but(clip=clip.clone())
        return out.but(objective=combine(out, phase))


