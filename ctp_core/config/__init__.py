"""One typed configuration object for an alignment run, with named presets.

Every knob of the method (../shared/docs/method.md) lives here with its default and a line on why; callers build an
``AlignConfig`` (usually ``AlignConfig.preset("default")`` plus overrides) and pass it down whole
instead of threading keyword arguments through the layers.

Presets:
- ``paper``: the paper's budget (2000 steps, 8 views per step, 3 phases, 5 restarts).
- ``default``: search, then a short refinement: the guide sees only what the relation and the geometry leave
  possible; its time per pair is measured in docs/presets-and-search.md, "Presets".
- ``fast``: the relation and the geometry choose, the guide glances at a few candidates: interactive use.
- ``descent``: local descent only from random starts, as the paper's method (about ten minutes a pair).
- ``test``: seconds; for CI and smoke tests (search included, tiny).
"""

from __future__ import annotations

import math
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from ctp_core.config import backends
from ctp_core.errors import ConfigError

# The penetration words -> what the priors get: auto lets the prior decide; allow and forbid override it.
PENETRATION: dict[str, bool | None] = {"auto": None, "allow": True, "forbid": False}
Penetration = Literal[tuple(PENETRATION)]
# where an object's up or front comes from (orientation.py): its file's convention, a geometric guess, or an axis
Direction = Literal["file", "auto", "+x", "-x", "+y", "-y", "+z", "-z"]


def crossing(up: str, front: str) -> bool:
    """Whether an up and a front given as file axes (``+y``, ``-z``) lie on one axis: a front must be at right
    angles to its up (``file`` and ``auto`` are checked once the object's up is known: ``orientation.orient``)."""
    return up[0] in "+-" and front[0] in "+-" and up[1] == front[1]
Runtime = Literal["auto", "torch", "onnx", "onnx-int8"]  # the runtimes, spelled once (runtime.RUNTIMES)
AUTO = "auto"  # the model spec that picks the guide per run (``guide.selection``)
DEFAULT_MODEL = "hf:openai/clip-vit-base-patch32"  # what auto uses where its weights are
MAX_ALTERNATIVES = 4  # distinct placements a result offers, the answer among them (align.alternatives)


def share_of(count: float, share: float) -> int:
    """How many of ``count`` a ``share`` keeps (``SearchConfig.min_share`` and its uses: the regions' proposals,
    the encoder's shortlist, the poses a guide may admit past the relation): rounded up, so any share > 0 of a
    non-empty count keeps at least one."""
    return math.ceil(share * count)


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=True)


class CameraConfig(_Strict):
    """Training and evaluation views, all in the normalised frame (target AABB longest side 2)."""

    views: int = Field(8, ge=1, le=64, description="training views per restart per step")
    image_size: int = Field(224, ge=32, le=1024, description="render resolution in pixels (square)")
    elevation_deg: tuple[float, float] = Field((20.0, 50.0), description="elevation range")
    elevation_beta: tuple[float, float] = Field((1.0, 5.0), description="Beta law over the elevation range")
    distance: tuple[float, float] = Field((3.0, 3.5), description="camera distance range to the look-at")
    fov_deg: tuple[float, float] = Field((30.0, 60.0), description="vertical field of view range")
    look_at_beta_last: float = Field(
        1.0, ge=0.0, le=1.0, description="beta of the last phase: look-at moves from target to source centroid"
    )
    zoom_last: float = Field(0.81, gt=0.0, le=1.0, description="distance factor of the last phase")
    schedule: bool = Field(True, description="camera scheduling on (off: beta=0, zoom=1 in every phase)")
    eval_views: int = Field(4, ge=1, le=16, description="fixed views for selection (azimuths evenly spaced)")
    eval_elevation_deg: float = 30.0
    eval_distance: float = 3.2
    eval_fov_deg: float = 45.0


