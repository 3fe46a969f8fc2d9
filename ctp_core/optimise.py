"""The phased, multi-restart pose optimiser (method.md "Optimise" and "Select").

All restarts are one batch: one render call renders restarts x views, one guide call embeds them, and
the losses return one value per restart. Each phase starts from every restart's best pose so far with
a fresh Adam; the best pose per restart is judged on fixed evaluation views (never the random
training views), and the answer is the best restart by that objective.
"""

from __future__ import annotations

import math
import time
from collections import defaultdict
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np
import torch

from ctp_core import losses, render
from ctp_core.cameras import Cameras, evaluation_views, sample_training_views
from ctp_core.config import AlignConfig
from ctp_core.errors import Canceled
from ctp_core.guidance import Guide
from ctp_core.pose import apply_pose, matrix_to_quaternion, pose_matrix, random_quaternions
from ctp_core.progress import CancelCheck, ProgressCallback, ProgressEvent
from ctp_core.scene import PreparedPair
from ctp_core.schedule import Phase
from ctp_core.targets import GuidanceTarget


@dataclass
class Poses:
    """A batch of poses, source local -> normalised (see ``pose``)."""

    t: torch.Tensor  # (B, 3)
    q: torch.Tensor  # (B, 4)
    log_s: torch.Tensor  # (B,)

    def detached(self) -> Poses:
        return Poses(self.t.detach().clone(), self.q.detach().clone(), self.log_s.detach().clone())

    def where(self, mask: torch.Tensor, other: Poses) -> Poses:
        """Per restart: self where mask, else other."""
        pick = lambda a, b: torch.where(mask.reshape(-1, *[1] * (a.dim() - 1)), a, b)  # noqa: E731
        return Poses(pick(self.t, other.t), pick(self.q, other.q), pick(self.log_s, other.log_s))

    def matrices(self) -> np.ndarray:
        return pose_matrix(self.t, self.q, self.log_s).detach().cpu().double().numpy()


@dataclass
class Problem:
    """What stays fixed during a run."""

    pair: PreparedPair
    config: AlignConfig
    contact_ratio: float
    guide: Guide | None = None
    target: GuidanceTarget | None = None  # None: no vision-language term at all


@dataclass
class Outcome:
    best: int  # index of the chosen restart
    poses: Poses  # best pose of every restart
    objectives: torch.Tensor  # (B,) on the evaluation views, last phase's weights
    terms: dict[str, torch.Tensor]  # (B,) each: clip, icp, pen of the best poses
    timings: dict[str, float]
    phase_timings: list[dict[str, float]]
    clip_images: int
    steps_run: int = 0
    trace: list[dict] = field(default_factory=list)


