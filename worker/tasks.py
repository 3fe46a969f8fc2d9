"""The rq tasks: take a queued job, run the engine on it, store its results or its error; and adjust a
succeeded job's result by hand (``run_adjustment``).

``run_job`` is the adapter (status, progress, leases, errors); ``align_job`` and ``assemble_job`` are
the calls into ``ctp_core``: bytes in, result files out. ``run_adjustment`` and ``adjust_job`` are the same
pair for an adjustment (``service.adjustments``).
"""

from __future__ import annotations

import gc
import json
import logging
from collections.abc import Callable
from contextlib import nullcontext
from dataclasses import dataclass
from typing import Any

import numpy as np
import trimesh
from rq.timeouts import JobTimeoutException

from ctp_core.adjust import Adjusted, adjust, read_back
from ctp_core.align import align
from ctp_core.assembly.adjusted import adjust_object
from ctp_core.assembly.assemble import Step, assemble, scene_of
from ctp_core.assembly.copies import place_copies, placed_copies, set_metrics
from ctp_core.assembly.plan import Also
from ctp_core.config import AUTO, AlignConfig
from ctp_core.errors import Canceled, ConfigError, CtpError, JobTooLarge, forget, out_of_memory
from ctp_core.export import (
    adjusted_copies_report,
    adjusted_report,
    adjusted_scene_report,
    arrangement_glb,
    assembly_glb,
    assembly_report,
    copies_glb,
    copies_report,
    preview_png,
    report,
    scene_glb,
    strip_png,
)
from ctp_core.guide import selection
from ctp_core.guide.loaders import guide_for
from ctp_core.guide.selection import GuideChoice
from ctp_core.io import MeshLimits, load_image, load_objects
from ctp_core.io.loader import MeshLoader
from ctp_core.progress import ProgressEvent
from ctp_core.reading.relation import RelationReading
from service.adjustments import AdjustmentRecord, Adjustments, AdjustOutcome
from service.jobs import (
    ORIGINAL,
    Alternative,
    JobError,
    JobRecord,
    Jobs,
    Progress,
    SavedAdjustment,
    Stage,
    Status,
    alternative_blob,
    now,
)
from service.redact import report_json
from service.settings import Settings
from service.storage import StorageUnavailable
from worker.main import context, where
from worker.memory import job_memory

log = logging.getLogger("ctp.worker")

# Optimiser events always published; step events are thinned (Heartbeat.publish).
_MILESTONES = {"phase_start", "phase_end", "done"}


@dataclass(frozen=True)
class JobContext:
    """What a job runs with on this worker besides its record: the bounded loader under the service limits,
    the callbacks to the job's record (progress, cancel) and the guide chosen for it."""

    loader: MeshLoader
    limits: MeshLimits
    on_progress: Callable[[Progress, bool], None]
    should_cancel: Callable[[], bool]
    choice: GuideChoice | None = None  # model auto's pick for this job (``job_guide``); None: chosen by the engine

    def load(self, data: bytes | None, filename: str) -> trimesh.Trimesh:
        """An upload, loaded in a loading process exactly as the API checked it."""
        return self.loader.load(data, filename=filename, limits=self.limits)

    def guide(self, config: AlignConfig, stage: Stage, image: bool = False):
        """The job's guidance model (process-cached: the one the worker preloaded is not loaded again), None when
        the run uses none (``selection.resolve``)."""
        config = selection.resolve(config, image=image, choice=self.choice)[0]
        if not config.uses_model:
            return None
        self.on_progress(Progress(stage=stage, kind="model", message=f"loading model {config.model}"), True)
        return guide_for(config)


def job_guide(record: JobRecord) -> tuple[GuideChoice | None, GuideChoice]:
    """Model auto's pick for a job, made once as a worker takes it (None: the job names its model), and the guide
    the job states (its record's): an assembly's is its first guided stage's."""
    auto = selection.choose() if record.config.model == AUTO else None
    runs = [(s.config, s.has_image) for s in record.steps] or [(record.config, record.has_image)]
    stated = [selection.resolve(config, image=image, choice=auto)[1] for config, image in runs]
    return auto, next((c for c in stated if c.guide != selection.NONE), stated[0])