class LossConfig(_Strict):
    """Weights and constants of L = l_clip*L_clip + l_icp*L_icp(r) + l_pen*L_pen."""

    lambda_clip: float = Field(1.0, ge=0.0, description="0 gives the geometry-only optimiser")
    lambda_icp: tuple[float, float] = Field((1.0, 100.0), description="first and last phase (log-spaced)")
    lambda_pen: tuple[float, float] = Field((10.0, 1000.0), description="first and last phase (log-spaced)")
    lambda_rel: tuple[float, float] = Field(
        (10.0, 100.0), description="the prompt's relation (predicates.relation_score, plus predicates.stable for "
        "the other relations that rest on something), first and last phase (log-spaced); 0 when "
        "``relation`` is off or the prompt has no known relation"
    )
    sigma_icp: tuple[float, float] = Field(
        (0.1, 0.02), description="soft-ICP softmax width, first and last phase (log-spaced), normalised frame; "
        "narrowing it turns the soft pull toward a neighbourhood's centroid into a closest-point pull"
    )
    sigma_pen: float = Field(
        0.01, gt=0.0, description="penetration nearest-point softmax width (reference 0.05; narrower keeps a "
        "thin wall's far side from voting, which made points outside a mug count as inside)"
    )
    c_pen: float = Field(0.0, ge=0.0, description="penetration margin, normalised frame units")
    icp_neighbours: int = Field(32, ge=1, description="soft-ICP softmax restricted to k nearest targets")
    distances: Literal["field", "samples"] = Field(
        "field", description="where the soft-ICP and penetration terms read distances: each surface's distance "
        "field (geometry.field: the nearest sample's distance and depth on a grid built once; soft-ICP at its "
        "closest-point limit) or a search of the k nearest samples per point (soft-ICP's softmax over them)"
    )
    samples: int = Field(3000, ge=100, le=50000, description="surface samples per object for the losses")
    selection_only: bool = Field(
        False, description="reference-code behaviour: no CLIP gradient, text only picks the best pose"
    )


class OptimConfig(_Strict):
    """Restarts, phases, steps and Adam settings."""

    steps: int = Field(120, ge=1, le=100000, description="total steps per restart over all phases")
    phases: int = Field(3, ge=1, le=10)
    restarts: int = Field(4, ge=1, le=64, description="random starts, optimised as one batch")
    lr_translation: float = Field(0.05, gt=0.0)
    lr_rotation: float = Field(0.05, gt=0.0)
    lr_scale: float = Field(0.02, ge=0.0, description="used only when scale is optimised")
    noise: float = Field(0.01, ge=0.0, description="per-step Gaussian pose noise, as a fraction of lr")
    cosine_t0: int = Field(10, ge=1, description="cosine warm restarts: first period in steps")
    cosine_t_mult: int = Field(2, ge=1)
    init_distance: tuple[float, float] = Field((2.0, 4.0), description="start distance in target radii")
    init_rotation: Literal["upright", "random"] = Field(
        "upright", description="upright: the source's canonical frame turned about +Y; random: uniform (paper)"
    )
    eval_every: int = Field(10, ge=1, description="steps between evaluations on fixed views")


