"""Which guide a run uses when its model is ``auto`` (the default): the default CLIP model where its weights are
on this machine, else none, the geometry and the prompt's relation placing it (``lambda_clip`` 0, no upright
judge). A machine without weights then still runs the main job, labelled as such, instead of refusing it.

Chosen per run (``resolve``), where it runs: a service's worker chooses for each job it takes, so weights pulled
while it runs (``ctp models pull``) serve the next job. An explicit spec (``hf:``, ``open_clip:``, ``onnx:``,
``random:``) is never replaced: it loads or the run is refused (``loaders.load_guide``). A run that asks for
guidance itself (a reference image, the upright judge; over HTTP also a positive ``lambda_clip``,
``asks_for_guide``) is refused when ``auto`` finds no model, rather than silently run without one.

No torch import: the API process states the service's guide (``/readyz``) from the workers' offers with it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

from ctp_core.config import AUTO, DEFAULT_MODEL, AlignConfig
from ctp_core.errors import ModelError
from ctp_core.guide.checkpoints import missing

NONE = "none"  # the guide of a run without a model


@dataclass(frozen=True)
class GuideChoice:
    """A run's guide (a model spec, or ``none``), why, and the command that brings the default model here when
    ``auto`` found it missing."""

    guide: str
    why: str
    get_model: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def pull_command(spec: str = DEFAULT_MODEL) -> str:
    """The one command that puts ``spec``'s weights where the loader reads them (``ctp models pull``)."""
    return f"ctp models pull {spec.removeprefix('hf:')}"


def choose() -> GuideChoice:
    """What ``auto`` picks on this machine now: the default model when its weights can be had, else none."""
    absent = missing(DEFAULT_MODEL)
    if absent is None:
        return GuideChoice(DEFAULT_MODEL, f"auto: the weights of the default model {DEFAULT_MODEL} are here")
    return unguided(absent)


def unguided(absent: str) -> GuideChoice:
    """``auto``'s choice where the default model's weights are missing (``absent`` says why)."""
    return GuideChoice(NONE, f"auto: the default model {DEFAULT_MODEL} is not here ({absent.split('. ')[0]}); the "
                       "geometry and the prompt's relation place the source", pull_command())


def asks_model(config: AlignConfig, image: bool = False) -> bool:
    """Whether a run uses a model: a guide's term or the upright judge, or ``auto`` asked for image guidance;
    else ``resolve`` gives it none and needs no ``choice``."""
    return config.uses_model or (config.model == AUTO and image)


def resolve(config: AlignConfig, *, image: bool = False,
            choice: GuideChoice | None = None) -> tuple[AlignConfig, GuideChoice]:
    """The config a run executes and its guide. ``auto``: the default model, or none (``lambda_clip`` 0, upright
    judge off; refused with ``model_unavailable`` when the run asks for guidance itself: ``image``, the judge);
    ``choice``: ``auto``'s pick made already for this run (a worker's, an assembly's), else ``choose()``.
    Any other spec: the config unchanged, its guide that model, or none when the run uses no model."""
    if not asks_model(config, image):
        return config, GuideChoice(NONE, "the run asks for no guide (lambda_clip 0, no upright judge)")
    if config.model != AUTO:
        return config, GuideChoice(config.model, f"named by the run's options ({config.model})")
    choice = choice or choose()
    if choice.guide != NONE:
        return config.merged({"model": choice.guide}), choice
    asked = "image guidance (a reference picture)" if image else "the upright judge" if config.upright_judge else None
    if asked is not None:
        raise ModelError(f"this run asks for {asked}, which needs a model, and "
                         f"{choice.why.split('; ')[0].removeprefix('auto: ')}: get it with `{choice.get_model}`",
                         field="model")
    return config.merged({"loss": {"lambda_clip": 0.0}, "upright_judge": False}), choice


def asks_for_guide(options: dict[str, Any], image: bool) -> bool:
    """Whether a job's options (flat option names, ``ctp_core.config.options``) ask for guidance themselves: a reference
    image, a positive ``lambda_clip`` or the upright judge. Such a job under ``auto`` needs the default model."""
    return image or (options.get("lambda_clip") or 0) > 0 or bool(options.get("upright_judge"))
