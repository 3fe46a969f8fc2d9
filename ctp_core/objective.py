"""The objective L = l_clip*L_clip + l_icp*L_icp(r) + l_pen*L_pen + l_rel*(L_rel + L_stable) of a batch of poses
(method.md "Objective"; the relation terms: ``predicates``, docs/relations.md).

One ``Scorer`` per run computes the terms for any batch of poses on any cameras: the search scores hundreds of
candidates with it (forward only), the optimiser its restarts (with the CLIP gradient during steps, forward
only on the fixed evaluation views). The weights are a ``schedule.Phase``'s, so the CLIP weight has one source
(``config.loss.lambda_clip`` through the phase plan); ``combine`` is the one place the terms are summed.

The prompt's relation also *orders* poses before any weighted sum (``rank_key``): the poses where it holds
(``predicates.holds``) come first, then the others; a guide orders the poses where it holds plus a share of the
others it likes best, as far as ``Gate`` (its spread over the candidates against its noise) lets it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch

from ctp_core import losses, predicates, render
from ctp_core.cameras import Cameras, evaluation_views
from ctp_core.config import AlignConfig
from ctp_core.goals import Goal
from ctp_core.guidance import Guide
from ctp_core.pose import Poses, apply_pose, quaternion_to_matrix
from ctp_core.priors.relations import RelationReading
from ctp_core.progress import Clock
from ctp_core.scene import PreparedPair
from ctp_core.schedule import Phase

if TYPE_CHECKING:
    from ctp_core.scaling import ScalePlan

NEAR = 2.0  # source diagonals: a pose whose source is farther than this from the target places it nowhere


def clearance(pair: PreparedPair, index: losses.SurfaceIndex, poses: Poses, points: int = 64) -> torch.Tensor:
    """(B,) the smallest distance between each posed source (``points`` of its samples) and the target samples,
    in source diagonals (normalised frame)."""
    posed = apply_pose(pair.source_subset(points), poses.t, poses.q, poses.log_s).detach().cpu()
    dist, _ = index.tree.query(posed.reshape(-1, 3).numpy().astype(np.float64), k=1, workers=1)
    return torch.as_tensor(dist.reshape(len(poses), -1).min(axis=1), dtype=torch.float32) / source_diagonal(pair, poses)


def source_diagonal(pair: PreparedPair, poses: Poses) -> torch.Tensor:
    """(B,) each posed source's diagonal, normalised units (CPU): the unit of ``clearance`` and ``touch_limit``."""
    return 2 * pair.source_radius * poses.log_s.detach().cpu().exp()


SCREEN_POINTS = 256  # ``Scorer.screen``: source samples of the geometric screen before the guide
ENCLOSED_SAMPLES = 512  # target samples a pose's enclosed penetration looks at (its bounding sphere's nearest)
TOUCH = 0.1  # source diagonals: a refined pose this close to the target touches it (plus the samples' spacing)


def contact_gap(pair: PreparedPair, poses: Poses) -> torch.Tensor:
    """(B,) each pose's gap to the target in source diagonals: its ``clearance`` less the target samples' spacing
    (a small source on a big target is farther from the nearest sample than from the surface), at least 0."""
    return (clearance(pair, pair.index, poses) - (touch_limit(pair, poses) - TOUCH)).clamp(min=0)


def touch_limit(pair: PreparedPair, poses: Poses) -> torch.Tensor:
    """(B,) the ``clearance`` (source diagonals) under which a pose touches: ``TOUCH`` plus the spacing of the
    target samples (a small source on a big target is farther from the nearest sample than from the surface)."""
    return TOUCH + pair.sample_spacing(len(pair.index.points)) / source_diagonal(pair, poses)