class SearchConfig(_Strict):
    """The global search before the optimiser (``search``): geometry-only proposals in contact, scored
    forward only, coarse to fine; its diverse best ``optim.restarts`` poses start the optimiser."""

    enabled: bool = Field(True, description="off: the optimiser starts from random poses (the method's Initialise)")
    candidates: int = Field(144, ge=1, le=20000, description="contact proposals made (and scored by the geometry)")
    shortlist: int = Field(
        0, ge=0, le=20000, description="the proposals the coarse stage scores in full (and whose images a guide "
        "sees), chosen by the relation and the geometry's screen (distinct places where the relation holds first, "
        "then a ``min_share`` of the others: ``coarse_to_fine.encoder_shortlist``); 0: all of them"
    )
    coarse_views: int = Field(2, ge=1, le=16, description="fixed views of the coarse stage, the same for all")
    coarse_image_size: int = Field(128, ge=32, le=1024, description="render size of the coarse stage")
    sweep: int = Field(2, ge=0, le=64, description="best distinct coarse sites re-tried with every source "
                       "orientation (at the coarse views)")
    sweep_keep: int = Field(
        0, ge=0, le=1000, description="of the sweep's turns, this many per site reach the guide, chosen as "
        "``shortlist`` is; 0: all"
    )
    fine: int = Field(24, ge=1, le=1000, description="best coarse candidates rescored at the fine stage")
    fine_views: int = Field(3, ge=1, le=16, description="views per candidate at the fine stage")
    fine_image_size: int = Field(160, ge=32, le=1024, description="render size of the fine stage")
    fine_zoom: float = Field(
        0.0, ge=0.0, le=1.0, description="fine views look this far from the target centre toward the "
        "candidate's source and come closer by the same fraction (a small source fills more pixels, but a view "
        "that crops the goal's source out favours candidates placed elsewhere); 0: views shared by all"
    )
    batch: int = Field(24, ge=1, le=1024, description="candidates per render/encoder call (cancel is "
                       "checked between calls)")
    yaw_steps: int = Field(8, ge=1, le=72, description="turns about +Y of each source orientation")
    stable_poses: int = Field(4, ge=0, le=32, description="most probable resting poses of the source used")
    tile_restarts: int = Field(
        2, ge=0, le=16, description="restarts added from the tile stage (to optim.restarts) where the source is "
        "small in the coarse views; 0: no tile stage"
    )
    tile_radius: float = Field(
        3.0, gt=0.0, le=100.0, description="tile stage: the radius a tile frames, in source radii (at least a "
        "third of the scene's); used only where that is at most half the scene's radius"
    )
    gaps: tuple[float, ...] = Field(
        (0.0, 0.1, 0.3), description="lateral proposals: gaps to the target, in source diagonals"
    )
    min_share: float = Field(
        0.08, gt=0.0, le=1.0, description="every proposal region keeps at least this share of its "
        "unweighted count, whatever the relation read from the prompt; also what of the poses where the relation "
        "fails reach the guide (``coarse_to_fine.encoder_shortlist``) and may be ranked with those where it holds "
        "(``ordering.rank_key``); counted by ``share_of``"
    )
    distinct_translation: float = Field(
        0.25, ge=0.0, description="top-k: poses closer than this (source diagonals) and distinct_rotation_deg "
        "count as duplicates"
    )
    distinct_rotation_deg: float = Field(30.0, ge=0.0, le=180.0)


