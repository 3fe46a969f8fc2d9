"""The align entry point: the one function the CLI, the worker and the bench call.

``align(target, source, prompt, config)`` takes meshes in their *file frames* (as ``io.load_mesh``
returns them) and returns an ``AlignResult`` whose transform maps the source file frame to the target
file frame. Everything in between (normalisation, canonical pose, optimisation) is internal.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
import trimesh

from ctp_core import frames, priors
from ctp_core.config import AlignConfig
from ctp_core.errors import ConfigError
from ctp_core.progress import CancelCheck, ProgressCallback, ProgressEvent

__all__ = ["AlignResult", "ProgressEvent", "align"]


@dataclass
class AlignResult:
    """The answer in file frames, plus what a report and an export need."""

    source_to_target: np.ndarray  # (4, 4): p_target_file = M @ [p_source_file; 1]
    objective: float
    target: trimesh.Trimesh | trimesh.Scene  # file frame, untouched (a scene: the objects placed so far)
    source: trimesh.Trimesh  # source file frame (apply source_to_target to place it)
    prompt: str | None
    config: AlignConfig
    hparams: dict[str, Any]
    restarts: list[dict[str, Any]]
    timings: dict[str, float]
    preview: np.ndarray | None = None  # (V, H, W, 3) uint8 views of the final scene
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def transform(self) -> frames.Similarity:
        """The answer as a named similarity: source file frame -> target file frame."""
        return frames.Similarity(self.source_to_target, frames.SOURCE_FILE, frames.TARGET_FILE)

    @property
    def scale(self) -> float:
        return self.transform.scale

    @property
    def rotation(self) -> np.ndarray:
        return self.transform.rotation

    @property
    def translation(self) -> np.ndarray:
        return self.transform.translation




def align(
    target: trimesh.Trimesh | trimesh.Scene,
    source: trimesh.Trimesh,
    prompt: str | None,
    config: AlignConfig,
    *,
    on: str | None = None,
    image: np.ndarray | None = None,
    target_name: str = "target",
    source_name: str = "source",
    guide=None,
    guidance=None,
    init: np.ndarray | None = None,
    on_event: ProgressCallback | None = None,
    should_cancel: CancelCheck | None = None,
) -> AlignResult:
    """Place ``source`` relative to ``target`` (both in file frames) so renders agree with the prompt.

    ``image`` (H, W, 3 uint8) guides by a reference picture instead of the text; ``guidance`` (a
    ``targets`` object) overrides both (the benchmark's oracle). ``guide`` is a preloaded
    vision-language model (``guidance.get_guide``); without one the configured model is loaded (and
    cached per process). ``init`` (4x4, source file -> target file) replaces the first random start.
    A ``trimesh.Scene`` target is a scene of placed objects (``scene.objects``): ``on`` names the one
    the source relates to (soft-ICP attaches to it; ``target_name`` and its size feed the priors), while
    renders and the penetration term see them all.
    Raises ``errors.Canceled`` when ``should_cancel()`` turns true, other ``CtpError`` on bad input.
    """
    from ctp_core import guidance as guidance_mod
    from ctp_core import optimise, scene, schedule, targets

    started = time.perf_counter()
    if config.threads:
        torch.set_num_threads(config.threads)
    if config.device == "cuda" and not torch.cuda.is_available():
        raise ConfigError("device 'cuda' was requested but no CUDA device is available", field="device")
    prior = priors.resolve_priors(
        priors.get_provider(config.hparams_provider), target_name, source_name, prompt or "",
        size_ratio=config.size_ratio, contact_ratio=config.contact_ratio,
        penetration={"auto": None, "allow": True, "forbid": False}[config.penetration],
        target_extent=float(scene.attachment(target, on).extents.max()), source_extent=float(source.extents.max()),
    )
    judge = None
    if config.upright and config.upright_judge:
        guide = guide or guidance_mod.guide_for(config)
        # a scene's up is its base's (scene.base), judged under the base's own name
        base_name, base = (target_name, target) if isinstance(target, trimesh.Trimesh) else scene.objects(target)[0]
        judge = scene.upright_judge(base, guide, base_name, device=config.device)
    pair = scene.prepare_pair(target, source, samples=config.loss.samples, seed=config.seed, device=config.device,
                              canonicalise=config.upright, judge=judge, on=on)
    prepared = time.perf_counter()

    if guidance is None and config.loss.lambda_clip > 0:
        if image is not None:
            guidance = targets.ImageTarget(image)
        elif prompt:
            guidance = targets.TextTarget(prompt)
    if guidance is not None and config.loss.lambda_clip > 0:
        guide = guide or guidance_mod.guide_for(config)
        guidance.prepare(pair, guide)
    else:
        guidance = None
    loaded = time.perf_counter()

    generator = torch.Generator().manual_seed(config.seed)
    start = optimise.initial_poses(pair, config, prior.size_ratio, generator, init=init)
    plan = schedule.phases(config, allow_penetration=prior.penetration)
    problem = optimise.Problem(pair, config, prior.contact_ratio, guide=guide, target=guidance)
    runner = optimise.Optimiser(problem, plan, on_event=on_event, should_cancel=should_cancel)
    outcome = runner.run(start)

    matrices = outcome.poses.matrices()
    answers = [pair.source_to_target(m) for m in matrices]
    preview = scene.render_pair(pair, matrices[outcome.best], views=4, image_size=224)
    preview = (preview.permute(0, 2, 3, 1).clamp(0, 1).cpu().numpy() * 255).round().astype(np.uint8)
    timings = {f"optimise_{k}_s": round(v, 3) for k, v in outcome.timings.items()}
    timings.update(prepare_s=round(prepared - started, 3), model_s=round(loaded - prepared, 3),
                   total_s=round(time.perf_counter() - started, 3))
    restarts = [
        {"restart": i, "objective": float(outcome.objectives[i]),
         **{k: float(v[i]) for k, v in outcome.terms.items()}, "source_to_target": answers[i].tolist()}
        for i in range(len(answers))
    ]
    result = AlignResult(
        source_to_target=answers[outcome.best], objective=float(outcome.objectives[outcome.best]),
        target=target, source=source, prompt=prompt, config=config,
        hparams={**prior.to_dict(), "target_name": target_name, "source_name": source_name},  # what they read
        restarts=restarts, timings=timings, preview=preview,
        extra={
            "best_restart": outcome.best,
            "on": on,
            "guidance": guidance.description if guidance is not None else "none (geometry only)",
            "model": config.model if guidance is not None else None,
            "runtime": guide.runtime if guide is not None else None,
            "clip_images": outcome.clip_images,
            "phase_timings": [{k: round(v, 3) for k, v in p.items()} for p in outcome.phase_timings],
            "target_upright": {"rotation": pair.target_upright.rotation.tolist(),
                               "changed": pair.target_upright.changed, "reason": pair.target_upright.reason},
        },
    )
    if on_event:
        on_event(ProgressEvent(kind="done", phase=len(plan), phases=len(plan), step=outcome.steps_run,
                               steps=runner.total_steps, restarts=config.optim.restarts,
                               elapsed_s=time.perf_counter() - started, eta_s=0.0,
                               best_objective=result.objective, message="done"))
    return result