def select_answer(terms: dict[str, torch.Tensor], clear: torch.Tensor, limit: torch.Tensor, weights: Phase, *,
                  guided: bool, touches: bool, override: float = 1.0, share: float = 0.08, tie: float = 0.0) -> int:
    """The answer among refined poses: those within ``NEAR`` of the target (any when none is: an image guide can
    prefer a source gone out of view, an absent source differing less from the goal than a misplaced one); with
    a guide, among them those that touch (``touches``: the relation's contact ratio is > 0), the lowest
    objective without its soft-ICP term (the guide's and the penetration's); otherwise, or when none touches,
    the lowest objective. The relation orders first, as in the search (``rank_key``): the restarts where it
    holds, plus, with a guide, a share of the others (``override`` x ``share``, at least one when the
    override is > 0: ``Gate``); ``override`` 0 (a guide with no signal) selects as without a guide. An admitted
    restart that fails the relation still pays its weighted relation term in the objective (``lambda_rel`` x its
    score): the guide overrides the relation at the selection only by more than that.

    Why not soft-ICP: at contact it measures how the samples fall, not contact (on cur-s01 with the pixels guide
    the restart refined onto the reference, guide term -0.999, lost to one a diagonal away, -0.996, by 0.004 of
    weighted soft-ICP); the search ranks its candidates by the guide the same way (``ranking.ranking_key``).
    Penetration likewise counts only past ``SUNK``: at contact the two halves see a few samples a hair inside
    (on cur-s01 with pixels, 3e-5, times lambda_pen 1000, outweighed the guide's 0.005 for the reference).
    The usual arrangement (``prefer``, already x (1 - override): ``Scorer.preference_weight``) breaks what the
    guide cannot tell: it counts ``tie`` per unit (``Gate.tie``: a difference the gate would trust fully), not
    its objective weight, which would outweigh any guide (pixels on cur-s01: a restart a
    third of a diagonal from the reference, the guide's best by 0.004, lost by its cup's sampled support patch
    to one 0.6 away).
    ``clear`` and ``limit``: per pose, in source diagonals (``clearance``, ``touch_limit``).
    """
    key = terms["objective"]
    if guided and override <= 0:  # a guide without signal: the geometry alone
        guided, key = False, combine({**terms, "clip": torch.zeros_like(key)}, weights)
    clear, limit = clear.to(key.device), limit.to(key.device)
    near = clear <= NEAR
    pool = near if near.any() else torch.ones_like(near)
    if guided:
        fit = pool & ((clear <= limit) | (not touches))
        if fit.any():
            pen = terms["pen"]
            if "sunk" in terms:  # penetration counts where the pose intersects, not at contact
                pen = torch.where(intersecting(terms).to(pen.device), pen, torch.zeros_like(pen))
            zeros = torch.zeros_like(key)
            key = combine({**terms, "icp": zeros, "pen": pen, "prefer": zeros}, weights)
            pool, key = fit, key + tie * terms.get("prefer", zeros)
    key = torch.where(pool, key.double(), torch.full_like(key, torch.inf, dtype=torch.float64))
    ranked = rank_key({**terms, "objective": key}, weights, guide_key=key if guided else None,
                      override=override, share=share, geometric=key)
    return int(ranked.argmin())


PREFER = 0.1  # ``combine``: weight of ``predicates.preference`` (the usual arrangement) relative to the relation's
TIER = 1e6  # ``rank_key``: added to the key of a pose outside the relation's pool (keys are float64)
GATE_FULL = 4.0  # ``Gate``: a guide whose spread is this many times its noise may override the relation fully