class AlignConfig(_Strict):
    """Everything one run needs besides the meshes and the prompt."""

    preset: str = "default"
    seed: int = Field(0, ge=0, le=2**32 - 1, description="random seed (numpy and torch take any value in range)")
    device: Literal["cpu", "cuda"] = "cpu"
    model: str = Field(AUTO, description="guidance model spec (guide/guidance.py); auto: the default CLIP model "
                       "where its weights are here, else no guide (the geometry and the prompt's relation; "
                       "guide/selection.py)")
    autocast: bool = Field(True, description="fp16 on CUDA, bf16 on CPUs with native bf16 (AVX512-BF16/AMX), else fp32")
    runtime: Runtime = Field(
        "auto", description="where forward-only encoding runs (scoring, selection, judge): torch, onnx (ONNX "
        "Runtime fp32), onnx-int8 (dynamic int8 vision tower), auto (onnx on CPUs without native bf16, else "
        "torch; docs/guidance.md); the gradient path is always torch"
    )
    scale: bool = Field(False, description="optimise isotropic scale too")
    size_ratio: float | None = Field(None, ge=0.01, le=100.0, description="source/target size; None: prior")
    contact_ratio: float | None = Field(None, ge=0.0, le=1.0, description="soft-ICP ratio r; None: prior")
    penetration: Penetration = Field("auto", description="auto: the prior decides; allow: lambda_pen = 0")
    upright: bool = Field(
        True, description="let the target's up follow target_up (orientation.py); off keeps the target file's +Y "
        "as up whatever the format or target_up"
    )
    target_up: Direction = Field(
        "file", description="the target's up: file (the format's convention: +Y for glTF; for OBJ, STL, PLY Y-up "
        "unless the geometric guess finds +Z up), auto (the geometric guess: resting poses, legs, symmetry), or an "
        "axis of the file (+x, -x, +y, -y, +z, -z)"
    )
    target_front: Direction = Field(
        "file", description="the target's front: file (+Z for glTF, trusted; a guess for other formats), auto (away "
        "from where its surface gathers: a backrest), or an axis of the file at right angles to its up"
    )
    source_up: Direction = Field("file", description="the source's up, as target_up: its starting orientation")
    source_front: Direction = Field("file", description="the source's front, as target_front")
    upright_judge: bool = Field(
        False, description="let the guidance model choose the target's up as target_up auto does (renders under "
        "candidate ups against "
        "'a photo of a TARGET_NAME'); needs real weights and a target name; its accuracy is unmeasured (docs/engine.md)"
    )
    hparams_provider: str = Field("rules", description="scene-prior provider (priors.py)")
    relation: bool = Field(
        True, description="judge poses by the prompt's relation (predicates.py, docs/relations.md) where the search, "
        "refinement and selection use it; off: the no-relation ablation (the report's relation verdict stays)"
    )
    threads: int | None = Field(None, ge=1, le=256, description="torch CPU threads; None leaves torch's")
    progress_every: int = Field(5, ge=1, description="steps between progress events")
    camera: CameraConfig = CameraConfig()
    loss: LossConfig = LossConfig()
    optim: OptimConfig = OptimConfig()
    search: SearchConfig = SearchConfig()

    @model_validator(mode="after")
    def _phases_fit(self) -> AlignConfig:
        if self.optim.steps < self.optim.phases:
            raise ValueError("steps must be at least the number of phases")
        for role in ("target", "source"):
            up, front = getattr(self, f"{role}_up"), getattr(self, f"{role}_front")
            if crossing(up, front):
                raise ValueError(f"{role}_front {front} is not at right angles to {role}_up {up}")
        return self

    @property
    def uses_model(self) -> bool:
        """Whether a run loads the guidance model: prompt guidance (lambda_clip > 0) or the upright judge.
        A geometry-only run needs none, so a service without the model's weights can still run it."""
        return self.loss.lambda_clip > 0 or (self.upright and self.upright_judge)

    @model_validator(mode="after")
    def _backend_serves_the_run(self) -> AlignConfig:
        """A forward-only backend cannot give the CLIP gradient; ONNX Runtime runs on the CPU only.

        Raises ``ConfigError`` itself (pydantic lets it through) so the field is ``model``/``runtime``.
        """
        backend = backends.BACKENDS.get(self.model.partition(":")[0])
        if backend is not None and not backend.differentiable:
            if self.needs_image_gradient:
                raise ConfigError(f"model {self.model!r} is forward only (no gradients), and this run descends "
                                  "the CLIP loss: use selection only (--selection-only, loss.selection_only), "
                                  "no guidance, or a differentiable model (hf:, random:, open_clip:)", field="model")
            if self.runtime == "torch" or self.device != "cpu":
                raise ConfigError(f"model {self.model!r} runs only in ONNX Runtime on the CPU: use device cpu "
                                  "and runtime auto, onnx or onnx-int8", field="runtime")
        if self.runtime.startswith("onnx") and self.device != "cpu":
            raise ConfigError(f"runtime {self.runtime!r} is ONNX Runtime on the CPU; on CUDA use auto or torch",
                              field="runtime")
        return self

    @property
    def needs_image_gradient(self) -> bool:
        """Whether the optimiser differentiates the CLIP loss w.r.t. the renders."""
        return self.loss.lambda_clip > 0 and not self.loss.selection_only

    def merged(self, overrides: dict) -> AlignConfig:
        """This config with nested overrides applied (sections as dicts merge into its own) and validated."""
        if not overrides:
            return self
        return AlignConfig.from_preset(self.preset, **_merge(self.model_dump(exclude={"preset"}), overrides))

    @classmethod
    def preset_names(cls) -> list[str]:
        return sorted(PRESETS)

    @classmethod
    def from_preset(cls, name: str = "default", **overrides) -> AlignConfig:
        """Build a preset, then apply overrides (nested sections as dicts merge into the preset's)."""
        if name not in PRESETS:
            raise ConfigError(f"unknown preset {name!r}; choose one of {', '.join(sorted(PRESETS))}",
                              field="preset")
        data = _merge(PRESETS[name], {"preset": name})
        data = _merge(data, overrides)
        try:
            return cls.model_validate(data)
        except ValueError as exc:  # pydantic.ValidationError is a ValueError
            raise ConfigError(_first_error(exc), field=_first_field(exc)) from None