def initial_poses(pair: PreparedPair, config: AlignConfig, size_ratio: float, generator: torch.Generator,
                  init: np.ndarray | None = None) -> Poses:
    """Random starts (method.md "Initialise"): direction uniform, distance 2-4 target radii.

    Rotations are uniformly random in the ``paper`` spirit when ``optim.init_rotation == "random"``;
    otherwise each start is the source's own upright frame turned about +Y, which keeps the source
    upright as CLIP expects. ``init`` (source file -> target file 4x4) replaces restart 0 and fixes the
    scale of all restarts (the benchmark's perturbation protocol).
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
    if config.scale:
        extent = float((pair.source_vertices.max(0).values - pair.source_vertices.min(0).values).max())
        log_s = torch.full((count,), math.log(size_ratio * 2.0 / max(extent, 1e-9)))
    else:
        log_s = torch.zeros(count)
    if init is not None:
        m = pair.local_to_normalised(init)
        scale = float(np.cbrt(np.linalg.det(m[:3, :3])))
        t[0] = torch.tensor(np.array(m[:3, 3]), dtype=torch.float32)  # m may be read-only
        q[0] = torch.as_tensor(matrix_to_quaternion(m[:3, :3] / scale), dtype=torch.float32)
        log_s = torch.full((count,), math.log(scale))
    device = pair.source_vertices.device
    return Poses(t.to(device), q.to(device), log_s.to(device))


def quaternion_product(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product a*b of (..., 4) quaternions, w first (rotation b then a)."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], dim=-1)


class _Clock:
    """Wall time per component (render / clip / geometry / eval).

    Spans do not nest: time inside an outer span (e.g. the render inside an evaluation) counts for
    the outer one only, so the parts add up to the total.
    """

    def __init__(self):
        self.totals: dict[str, float] = defaultdict(float)
        self._active = False

    @contextmanager
    def time(self, key: str):
        if self._active:
            yield
            return
        self._active = True
        start = time.perf_counter()
        try:
            yield
        finally:
            self.totals[key] += time.perf_counter() - start
            self._active = False


class Optimiser:
    """Runs the phase plan over a batch of restarts; one instance per run."""

    def __init__(self, problem: Problem, plan: list[Phase], on_event: ProgressCallback | None = None,
                 should_cancel: CancelCheck | None = None):
        self.problem = problem
        self.plan = plan
        self.on_event = on_event or (lambda event: None)
        self.should_cancel = should_cancel or (lambda: False)
        cfg = problem.config
        self.generator = torch.Generator().manual_seed(cfg.seed)
        self.use_clip = problem.target is not None and problem.guide is not None and cfg.loss.lambda_clip > 0
        self.clip_gradient = self.use_clip and not cfg.loss.selection_only
        self.clip_images = 0
        self.clock = _Clock()
        self.total_steps = sum(p.steps for p in plan)
        self.done = 0
        self.start = time.perf_counter()
        self._eval_cameras: Cameras | None = None
        self._eval_targets: torch.Tensor | None = None

    # -- terms ---------------------------------------------------------------------------------------
    def geometry(self, poses: Poses, phase: Phase) -> dict[str, torch.Tensor]:
        cfg = self.problem.config.loss
        pair = self.problem.pair
        with self.clock.time("geometry"):
            pts = apply_pose(pair.source_samples, poses.t, poses.q, poses.log_s)
            icp = losses.soft_icp(pts, pair.anchor, self.problem.contact_ratio, phase.sigma_icp, cfg.icp_neighbours)
            if phase.lambda_pen > 0:
                pen = losses.penetration(pts, pair.index, cfg.sigma_pen, cfg.c_pen, cfg.icp_neighbours)
            else:
                pen = torch.zeros_like(icp)
        return {"icp": icp, "pen": pen, "centroid": pts.mean(dim=1)}

    def clip_term(self, poses: Poses, cameras: Cameras, targets: torch.Tensor | None = None,
                  grad: bool = True) -> tuple[torch.Tensor, torch.Tensor | None]:
        """L_clip per restart; with grad, also the image gradient pushed back through the renderer."""
        pair, guide = self.problem.pair, self.problem.guide
        with self.clock.time("render"):
            verts = pair.scene_vertices(apply_pose(pair.source_vertices, poses.t, poses.q, poses.log_s))
            images = render.render(pair.mesh, verts, cameras)
        batch, views = images.shape[:2]
        with self.clock.time("clip"):
            if targets is None:
                targets = self.problem.target.embeddings(cameras)
            leaf = images.detach().requires_grad_(grad)
            emb = guide.encode_images(leaf.reshape(batch * views, *images.shape[2:])).reshape(batch, views, -1)
            value = losses.clip_loss(emb, targets)
            image_grad = None
            if grad:
                (image_grad,) = torch.autograd.grad(value.sum() * self.problem.config.loss.lambda_clip, leaf)
        self.clip_images += batch * views
        if grad:
            with self.clock.time("render"):
                images.backward(image_grad)
        return value.detach(), image_grad

    @torch.no_grad()
    def evaluate(self, poses: Poses, phase: Phase) -> dict[str, torch.Tensor]:
        """The selection objective on fixed evaluation views (no noise from random cameras)."""
        with self.clock.time("eval"):
            terms = self.geometry(poses, phase)
            del terms["centroid"]
            objective = phase.lambda_icp * terms["icp"] + phase.lambda_pen * terms["pen"]
            if self.use_clip:
                if self._eval_cameras is None:
                    origin = torch.zeros(len(poses.t), 3, device=poses.t.device)
                    self._eval_cameras = evaluation_views(origin, self.problem.config.camera)
                    self._eval_targets = self.problem.target.embeddings(self._eval_cameras)
                clip, _ = self.clip_term(poses, self._eval_cameras, self._eval_targets, grad=False)
                terms["clip"] = clip
                objective = objective + phase.lambda_clip * clip
            else:
                terms["clip"] = torch.zeros_like(objective)
        terms["objective"] = objective
        return terms

    # -- loop ----------------------------------------------------------------------------------------
    def run(self, start: Poses) -> Outcome:
        best = start.detached()
        phase_timings = []
        scores: dict[str, torch.Tensor] = {}
        for phase in self.plan:
            before = dict(self.clock.totals)
            t0 = time.perf_counter()
            self._emit("phase_start", phase, message=f"phase {phase.index}/{len(self.plan)}")
            best, scores = self._phase(phase, best)
            split = {k: v - before.get(k, 0.0) for k, v in self.clock.totals.items()}
            split["total"] = time.perf_counter() - t0
            split["other"] = split["total"] - sum(v for k, v in split.items() if k != "total")
            phase_timings.append(split)
            self._emit("phase_end", phase, best_objective=float(scores["objective"].min()))
        objectives = scores["objective"]
        totals = dict(self.clock.totals)
        totals["total"] = time.perf_counter() - self.start
        totals["other"] = totals["total"] - sum(v for k, v in self.clock.totals.items())
        return Outcome(
            best=int(objectives.argmin()), poses=best, objectives=objectives,
            terms={k: scores[k] for k in ("clip", "icp", "pen")}, timings=totals,
            phase_timings=phase_timings, clip_images=self.clip_images, steps_run=self.done,
        )

    def _phase(self, phase: Phase, start: Poses) -> tuple[Poses, dict[str, torch.Tensor]]:
        cfg = self.problem.config
        t = start.t.clone().requires_grad_(True)
        q = start.q.clone().requires_grad_(True)
        log_s = start.log_s.clone().requires_grad_(cfg.scale)
        groups = [{"params": [t], "lr": cfg.optim.lr_translation},
                  {"params": [q], "lr": cfg.optim.lr_rotation}]
        if cfg.scale and cfg.optim.lr_scale > 0:
            groups.append({"params": [log_s], "lr": cfg.optim.lr_scale})
        opt = torch.optim.Adam(groups)
        sched = torch.optim.lr_scheduler.CosineAnnealingWarmRestarts(
            opt, T_0=cfg.optim.cosine_t0, T_mult=cfg.optim.cosine_t_mult)
        best = start.detached()
        scores = self.evaluate(best, phase)
        for step in range(phase.steps):
            if self.should_cancel():
                raise Canceled("the run was cancelled")
            opt.zero_grad(set_to_none=True)
            poses = Poses(t, q, log_s)
            geo = self.geometry(poses, phase)
            last = {"icp": geo["icp"].detach(), "pen": geo["pen"].detach()}
            if self.clip_gradient:
                with torch.no_grad():
                    look_at = phase.look_at_beta * geo["centroid"]  # target centre is the origin
                cams = sample_training_views(look_at, cfg.camera, phase.zoom, self.generator)
                last["clip"], _ = self.clip_term(poses, cams)
            with self.clock.time("geometry"):
                (phase.lambda_icp * geo["icp"] + phase.lambda_pen * geo["pen"]).sum().backward()
            opt.step()
            self._perturb(opt)
            sched.step()
            self.done += 1
            if (step + 1) % cfg.optim.eval_every == 0 or step + 1 == phase.steps:
                current = Poses(t, q, log_s).detached()
                now = self.evaluate(current, phase)
                better = now["objective"] < scores["objective"]
                best = current.where(better, best)
                scores = {k: torch.where(better, now[k], scores[k]) for k in scores}
            if (step + 1) % cfg.progress_every == 0 or step + 1 == phase.steps:
                losses_now = {k: float(v.mean()) for k, v in last.items()}
                self._emit("step", phase, losses=losses_now, best_objective=float(scores["objective"].min()))
        return best, scores

    def _perturb(self, opt: torch.optim.Optimizer) -> None:
        """Zero-mean Gaussian pose noise after each step, sigma = noise * current lr (method.md)."""
        scale = self.problem.config.optim.noise
        if scale <= 0:
            return
        with torch.no_grad():
            for group in opt.param_groups:
                for p in group["params"]:
                    noise = torch.randn(p.shape, generator=self.generator).to(p.device)
                    p.add_(noise * (scale * group["lr"]))

    def _emit(self, kind, phase: Phase, **fields) -> None:
        elapsed = time.perf_counter() - self.start
        eta = elapsed / self.done * (self.total_steps - self.done) if self.done else None
        self.on_event(ProgressEvent(kind=kind, phase=phase.index, phases=len(self.plan), step=self.done,
                                    steps=self.total_steps, restarts=self.problem.config.optim.restarts,
                                    elapsed_s=elapsed, eta_s=eta, **fields))