@dataclass(frozen=True)
class Gate:
    """How far a guide may override the relation: its scores' spread over the search's candidates (standard
    deviation) against its noise (the largest change of the score of a few candidates moved by a negligible
    amount: ``ranking.guide_noise``). ``override`` grows from 0 (spread at most the noise: the guide does not
    tell the candidates apart, so it must not undo the geometry) to 1 at ``GATE_FULL`` times the noise."""

    spread: float
    noise: float

    @property
    def ratio(self) -> float:
        return self.spread / self.noise if self.noise > 0 else math.inf

    @property
    def override(self) -> float:
        return float(min(1.0, max(0.0, (self.ratio - 1.0) / (GATE_FULL - 1.0))))

    @property
    def tie(self) -> float:
        """What one unit of ``prefer`` is worth where the guide orders (``rank_key``, ``select_answer``): a
        difference of the guide's term the gate would trust fully (``GATE_FULL`` x its noise)."""
        return GATE_FULL * self.noise

    @property
    def chooser(self) -> str:
        """Who orders the poses where the relation holds: ``geometry`` (override 0: the usual arrangement),
        ``guide`` (override 1: the usual arrangement only breaks its ties) or ``both`` (between: the usual
        arrangement weighs 1 - override, ``Scorer.preference_weight``)."""
        return "geometry" if self.override <= 0 else "guide" if self.override >= 1 else "both"

    def summary(self) -> str:
        """The gate in one line, for the progress readout, the report and the page."""
        spread = f"the guide's scores spread {self.ratio:.1f}x their noise" if self.noise > 0 else (
            "the guide's scores have no measurable noise")
        return spread + {"geometry": ": the geometry chose", "guide": ": the guide chose",
                         "both": f": the guide chose, the usual arrangement weighing {1 - self.override:.2f}"
                         }[self.chooser]

    def to_dict(self) -> dict[str, float | str]:
        return {"spread": self.spread, "noise": self.noise, "override": round(self.override, 3),
                "chose": self.chooser, "summary": self.summary()}


SUNK = 0.01  # source diagonals of penetration (``sunk``) past which a pose intersects: a sphere pressed into a
# plane by a tenth of its diagonal (forward and enclosed halves ~ depth^2 / radius / 2 each side summed)


def holding(terms: dict[str, torch.Tensor]) -> torch.Tensor:
    """(B,) bool: where the relation holds (``predicates.holds`` of the ``rel`` term; everywhere without one) and
    the pose does not intersect the target (``sunk`` at most ``SUNK``; 0 where penetration is allowed). Without
    the second rule a ball pulled into a mug's wall by "in" (its foot inside the hull, below the rim) outranked
    every clean pose beside the mug: intersecting is worse than the relation failing."""
    held = predicates.holds(terms["rel"]) if "rel" in terms else torch.ones_like(terms["objective"], dtype=torch.bool)
    return held & ~intersecting(terms).to(held.device)


def intersecting(terms: dict[str, torch.Tensor]) -> torch.Tensor:
    """(B,) bool: where the pose is sunk into the target past ``SUNK`` (nowhere without a ``sunk`` term)."""
    sunk = terms.get("sunk")
    if sunk is None:
        return torch.zeros_like(terms["objective"], dtype=torch.bool)
    return sunk > SUNK


def rank_key(terms: dict[str, torch.Tensor], weights: Phase, *, guide_key: torch.Tensor | None = None,
             override: float = 1.0, share: float = 0.08, geometric: torch.Tensor | None = None,
             tie: float = 0.0) -> torch.Tensor:
    """(B,) float64 ranking key (lower is better), the relation first.

    Without a guide (``guide_key`` None) or with ``override`` 0: the geometric objective (``geometric``, else
    ``combine`` without the guide's term) plus ``TIER`` where the relation does not hold. With a guide: its key
    over the *pool*, the poses where the relation holds plus the ``ceil(override x share x others)`` others
    that the guide ranks best (a misread prompt must not make the right answer unreachable: ``share`` is the
    search's ``min_share``, the principle of the region weights); ``TIER`` added outside the pool; plus ``tie``
    (``Gate.tie``) per unit of ``prefer``: the usual arrangement breaks what the guide
    cannot tell.
    """
    holds = holding(terms).to(terms["objective"].device)
    if guide_key is None or override <= 0:
        if geometric is None:
            geometric = combine({**terms, "clip": torch.zeros_like(terms["objective"])}, weights)
        return geometric.double() + TIER * (~holds).double()
    key = guide_key.double() + tie * terms.get("prefer", torch.zeros_like(guide_key)).double()
    pool = holds.clone()
    others = torch.nonzero(~holds)[:, 0]
    admit = math.ceil(override * share * len(others)) if len(others) else 0
    if admit:
        pool[others[torch.argsort(key[others])[:admit]]] = True
    return key + TIER * (~pool).double()