def served(record: JobRecord, settings: Settings) -> JobRecord:
    """The job as this worker runs it: its configs (an assembly's and every stage's) with the worker's
    device, runtime and threads (``worker.main.where``) applied.

    The client's options were validated at submit, under the default device and runtime; a run that these
    settings cannot serve (a forward-only ``onnx:`` model on the torch runtime or on CUDA, an ONNX runtime on
    CUDA, more threads than a run may have) is the worker's to refuse, so it raises ``worker_cannot_serve``
    here, when the job is taken and before any mesh or model loads.
    """
    overrides = where(settings)
    shown = ", ".join(f"{key} {value} (CTP_{key.upper()})" for key, value in overrides.items() if value is not None)

    def run_here(config: AlignConfig) -> AlignConfig:
        try:
            return config.merged(overrides)
        except ConfigError as exc:
            raise CtpError(f"this worker runs jobs with {shown} and cannot serve this one: {exc.message}",
                           code="worker_cannot_serve") from None

    config = run_here(record.config)
    steps = [s.model_copy(update={"config": run_here(s.config)}) for s in record.steps]
    return record.model_copy(update={"config": config, "steps": steps})


def run_job(job_id: str) -> str:
    """rq entry point (by name, JSON-serialised id only); returns the job's final status."""
    ctx = context()
    record = ctx.jobs.start(job_id, ctx.name)
    if record is None:
        log.info("job skipped: no longer queued", extra={"job_id": job_id, "worker": ctx.name})
        return "skipped"
    log.info("job started", extra={"job_id": job_id, "worker": ctx.name})
    ctx.beat.begin(job_id)
    status: Status = "failed"
    error: JobError | None = None
    alternatives: list[Alternative] = []  # a succeeded alignment's best distinct placements (the record keeps them)
    stage = Stage(name="loading")  # the stage of the job's last progress: where an allocation failed
    budget_mb: int | None = None

    def on_progress(progress: Progress, force: bool) -> None:
        nonlocal stage
        stage = progress.stage
        ctx.beat.publish(progress, force=force)

    stored: list[str] = []  # the results written so far: a job handed back leaves none behind
    try:
        with job_memory(ctx.settings.job_memory_mb) as budget_mb:
            record = served(record, ctx.settings)
            auto, stated = job_guide(record)
            ctx.jobs.set_guide(job_id, stated.guide, stated.why)
            inputs = {name: ctx.jobs.storage.get(job_id, name) for name in record.inputs()}
            if inputs["target"] is None or inputs.get("source", inputs.get("source-0")) is None:
                raise CtpError("the job's uploads expired before a worker picked it up", code="inputs_expired")
            job = JobContext(loader=ctx.loader, limits=ctx.settings.mesh_limits, on_progress=on_progress,
                             should_cancel=lambda: ctx.stop.requested or ctx.jobs.should_stop(job_id, ctx.name),
                             choice=auto)
            files, alternatives = (assemble_job if record.kind == "assemble" else align_job)(record, inputs, job)
            for name, data in files.items():
                stored.append(name)
                ctx.jobs.storage.put(job_id, name, data)
            status = "succeeded"
    except Exception as exc:
        if ctx.stop.hands_back(exc) and ctx.jobs.hand_back(job_id, ctx.name) is not None:
            ctx.jobs.storage.delete(job_id, stored)
            log.info("job handed back", extra={"job_id": job_id, "worker": ctx.name, "code": _code(exc)})
            return "handed back"
        if isinstance(exc, Canceled):
            status, error = "canceled", JobError(code=exc.code, message="canceled while running")
        else:
            error = failure(exc, stage, budget_mb, "job", ctx.settings.job_timeout_s * record.stage_count,
                            {"job_id": job_id, "worker": ctx.name})
    finally:
        ctx.beat.end()
    if error is not None and error.code == JobTooLarge.code:
        gc.collect()  # frames in reference cycles: give their memory back before the next job
    ctx.jobs.finish(job_id, status, error, alternatives, ctx.name)
    return status