def _merge(base: dict, extra: dict) -> dict:
    out = dict(base)
    for key, value in extra.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _merge(out[key], value)
        else:
            out[key] = value
    return out


def _first_error(exc: Exception) -> str:
    errors = getattr(exc, "errors", None)
    if callable(errors):
        err = errors()[0]
        loc = ".".join(str(p) for p in err.get("loc", ()))
        return f"{loc}: {err.get('msg')}" if loc else str(err.get("msg"))
    return str(exc)


def _first_field(exc: Exception) -> str | None:
    errors = getattr(exc, "errors", None)
    if callable(errors):
        loc = errors()[0].get("loc", ())
        return ".".join(str(p) for p in loc) or None
    return None


PRESETS: dict[str, dict] = {
    # The paper's budget: 2000 steps, 8 views per step, 3 phases, 5 restarts, no search; its soft-ICP (a softmax
    # over each point's nearest samples, not the distance field's closest-point limit).
    "paper": {
        "camera": {"views": 8},
        "loss": {"distances": "samples"},
        "optim": {"steps": 2000, "phases": 3, "restarts": 5, "eval_every": 50, "init_rotation": "random"},
        "search": {"enabled": False},
    },
    # Search, then a short refinement (its time: docs/presets-and-search.md, "Presets"). The guide sees only what
    # can be the answer: the 48 proposals the relation and the geometry shortlist, 8 turns at each of the 2 best
    # sites, the best 12 again at the fine views; then the geometry refines its 4 best poses (+1 from the tile
    # stage) in 8 small steps and the guide chooses among them (selection only: its gradient placed no more cases
    # and costs more than a forward image on a CPU, docs/guidance.md).
    "default": {
        "camera": {"views": 1, "image_size": 128, "zoom_last": 0.7},
        "loss": {"samples": 2000, "selection_only": True},
        "optim": {"steps": 8, "phases": 2, "restarts": 4, "eval_every": 4, "lr_translation": 0.01,
                  "lr_rotation": 0.02},
        "search": {"shortlist": 48, "sweep_keep": 8, "fine": 12, "tile_restarts": 1},
        "progress_every": 2,
    },
    # The page's first look and interactive use: the relation and the geometry choose; the guide sees 12
    # proposals at the coarse views and 4 at the fine ones, and picks among 2 restarts refined by the geometry
    # alone (no gradient images).
    "fast": {
        "camera": {"views": 1, "image_size": 128, "eval_views": 2},
        "loss": {"samples": 2000, "selection_only": True},
        "optim": {"steps": 4, "phases": 1, "restarts": 2, "eval_every": 4, "lr_translation": 0.01,
                  "lr_rotation": 0.02},
        "search": {"shortlist": 12, "sweep": 0, "fine": 4, "fine_views": 2, "tile_restarts": 0},
        "progress_every": 1,
    },
    # Local descent from random starts (~10 min for a typical pair on 2 cores).
    "descent": {
        "camera": {"views": 4},
        "optim": {"steps": 120, "phases": 3, "restarts": 4, "eval_every": 10},
        "search": {"enabled": False},
    },
    # Seconds: CI and smoke tests (use with a small model such as random:tiny).
    "test": {
        "camera": {"views": 2, "image_size": 64, "eval_views": 2},
        "loss": {"samples": 400},
        "optim": {"steps": 6, "phases": 2, "restarts": 2, "eval_every": 3},
        "search": {"candidates": 12, "sweep": 1, "coarse_views": 1, "coarse_image_size": 64, "fine": 4, "fine_views": 1,
                   "fine_image_size": 64, "batch": 6, "yaw_steps": 4, "stable_poses": 1},
        "progress_every": 1,
    },
}