def goal_rows(goal_embeddings: torch.Tensor | None, rows: slice | torch.Tensor,
              shared: bool = False) -> torch.Tensor | None:
    """The goal's embeddings for some poses: per-pose (or per-group) ones (N, C, D) at ``rows`` (a slice, or an
    index with repeats: each pose its group's); those of cameras shared by every pose (1, C, D), a fixed goal's
    (D,) or None as they are."""
    if shared or goal_embeddings is None or goal_embeddings.dim() < 3:
        return goal_embeddings
    return goal_embeddings[rows]


def combine(terms: dict[str, torch.Tensor], weights: Phase) -> torch.Tensor:
    """The weighted sum, one value per pose: the only place the weights meet the terms (``rel`` and ``stable``
    count where present: the relation's, ``Scorer.relation_terms``; ``scale`` in scale mode, weighted already:
    ``scaling.ScalePlan.term``)."""
    out = weights.lambda_clip * terms["clip"] + weights.lambda_icp * terms["icp"] + weights.lambda_pen * terms["pen"]
    if "scale" in terms:
        out = out + terms["scale"]
    if weights.lambda_rel and "rel" in terms:
        zeros = torch.zeros_like(out)
        out = out + weights.lambda_rel * (terms["rel"] + terms.get("stable", zeros)
                                          + PREFER * terms.get("prefer", zeros))
    return out