def run_adjustment(adjustment_id: str) -> str:
    """rq entry point of an adjustment (by name, JSON-serialised id only); returns its final status.

    Under the job memory ceiling and the job time limit like a job, but without a job lease: a reader of the
    adjustment fails it when its worker is gone (``Adjustments.get``). A save holds the job's adjust lock from
    reading the result to writing it."""
    ctx = context()
    adjustments = Adjustments(ctx.jobs)
    adjustment = adjustments.start(adjustment_id, ctx.name)
    if adjustment is None:
        return "skipped"
    log.info("adjustment started", extra={"job_id": adjustment.job, "adjustment": adjustment_id, "worker": ctx.name})
    outcome, error, budget_mb = None, None, None
    try:
        with (job_memory(ctx.settings.job_memory_mb) as budget_mb,
              adjustments.lock(adjustment.job) if adjustment.request.save else nullcontext()):
            outcome = adjust_job(adjustment, ctx.jobs, ctx.settings.mesh_limits)
    except Exception as exc:
        error = failure(exc, Stage(name="adjust"), budget_mb, "adjustment", ctx.settings.job_timeout_s,
                        {"job_id": adjustment.job, "adjustment": adjustment_id, "worker": ctx.name})
    status = "failed" if error is not None else "succeeded"
    adjustments.finish(adjustment_id, status, outcome, error)
    return status


def _code(exc: Exception) -> str:
    """What ended a job that was handed back, for its log line: the engine's code, else the exception's type."""
    return exc.code if isinstance(exc, CtpError) else type(exc).__name__


def failure(exc: Exception, stage: Stage, budget_mb: int | None, what: str, limit_s: int,
            extra: dict[str, str]) -> JobError:
    """The error ``what`` (a job, an adjustment) ends with when ``exc`` ends it (``limit_s``: its time limit):
    the engine's own code, the store's, the time limit, ``job_too_large`` for an allocation failure in ``stage``
    (the memory ceiling is lifted by now; what the work held is freed), else ``internal_error``, logged."""
    if isinstance(exc, CtpError):
        return JobError(**exc.to_dict())
    if isinstance(exc, StorageUnavailable):
        return JobError(code="storage_unavailable", message=str(exc))
    if isinstance(exc, JobTimeoutException):
        return JobError(code="job_timeout", message=f"the {what} ran over {limit_s} s")
    if out_of_memory(exc):
        forget(exc)
        error = too_large(exc, stage, budget_mb)
        log.warning("%s too large: %s", what, error.message, extra=extra)
        return error
    log.exception("%s crashed", what, extra=extra)
    return JobError(code="internal_error", message=f"{type(exc).__name__}: {exc}")


def adjust_job(adjustment: AdjustmentRecord, jobs: Jobs, limits: MeshLimits) -> AdjustOutcome:
    """Run ``ctp_core.adjust`` on a succeeded job's stored result (its inputs are gone by now): the scene read
    back from ``result.glb``, the frames and the relation from ``report.json``. With ``save``, the adjusted scene
    and report replace them (the run's own GLB kept once as ``original.glb``) and the job record says so."""
    record = jobs.get(adjustment.job)
    gone = CtpError(f"job {adjustment.job}'s results are gone (expired)", code="job_not_ready")
    if record is None or record.status != "succeeded":
        raise gone
    stored = {name: jobs.storage.get(adjustment.job, name) for name in ("result.glb", "report.json")}
    if None in stored.values():
        raise gone
    facts = json.loads(stored["report.json"])
    request = adjustment.request
    scene = load_objects(stored["result.glb"], filename="result.glb", limits=limits)
    if record.kind == "assemble":
        return _scene_adjusted(adjustment, record, jobs, scene, stored, facts)
    # the adjusted object: the source (the last node), or one of several copies (its node, judged as it was)
    copies = record.count > 1
    entry = facts["copies"][request.copy_index - 1] if copies else facts
    at = np.asarray(entry["transform"]["matrix"], dtype=np.float64)  # the stored result.glb's node
    target, source, name = read_back(scene, at, entry.get("name") if copies else None)
    upright = (facts.get("extra") or {}).get("target_upright")
    done = adjust(target, source, np.asarray(request.transform), record.config, settle=request.settle,
                  direction=request.direction, upright=None if upright is None else upright["rotation"],
                  on=entry["on"] if copies else (facts.get("extra") or {}).get("grounds") or record.on,
                  reading=RelationReading.from_verdict(entry.get("relation")))
    if request.save:
        saved_at = now()
        at_text = saved_at.isoformat(timespec="seconds")
        if copies:
            glb, report_ = _copies_saved(request.copy_index, facts, scene, source, done, at_text)
        else:
            glb, report_ = arrangement_glb(target, source, done.source_to_target, name), adjusted_report(
                facts, done, at=at_text)
        _save(adjustment, jobs, stored, glb, report_, SavedAdjustment(
            saved_at=saved_at, adjustment=adjustment.id, transform=done.source_to_target.tolist(),
            penetration=done.penetration, contact_gap=done.contact_gap))
    return AdjustOutcome(transform=done.source_to_target.tolist(), saved=request.save, **done.to_dict())


