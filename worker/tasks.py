"""The rq task: take a queued job, run the engine on it, store its results or its error.

``run_job`` is the adapter (status, progress, leases, errors); ``align_job`` is the one call into
``ctp_core``: bytes in, result files out.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable

from rq.timeouts import JobTimeoutException

from ctp_core.align import align
from ctp_core.config import AlignConfig
from ctp_core.errors import Canceled, CtpError
from ctp_core.export import preview_png, report, scene_glb
from ctp_core.guidance import guide_for
from ctp_core.io import MeshLimits, load_image
from ctp_core.loader import MeshLoader
from ctp_core.progress import ProgressEvent
from service.jobs import JobError, JobRecord, Progress, Stage, Status
from worker.main import context

log = logging.getLogger("ctp.worker")

# Optimiser events always published; step events are thinned (Heartbeat.publish).
_MILESTONES = {"phase_start", "phase_end", "done"}


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
    try:
        inputs = {name: ctx.jobs.storage.get(job_id, name) for name in ("target", "source", "image")}
        if inputs["target"] is None or inputs["source"] is None:
            raise CtpError("the job's uploads expired before a worker picked it up", code="inputs_expired")
        files = align_job(
            record, inputs, device=ctx.settings.device, threads=ctx.settings.threads, runtime=ctx.settings.runtime,
            loader=ctx.loader,
            limits=ctx.settings.mesh_limits,
            on_progress=lambda p, force: ctx.beat.publish(p, force=force),
            should_cancel=lambda: ctx.jobs.should_stop(job_id),
        )
        for name, data in files.items():
            ctx.jobs.storage.put(job_id, name, data)
        status = "succeeded"
    except Canceled as exc:
        status, error = "canceled", JobError(code=exc.code, message="canceled while running")
    except CtpError as exc:
        error = JobError(**exc.to_dict())
    except JobTimeoutException:
        error = JobError(code="job_timeout", message=f"the job ran over {ctx.settings.job_timeout_s} s")
    except Exception as exc:
        log.exception("job crashed", extra={"job_id": job_id, "worker": ctx.name})
        error = JobError(code="internal_error", message=f"{type(exc).__name__}: {exc}")
    finally:
        ctx.beat.end()
    ctx.jobs.finish(job_id, status, error)
    return status


def align_job(
    record: JobRecord,
    inputs: dict[str, bytes | None],
    *,
    device: str,
    threads: int | None,
    loader: MeshLoader,
    runtime: str = "auto",
    limits: MeshLimits,
    on_progress: Callable[[Progress, bool], None],
    should_cancel: Callable[[], bool],
) -> dict[str, bytes]:
    """Run ``ctp_core.align`` on a job's uploads; returns ``result.glb``, ``report.json``, ``preview.png``.

    The config was validated when the job was accepted; only where and how it runs (device, threads,
    the forward-only runtime) is this worker's to decide.
    """
    config = AlignConfig.model_validate({**record.config, "device": device, "threads": threads, "runtime": runtime})
    on_progress(Progress(stage=Stage(name="loading"), kind="loading", message="loading meshes"), True)
    target = loader.load(inputs["target"], filename=record.target_file, limits=limits)
    source = loader.load(inputs["source"], filename=record.source_file, limits=limits)
    image = load_image(inputs["image"]) if inputs.get("image") is not None else None
    guide = None
    if config.uses_model:
        on_progress(Progress(stage=Stage(name="model"), kind="model", message=f"loading model {config.model}"), True)
        guide = guide_for(config)

    def on_event(event: ProgressEvent) -> None:
        on_progress(progress_of(event), event.kind in _MILESTONES)

    result = align(target, source, record.prompt, config, image=image, target_name=record.target_name,
                   source_name=record.source_name, guide=guide, on_event=on_event, should_cancel=should_cancel)
    on_progress(Progress(stage=Stage(name="exporting"), kind="exporting", phase=config.optim.phases,
                         phases=config.optim.phases, step=config.optim.steps, steps=config.optim.steps,
                         restarts=config.optim.restarts, fraction=1.0, eta_s=0.0,
                         objective=round(result.objective, 5), message="writing results"), True)
    files = {"result.glb": scene_glb(result),
             "report.json": json.dumps(report(result), indent=2).encode()}
    if result.preview is not None:
        files["preview.png"] = preview_png(result.preview)
    return files


def progress_of(event: ProgressEvent) -> Progress:
    """The optimiser's event as the API's progress object."""
    message = event.message or (f"phase {event.phase}/{event.phases}, step {event.step}/{event.steps}"
                                if event.phase else event.kind)
    return Progress(stage=Stage(name=event.stage), kind=event.kind, phase=event.phase, phases=event.phases,
                    step=event.step, steps=event.steps,
                    restarts=event.restarts, fraction=round(event.fraction, 4),
                    eta_s=None if event.eta_s is None else round(event.eta_s, 1),
                    objective=None if event.best_objective is None else round(event.best_objective, 5), message=message)