class Scorer:
    """The objective's terms for any batch of poses; counts every image the guide encodes in ``clip_images``."""

    def __init__(self, pair: PreparedPair, config: AlignConfig, contact_ratio: float, guide: Guide | None = None,
                 goal: Goal | None = None, clock: Clock | None = None, *, reading: RelationReading | None = None,
                 scale: ScalePlan | None = None):
        self.pair, self.config, self.contact_ratio = pair, config, contact_ratio
        self.scale = scale  # scale mode: the ``scale`` term's plan (None: rigid, no term)
        # the prompt's relation where it judges poses (None: unknown, or ``config.relation`` off: zero terms)
        self.reading = reading if config.relation and reading is not None and reading.known else None
        self.gate: Gate | None = None  # the guide's gate, measured by the search (None: not measured, trusted)
        self.guide, self.goal = guide, goal
        self.use_clip = goal is not None and guide is not None and config.loss.lambda_clip > 0
        self.clock = clock or Clock()
        self.clip_images = 0
        self._eval: tuple[Cameras, torch.Tensor] | None = None

    @property
    def guided(self) -> bool:
        """Whether scoring encodes images: a guide, and one the search has not found without signal (``Gate``
        override 0: its scores spread no more than its noise). Once it has, the guide ranks nothing (the geometry
        does, ``rank_key``), so its images are not encoded: the rest of the search, the refinement's gradient and
        the selection's views run on the geometry alone."""
        return self.use_clip and (self.gate is None or self.gate.override > 0)

    def geometry(self, poses: Poses, weights: Phase, points: int | None = None) -> dict[str, torch.Tensor]:
        """Soft-ICP and penetration (zero when the phase switches it off), the penetration in source diagonals
        (``sunk``: what ``holding`` reads), the relation's terms, the ``scale`` term in scale mode and the posed
        centroid. ``points``: on that many
        of the source's samples (``PreparedPair.source_subset``) instead of all."""
        cfg = self.config.loss
        samples = self.pair.source_samples if points is None else self.pair.source_subset(points)
        with self.clock.time("geometry"):
            pts = apply_pose(samples, poses.t, poses.q, poses.log_s)
            icp = losses.soft_icp(pts, self.pair.anchor, self.contact_ratio, weights.sigma_icp, cfg.icp_neighbours)
            if weights.lambda_pen > 0:
                pen = losses.penetration(pts, self.pair.index, cfg.sigma_pen, cfg.c_pen, cfg.icp_neighbours)
                pen = pen + self.enclosed(poses)
            else:
                pen = torch.zeros_like(icp)
            sunk = pen.detach() / source_diagonal(self.pair, poses).to(pen.device)
        out = {"icp": icp, "pen": pen, "sunk": sunk, **self.relation_terms(poses), "centroid": pts.mean(dim=1)}
        if self.scale is not None:
            out["scale"] = self.scale.term(poses.log_s, self.preference_weight)
        return out

    def screen(self, poses: Poses, weights: Phase) -> dict[str, torch.Tensor]:
        """The geometry's terms and objective (``clip`` 0) on ``SCREEN_POINTS`` of the source's samples, forward
        only: enough to tell where the relation holds and which poses intersect (the relation's own features are
        fewer still), at a fraction of the cost. The search screens every proposal with it before the guide
        sees any (``ranking.encoder_shortlist``)."""
        with torch.inference_mode():
            terms = self._score(poses, weights, None, None, None, encode=False, points=SCREEN_POINTS)
        return {k: v.clone().cpu() for k, v in terms.items()}

    def enclosed(self, poses: Poses) -> torch.Tensor:
        """(B,) ``losses.enclosed_penetration``: the target samples within each posed source's bounding sphere
        (at most ``ENCLOSED_SAMPLES``, nearest its centre), taken into its local frame."""
        pair, cfg = self.pair, self.config.loss
        scale = poses.log_s.exp()
        count = min(ENCLOSED_SAMPLES, len(pair.index.points))
        centres = poses.t.detach().cpu().numpy().astype(np.float64)
        dist, idx = pair.index.tree.query(centres, k=count, workers=1)
        dist, idx = dist.reshape(len(poses), count), idx.reshape(len(poses), count)
        reach = scale.detach().cpu().numpy()[:, None] * pair.source_radius
        inside = torch.as_tensor(dist <= reach, dtype=torch.float32, device=poses.t.device)
        if not bool(inside.any()):
            return torch.zeros(len(poses), device=poses.t.device)
        near = pair.index.points[torch.as_tensor(idx, device=poses.t.device)] - poses.t[:, None]
        local = torch.einsum("bji,bkj->bki", quaternion_to_matrix(poses.q), near) / scale[:, None, None]
        area_ratio = pair.sample_spacing(len(pair.index.points)) ** 2 / (pair.source_area * scale**2)
        return losses.enclosed_penetration(local, inside, pair.source_surface, scale, area_ratio, cfg.sigma_pen,
                                           cfg.c_pen, cfg.icp_neighbours)

    def relation_terms(self, poses: Poses) -> dict[str, torch.Tensor]:
        """``rel``: how far each pose is from the prompt's relation (``predicates.relation_score``, figure
        diagonals, 0 where it holds); ``stable``: its centre of mass off its support (``predicates.stable``), for
        the relations that rest on something besides the resting ones (``on``, ``stand``, ... include it in
        their score already); ``prefer``: ``predicates.preference`` x ``preference_weight``; zeros without a
        relation. Differentiable (a refinement term)."""
        with self.clock.time("relation"):
            out = predicates.terms(self.pair, poses, self.reading)
        out["prefer"] = out["prefer"] * self.preference_weight
        return out

    @property
    def preference_weight(self) -> float:
        """How much ``predicates.preference`` (the usual arrangement among poses where the relation holds) counts:
        fully without a guide, and with one as much as its ``Gate`` says it cannot tell poses apart (1 less its
        override): a guide with signal is the judge of where (a cup on a table's corner when the picture says
        so); one without must not leave it to soft-ICP, which favours corners."""
        if not self.use_clip or self.gate is None:
            return 1.0
        return 1.0 - self.gate.override

    def embed_goal(self, cameras: Cameras) -> torch.Tensor:
        """The goal's embeddings for these cameras; a per-view goal (the oracle) encodes one image per view."""
        with self.clock.time("clip"):
            embeddings = self.goal.embeddings(cameras)
        if embeddings.dim() == 3:
            self.clip_images += embeddings.shape[0] * embeddings.shape[1]
        return embeddings

    def clip_term(self, poses: Poses, cameras: Cameras, goal_embeddings: torch.Tensor | None = None,
                  weight: float = 0.0) -> torch.Tensor:
        """L_clip per pose. With ``weight`` > 0 (and grad enabled), ``weight * L_clip`` is back-propagated
        through the renderer to the poses; otherwise forward only."""
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
            value = losses.clip_loss(emb, goal_embeddings)
            if grad:
                (image_grad,) = torch.autograd.grad(value.sum() * weight, leaf)
        self.clip_images += batch * views
        if grad:
            with self.clock.time("render"):
                images.backward(image_grad)
        return value.detach()

    def score(self, poses: Poses, weights: Phase, cameras: Cameras, goal_embeddings: torch.Tensor | None = None,
              batch: int | None = None, *, encode: bool = True) -> dict[str, torch.Tensor]:
        """Every term and the objective of ``poses`` on ``cameras``, forward only, ``batch`` poses per call.

        ``cameras`` are (1, C) shared by every pose (a per-view goal is then encoded once for all) or
        (len(poses), C) per pose; ``goal_embeddings`` are the goal's, precomputed: for shared cameras, or
        (len(poses), C, D) per pose (poses that share cameras share their goal's images: the tile stage).
        ``encode`` False (or a run not ``guided``): the geometry's terms only, ``clip`` 0, nothing rendered.
        """
        with torch.inference_mode():
            out = self._score(poses, weights, cameras, goal_embeddings, batch, encode and self.guided)
        return {k: v.clone() for k, v in out.items()}  # normal tensors, usable outside inference mode

    def _score(self, poses: Poses, weights: Phase, cameras: Cameras | None, goal_embeddings: torch.Tensor | None,
               batch: int | None, encode: bool, points: int | None = None) -> dict[str, torch.Tensor]:
        """``score``'s work, without inference mode or copies; ``cameras`` may be None where nothing is encoded,
        ``points``: the geometry on that many source samples (``geometry``)."""
        shared = cameras is not None and cameras.fov_deg.shape[0] == 1
        if encode and shared and goal_embeddings is None:
            goal_embeddings = self.embed_goal(cameras)
        step = batch or len(poses)
        parts: list[dict[str, torch.Tensor]] = []
        for lo in range(0, len(poses), step):
            chunk = poses.select(slice(lo, lo + step))
            terms = self.geometry(chunk, weights, points)
            del terms["centroid"]
            if encode:
                cams = cameras.expand(len(chunk)) if shared else cameras.rows(lo, lo + step)
                terms["clip"] = self.clip_term(chunk, cams, goal_rows(goal_embeddings, slice(lo, lo + step), shared))
            else:
                terms["clip"] = torch.zeros_like(terms["icp"])
            parts.append(terms)
        out = {k: torch.cat([p[k] for p in parts]) for k in parts[0]}
        out["objective"] = combine(out, weights)
        return out

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

    def evaluate(self, poses: Poses, weights: Phase, clip: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """The selection objective on the fixed evaluation views, for any number of poses. ``clip``: the guide's
        term of these poses on these views, already known (a phase starts from the poses the last one ended
        with evaluated): only the geometry is computed again, under this phase's weights."""
        with self.clock.time("eval"):
            cams, goal_embeddings = self.evaluation_cameras()
            if clip is None:
                return self.score(poses, weights, cams, goal_embeddings)
            out = self.score(poses, weights, cams, encode=False)
        out["clip"] = clip.clone()
        out["objective"] = combine(out, weights)
        return out