def _scene_adjusted(adjustment: AdjustmentRecord, record: JobRecord, jobs: Jobs, scene: trimesh.Scene,
                    stored: dict[str, bytes | None], facts: dict[str, Any]) -> AdjustOutcome:
    """An assembly's object adjusted (``assembly.adjusted``): every relation judged again; with ``save`` the scene
    with it there and its report replace the job's result."""
    request = adjustment.request
    done = adjust_object(scene, facts, request.object or "", np.asarray(request.transform),
                         [s.config for s in record.steps], settle=request.settle,
                         direction=None if request.direction is None else np.asarray(request.direction))
    if request.save:
        saved_at = now()
        report_ = adjusted_scene_report(facts, done, at=saved_at.isoformat(timespec="seconds"))
        glb = trimesh.exchange.gltf.export_glb(scene_of(done.objects))
        _save(adjustment, jobs, stored, glb, report_, SavedAdjustment(
            saved_at=saved_at, adjustment=adjustment.id, transform=done.adjusted.source_to_target.tolist(),
            penetration=done.adjusted.penetration, contact_gap=done.adjusted.contact_gap))
    return AdjustOutcome(transform=done.adjusted.source_to_target.tolist(), saved=request.save,
                         whole=done.whole, stands_on=done.stands_on, **done.adjusted.to_dict())


def _save(adjustment: AdjustmentRecord, jobs: Jobs, stored: dict[str, bytes | None], glb: bytes,
          report_: dict[str, Any], saved: SavedAdjustment) -> None:
    """An adjusted result stored as the job's: the run's own GLB kept once as ``original.glb``."""
    if jobs.storage.get(adjustment.job, ORIGINAL) is None:  # the run's own, kept through later saves
        jobs.storage.put(adjustment.job, ORIGINAL, stored["result.glb"])
    jobs.storage.put(adjustment.job, "result.glb", glb)
    jobs.storage.put(adjustment.job, "report.json", report_json(report_))
    jobs.mark_adjusted(adjustment.job, saved)


def _copies_saved(k: int, facts: dict[str, Any], scene: trimesh.Scene, source: trimesh.Trimesh, done: Adjusted,
                  at: str) -> tuple[bytes, dict[str, Any]]:
    """A copies job's result with copy ``k`` where ``done`` put it: the GLB again (the target and every copy under
    its matrix, ``copies.placed_copies``), and the report with that copy and the set's measures."""
    entries = facts["copies"]
    matrices = [np.asarray(c["transform"]["matrix"], dtype=np.float64) for c in entries]
    matrices[k - 1] = done.source_to_target
    verdicts = [c.get("relation") for c in entries]
    verdicts[k - 1] = done.relation
    target_name = facts["target_name"]
    placed = placed_copies(scene.geometry[target_name], target_name, source,
                           [(c["name"], m) for c, m in zip(entries, matrices, strict=True)])
    report_ = adjusted_copies_report(facts, k, done, set_metrics(source, matrices, verdicts), at=at)
    return trimesh.exchange.gltf.export_glb(scene_of(placed)), report_


def too_large(exc: BaseException, stage: Stage, budget_mb: int | None) -> JobError:
    """A ``job_too_large`` error for an allocation failure in ``stage`` (an assembly's: field ``steps.<i>``)."""
    where = stage.name if stage.count == 1 else f"{stage.name} of alignment {stage.index}/{stage.count}"
    error = JobTooLarge.of(exc, stage=where, budget_mb=budget_mb)
    if stage.count > 1 and stage.name in ("search", "refine"):
        error.field = f"steps.{stage.index - 1}"
    return JobError(**error.to_dict())


JobOutput = tuple[dict[str, bytes], list[Alternative]]  # a job's files (``service.jobs.OUTPUTS``), its alternatives


