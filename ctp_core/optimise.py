"""The phased, multi-restart pose optimiser (../shared/docs/method.md, "Optimise" and "Select").

All restarts are one batch: one render call renders restarts x views, one guide call embeds them, and
the losses return one value per restart. Each phase starts from every restart's best pose so far with
a fresh Adam; the best pose per restart is judged on fixed evaluation views (never the random
training views) by ``ordering.improves``. The answer is the restart ``ordering.select_answer`` picks among those
poses (``Optimiser.answer``): the relation first, near the target, then the objective (with a guide, soft-ICP
left out among those that touch), so not always the lowest objective; the progress readout describes that
restart too.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import torch

from ctp_core.config import AlignConfig
from ctp_core.config.schedule import Phase
from ctp_core.contact import clearance, contact_gap, touch_limit
from ctp_core.errors import Canceled
from ctp_core.geometry.pose import (
    Poses,
    matrix_to_quaternion,
    quaternion_product,
    random_quaternions,
    upright_twist,
)
from ctp_core.objective import Scorer, Terms
from ctp_core.pairs import PreparedPair
from ctp_core.progress import CancelCheck, ProgressCallback, ProgressEvent
from ctp_core.render.cameras import sample_training_views
from ctp_core.search.ordering import GuideSay, holding, improves, select_answer

# ``Adam``: torch.optim.Adam's defaults, its single-tensor CPU update operation for operation, and the learning rate
# of torch.optim.lr_scheduler.CosineAnnealingWarmRestarts (eta_min 0): on the CPU the poses come out bit for bit the
# same. Not torch.optim itself: its first optimiser in a process imports torch._dynamo (two to five seconds on a
# 2-core machine) for nothing three small tensors need, and a command-line placement pays that in every process.
ADAM_BETAS = (0.9, 0.999)
ADAM_EPS = 1e-8


class Adam:
    """Adam over parameter groups of one tensor and one base learning rate each, the rate on a cosine schedule
    with warm restarts (first period ``t0`` steps, each next ``t_mult`` times longer)."""

    def __init__(self, groups: list[tuple[torch.Tensor, float]], t0: int, t_mult: int = 1):
        self.params = [p for p, _ in groups]
        self.base_lrs = [float(lr) for _, lr in groups]
        self.lrs = list(self.base_lrs)  # each group's current rate
        self._steps = [0] * len(groups)
        self._exp_avg = [torch.zeros_like(p, memory_format=torch.preserve_format) for p in self.params]
        self._exp_avg_sq = [torch.zeros_like(p, memory_format=torch.preserve_format) for p in self.params]
        self._t_i, self._t_cur, self._t_mult = t0, 0, t_mult

    def zero_grad(self) -> None:
        for p in self.params:
            p.grad = None

    @torch.no_grad()
    def step(self) -> None:
        """One update of every parameter that has a gradient, at the current rates."""
        beta1, beta2 = ADAM_BETAS
        for i, param in enumerate(self.params):
            grad = param.grad
            if grad is None:
                continue
            self._steps[i] += 1
            step = float(self._steps[i])
            exp_avg, exp_avg_sq = self._exp_avg[i], self._exp_avg_sq[i]
            exp_avg.lerp_(grad, 1 - beta1)
            exp_avg_sq.mul_(beta2).addcmul_(grad, grad, value=1 - beta2)
            bias_correction1 = 1 - beta1**step
            bias_correction2 = 1 - beta2**step
            step_size = self.lrs[i] / bias_correction1
            denom = (exp_avg_sq.sqrt() / bias_correction2**0.5).add_(ADAM_EPS)
            param.addcdiv_(exp_avg, denom, value=-step_size)

    def schedule(self) -> None:
        """Advance the cosine schedule by one step (after ``step``)."""
        self._t_cur += 1
        if self._t_cur >= self._t_i:
            self._t_cur = self._t_cur % self._t_i
            self._t_i = self._t_i * self._t_mult
        cosine = 1 + math.cos(math.pi * self._t_cur / self._t_i)
        self.lrs = [base * cosine / 2 for base in self.base_lrs]


@dataclass
class Outcome:
    best: int  # the answer's restart (``Optimiser.answer``: ``ordering.select_answer``), not the lowest objective's
    poses: Poses  # best pose of every restart
    objectives: torch.Tensor  # (B,) on the evaluation views, last phase's weights
    terms: Terms  # the best poses' terms on the evaluation views, the last phase's weights
    timings: dict[str, float]
    phase_timings: list[dict[str, float]]
    clip_images: int
    steps_run: int = 0
    say: GuideSay | None = None  # the search's say the refinement and the selection ran under; None: not measured


def initial_poses(pair: PreparedPair, config: AlignConfig, log_s: float, generator: torch.Generator,
                  init: np.ndarray | None = None) -> Poses:
    """Random starts (the method's "Initialise"): direction uniform, distance 2-4 target radii, scale ``log_s``.

    Rotations are uniformly random in the ``paper`` spirit when ``optim.init_rotation == "random"``;
    otherwise each start is the source's own upright frame turned about +Y, which keeps the source
    upright as CLIP expects. ``init`` (source file -> target file 4x4) replaces restart 0's position and
    rotation; rigid, its scale is every restart's (the files' relative size, or the caller's), while in scale
    mode every start keeps ``log_s`` (the priors' or the geometry's: ``scaling``), never an incoming pose's.
    """
    count = config.optim.restarts
    direction = torch.randn(count, 3, generator=generator)
    direction = direction / direction.norm(dim=1, keepdim=True)
    lo, hi = config.optim.init_distance
    distance = (lo + (hi - lo) * torch.rand(count, generator=generator)) * pair.target_radius
    t = direction * distance[:, None]
    if config.optim.init_rotation == "random":
        q = random_quaternions(count, generator)
    else:
        yaw = torch.rand(count, generator=generator) * 2 * math.pi
        q_yaw = torch.stack([torch.cos(yaw / 2), 0 * yaw, torch.sin(yaw / 2), 0 * yaw], dim=1)
        q_up = torch.as_tensor(matrix_to_quaternion(pair.source_upright.rotation), dtype=torch.float32)
        q = quaternion_product(q_yaw, q_up.expand(count, 4))
    log_s = torch.full((count,), float(log_s))
    if init is not None:
        m = pair.local_to_normalised(init)
        scale = float(np.cbrt(np.linalg.det(m[:3, :3])))
        t[0] = torch.tensor(np.array(m[:3, 3]), dtype=torch.float32)  # m may be read-only
        q[0] = torch.as_tensor(matrix_to_quaternion(m[:3, :3] / scale), dtype=torch.float32)
        if not config.scale:
            log_s = torch.full((count,), math.log(scale))
    device = pair.source_vertices.device
    return Poses(t.to(device), q.to(device), log_s.to(device))


class Optimiser:
    """Runs the phase plan over a batch of restarts; one instance per run. ``say``: the search's
    (``coarse_to_fine.Ranked.say``; None: not measured), which sets what the scorer encodes and how the answer is
    selected."""

    def __init__(self, scorer: Scorer, plan: list[Phase], on_event: ProgressCallback | None = None,
                 should_cancel: CancelCheck | None = None, say: GuideSay | None = None):
        self.scorer = scorer.with_say(say)  # its ``say`` is the one the selection and the outcome read
        self.plan = plan
        self.on_event = on_event or (lambda event: None)
        self.should_cancel = should_cancel or (lambda: False)
        cfg = self.scorer.config
        self.generator = torch.Generator().manual_seed(cfg.seed)
        self.clip_gradient = self.scorer.guided and not cfg.loss.selection_only
        self.clock = self.scorer.clock
        self.total_steps = sum(p.steps for p in plan)
        self.done = 0
        self.restarts = 0  # set by run(): the batch it is given (the search may keep fewer or add some)
        self.start = time.perf_counter()
        self._clock_start = self.clock.mark()  # the scorer's clock may have run before (the search)

    # -- loop ----------------------------------------------------------------------------------------
    def run(self, start: Poses) -> Outcome:
        self.restarts = len(start)
        best = self._standing(start.detached())
        phase_timings = []
        scores: Terms | None = None
        answer = 0
        for phase in self.plan:
            before, t0 = self.clock.mark(), time.perf_counter()
            self._emit("phase_start", phase, message=f"phase {phase.index}/{len(self.plan)}")
            best, scores = self._phase(phase, best, None if scores is None else scores.clip)
            phase_timings.append(self.clock.since(before, t0))
            answer = self.answer(best, scores, phase)  # the last phase's: the run's answer
            self._emit("phase_end", phase, **self._readout(best, scores, answer))
        assert scores is not None  # a plan has at least one phase
        totals = self.clock.since(self._clock_start, self.start)
        return Outcome(
            best=answer, poses=best, objectives=scores.objective, terms=scores, timings=totals,
            phase_timings=phase_timings, clip_images=self.scorer.clip_images, steps_run=self.done,
            say=self.scorer.say,
        )

    def _phase(self, phase: Phase, start: Poses, clip: torch.Tensor | None) -> tuple[Poses, Terms]:
        """One phase from ``start`` (each restart's best so far); ``clip``: their guide's term on the evaluation
        views, known when an earlier phase evaluated them (None in the first)."""
        cfg = self.scorer.config
        t = start.t.clone().requires_grad_(True)
        q = start.q.clone().requires_grad_(True)
        log_s = start.log_s.clone().requires_grad_(cfg.scale)
        groups = [(t, cfg.optim.lr_translation), (q, cfg.optim.lr_rotation)]
        if cfg.scale and cfg.optim.lr_scale > 0:
            groups.append((log_s, cfg.optim.lr_scale))
        opt = Adam(groups, cfg.optim.cosine_t0, cfg.optim.cosine_t_mult)
        best = start.detached()
        scores = self.scorer.evaluate(best, phase, clip)
        for step in range(phase.steps):
            if self.should_cancel():
                raise Canceled("the run was cancelled")
            opt.zero_grad()
            poses = Poses(t, q, log_s)
            geo = self.scorer.geometry(poses, phase)
            last = {"icp": geo.icp.detach(), "pen": geo.pen.detach(), "rel": geo.rel.detach()}
            if self.clip_gradient:
                with torch.no_grad():
                    look_at = phase.look_at_beta * geo.centroid  # target centre is the origin
                cams = sample_training_views(look_at, cfg.camera, phase.zoom, self.generator)
                last["clip"] = self.scorer.clip_term(poses, cams, weight=phase.lambda_clip)
            with self.clock.time("geometry"):
                # the objective without the guide's term (its gradient went back in ``clip_term``); the relation's
                # terms pull toward where it holds
                geo.objective.sum().backward()
            opt.step()
            self._perturb(opt)
            if self.scorer.pair.source_keeps_up:
                with torch.no_grad():
                    q.copy_(upright_twist(q, self.scorer.pair.source_up_quaternion))
            opt.schedule()
            self.done += 1
            if (step + 1) % cfg.optim.eval_every == 0 or step + 1 == phase.steps:
                current = Poses(t, q, log_s).detached()
                now = self.scorer.evaluate(current, phase)
                better = improves(now, scores)
                best = current.where(better, best)
                scores = now.where(better, scores)
            if (step + 1) % cfg.progress_every == 0 or step + 1 == phase.steps:
                losses_now = {k: float(v.mean()) for k, v in last.items()}
                readout = self._readout(best, scores, self.answer(best, scores, phase))
                self._emit("step", phase, losses=losses_now, **readout)
        return best, scores

    def _standing(self, poses: Poses) -> Poses:
        """``poses`` with each rotation the nearest that keeps the source standing (``pose.upright_twist``) where the
        source keeps its up (``PreparedPair.source_keeps_up``): its rotation is then a turn about +Y alone, before
        the first step and after every one."""
        pair = self.scorer.pair
        if not pair.source_keeps_up:
            return poses
        return Poses(poses.t, upright_twist(poses.q, pair.source_up_quaternion.to(poses.q.device)), poses.log_s)

    def answer(self, best: Poses, scores: Terms, phase: Phase) -> int:
        """The restart whose best pose is the answer (``ordering.select_answer`` under ``phase``'s weights and the
        search's say): after the last phase the run's (``Outcome.best``), before it the answer were the run to
        stop there. Not the lowest objective: the selection orders by the relation first, leaves out restarts far
        from the target and, with a guide, soft-ICP among those that touch."""
        scorer = self.scorer
        return select_answer(scores, clearance(scorer.pair, scorer.pair.index, best), touch_limit(scorer.pair, best),
                             phase, guided=scorer.use_clip, touches=scorer.contact_ratio > 0,
                             share=scorer.config.search.min_share, say=scorer.say)

    def _readout(self, best: Poses, scores: Terms, i: int) -> dict:
        """The progress figures of restart ``i`` (the one the run would answer with now) on the
        evaluation views: its objective, and what a person reads instead of it (its scale changes with each
        phase's weights): its match to the guide (mean cosine; none without one, or with one whose say is 0) and
        its gap to the target (source diagonals, within the target samples' spacing), and in how many restarts
        the prompt's relation holds."""
        scorer = self.scorer
        gap = contact_gap(scorer.pair, best.select(slice(i, i + 1)))
        reading = scorer.reading
        return {"restart": i, "best_objective": float(scores.objective[i]), "contact_gap": float(gap[0]),
                "guide_match": -float(scores.clip[i]) if scorer.guided else None,
                "relation": reading.name if reading is not None else None,
                "relation_holds": int(holding(scores).sum()) if reading is not None else None,
                "relation_checked": len(best) if reading is not None else None}

    def _perturb(self, opt: Adam) -> None:
        """Zero-mean Gaussian pose noise after each step, sigma = noise * current lr (the method's)."""
        scale = self.scorer.config.optim.noise
        if scale <= 0:
            return
        with torch.no_grad():
            for p, lr in zip(opt.params, opt.lrs, strict=True):
                noise = torch.randn(p.shape, generator=self.generator).to(p.device)
                p.add_(noise * (scale * lr))

    def _emit(self, kind, phase: Phase, **fields) -> None:
        elapsed = time.perf_counter() - self.start
        eta = elapsed / self.done * (self.total_steps - self.done) if self.done else None
        self.on_event(ProgressEvent(kind=kind, phase=phase.index, phases=len(self.plan), step=self.done,
                                    steps=self.total_steps, restarts=self.restarts,
                                    elapsed_s=elapsed, eta_s=eta, **fields))