def align_job(record: JobRecord, inputs: dict[str, bytes | None], job: JobContext) -> JobOutput:
    """Run ``ctp_core.align`` on a job's uploads; returns ``result.glb``, ``report.json``, ``preview.png``, the other
    alternatives' GLBs and ``alternatives.png``, and the alternatives' summary for the job record.

    ``record`` is as ``served`` returns it: its config is the one this worker runs.
    """
    config = record.config
    if record.count > 1:
        return copies_job(record, inputs, job)
    job.on_progress(Progress(stage=Stage(name="loading"), kind="loading", message="loading meshes"), True)
    # A chained job's target is an earlier result scene (this service's own output), read back as its objects.
    if record.target_job:
        target = load_objects(inputs["target"], filename=record.target_file, limits=job.limits)
    else:
        target = job.load(inputs["target"], record.target_file)
    source = job.load(inputs["source"], record.source_file)
    image = load_image(inputs["image"]) if inputs.get("image") is not None else None
    guide = job.guide(config, Stage(name="model"), image is not None)

    def on_event(event: ProgressEvent) -> None:
        job.on_progress(progress_of(event), event.kind in _MILESTONES)

    result = align(target, source, record.prompt, config, on=record.on, image=image, target_name=record.target_name,
                   source_name=record.source_name, guide=guide, on_event=on_event, should_cancel=job.should_cancel,
                   choice=job.choice)
    job.on_progress(_exporting(config, objective=result.objective, restarts=len(result.restarts)), True)
    files = _results(scene_glb(result, source_name=record.source_name), report(result), result.preview)
    for k in range(1, len(result.alternatives)):  # the answer's is result.glb
        files[alternative_blob(k)] = scene_glb(result.alternative(k), source_name=record.source_name)
    if result.thumbnails is not None:
        files["alternatives.png"] = strip_png(result.thumbnails)
    return files, alternatives_of(result.alternatives)


def copies_job(record: JobRecord, inputs: dict[str, bytes | None], job: JobContext) -> JobOutput:
    """Run ``ctp_core.assembly.copies`` on a job of several copies: progress per copy (as an assembly's
    stages), the GLB with one node per copy, the report of every copy and the set, the preview; no
    alternatives."""
    config, count = record.config, record.count
    job.on_progress(Progress(stage=Stage(name="loading", count=count), kind="loading", message="loading meshes"), True)
    target = job.load(inputs["target"], record.target_file)
    source = job.load(inputs["source"], record.source_file)
    guide = job.guide(config, Stage(name="model", count=count))
    current = Stage(name="search", count=count)

    def on_copy(index: int, total: int) -> None:
        nonlocal current
        current = Stage(name="search", index=index, count=total, label=f"{record.source_name}_{index}")
        job.on_progress(Progress(stage=current, kind="phase_start", fraction=round((index - 1) / total, 4),
                                 message=f"copy {index}/{total}"), True)

    def on_event(event: ProgressEvent) -> None:
        job.on_progress(progress_of(event, current), event.kind in _MILESTONES)

    copies = place_copies(target, source, record.prompt, config, count=count, arrangement=record.arrangement or AUTO,
                          target_name=record.target_name, source_name=record.source_name, guide=guide,
                          on_event=on_event, on_copy=on_copy, should_cancel=job.should_cancel, choice=job.choice)
    job.on_progress(_exporting(config, current.model_copy(update={"name": "exporting"})), True)
    return _results(copies_glb(copies), copies_report(copies), copies.preview), []


def alternatives_of(alternatives: list[dict[str, Any]]) -> list[Alternative]:
    """The job record's summary of a result's ``AlignResult.alternatives`` (GET /jobs/{id})."""
    return [Alternative(index=k, objective=a["objective"], guide_match=None if not a.get("clip") else -a["clip"],
                        relation_holds=None if a.get("relation") is None else a["relation"]["holds"])
            for k, a in enumerate(alternatives)]


def assemble_job(record: JobRecord, inputs: dict[str, bytes | None], job: JobContext) -> JobOutput:
    """Run ``ctp_core.assembly.assemble`` on an assembly job (``record`` as ``served`` returns it): the model loaded
    once, progress per stage, the whole scene's GLB, report and preview out. A failure names its stage
    (message and field ``steps.<i>``)."""
    config = record.config
    count = record.stage_count
    job.on_progress(Progress(stage=Stage(name="loading", count=count), kind="loading", message="loading meshes"), True)
    base = job.load(inputs["target"], record.target_file)
    steps = [Step(source=job.load(inputs[f"source-{i}"], s.file), name=s.name, prompt=s.prompt, on=s.on,
                  config=s.config, also=[Also(a.prompt, tuple(a.on), a.relation) for a in s.also],
                  image=load_image(inputs[f"image-{i}"]) if inputs.get(f"image-{i}") is not None else None)
             for i, s in enumerate(record.steps)]
    model = Stage(name="model", count=count)
    guide = next((g for s in steps if (g := job.guide(s.config, model, s.image is not None)) is not None), None)
    current = Stage(name="search", count=count)

    def on_step(index: int, total: int, step: Step) -> None:
        nonlocal current
        current = Stage(name="search", index=index, count=total, label=step.prompt or f"{step.name} (image-guided)")

    def on_event(event: ProgressEvent) -> None:
        job.on_progress(progress_of(event, current), event.kind in _MILESTONES)

    try:
        assembly = assemble(base, steps, config, base_name=record.target_name, guide=guide, on_event=on_event,
                            on_step=on_step, should_cancel=job.should_cancel, choice=job.choice)
    except (CtpError, JobTimeoutException):
        raise  # the library names the stage of its own errors
    except Exception as exc:
        if out_of_memory(exc):
            raise  # run_job: job_too_large, with the stage from the last progress
        log.exception("assembly stage crashed", extra={"job_id": record.id})
        raise CtpError(f"stage {current.index}/{count} ({record.steps[current.index - 1].name}): "
                       f"{type(exc).__name__}: {exc}", code="internal_error",
                       field=f"steps.{current.index - 1}") from exc
    job.on_progress(_exporting(config, current.model_copy(update={"name": "exporting"})), True)
    return _results(assembly_glb(assembly), assembly_report(assembly), assembly.preview), []  # no alternatives


def _results(glb: bytes, report_: dict[str, Any], preview) -> dict[str, bytes]:
    """A succeeded job's files (``service.jobs.OUTPUTS``); a preview only when the run rendered one."""
    files = {"result.glb": glb, "report.json": report_json(report_)}  # stored without the machine's paths
    if preview is not None:
        files["preview.png"] = preview_png(preview)
    return files


def _exporting(config: AlignConfig, stage: Stage | None = None, objective: float | None = None,
               restarts: int | None = None) -> Progress:
    """The exporting progress; ``restarts``: those the run refined (the search keeps fewer than configured or adds
    the tile stage's), the configured count where unknown (an assembly)."""
    return Progress(stage=stage or Stage(name="exporting"), kind="exporting", phase=config.optim.phases,
                    phases=config.optim.phases, step=config.optim.steps, steps=config.optim.steps,
                    restarts=config.optim.restarts if restarts is None else restarts, fraction=1.0, eta_s=0.0,
                    objective=None if objective is None else round(objective, 5), message="writing results")


def progress_of(event: ProgressEvent, stage: Stage | None = None) -> Progress:
    """The optimiser's event as the API's progress object; ``stage`` says which alignment of an assembly."""
    message = event.message or (f"phase {event.phase}/{event.phases}, step {event.step}/{event.steps}"
                                if event.phase else event.kind)
    if stage is None:
        stage = Stage(name=event.stage)
    else:
        stage = stage.model_copy(update={"name": event.stage})
        message = f'stage {stage.index}/{stage.count}: "{stage.label}": {message}'
    rounded = lambda value, digits: None if value is None else round(value, digits)  # noqa: E731
    done = (stage.index - 1 + event.fraction) / stage.count  # each alignment of several a 1/count share: one bar
    return Progress(stage=stage, kind=event.kind, phase=event.phase, phases=event.phases,
                    step=event.step, steps=event.steps,
                    restarts=event.restarts, fraction=round(min(1.0, done), 4),
                    eta_s=rounded(event.eta_s, 1), objective=rounded(event.best_objective, 5), message=message,
                    relation=event.relation, relation_holds=event.relation_holds,
                    relation_checked=event.relation_checked, guide_match=rounded(event.guide_match, 4),
                    contact_gap=rounded(event.contact_gap, 4))
