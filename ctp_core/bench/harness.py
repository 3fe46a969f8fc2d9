"""The benchmark run loop: cases x protocol inits x methods -> one ``results.jsonl`` row each.

Every method starts init i of a case from the same protocol pose (``protocol.initial_poses``), and
every row says which guide and encoder produced it, because numbers from a random encoder or the
oracle guide mean something different from numbers with real CLIP weights and a text prompt.

Methods:
- ``ctp``: ``align`` with the chosen guide (text, image or oracle), restart 0 at the protocol pose.
- ``geometry``: ``align`` with lambda_clip = 0 (no guide at all).
- ``b1`` / ``b2``: the shrinkwrap baselines (``baselines``); b2 selects with ctp's guide and encoder.

Ablations change ctp's (and geometry's) configuration through the optimiser's own switches.
"""

from __future__ import annotations

import json
import os
import sys
import time
import traceback
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from multiprocessing import get_context
from pathlib import Path

import numpy as np
import trimesh

from ctp_core import metrics, priors
from ctp_core.bench import baselines, protocol
from ctp_core.bench.cases import Case
from ctp_core.bench.guides import GUIDES, GuideInputs, PixelGuide, SelectionScore, guide_inputs
from ctp_core.config import DEFAULT_MODEL, AlignConfig
from ctp_core.errors import ConfigError
from ctp_core.geometry import sampling
from ctp_core.reading import counts
from ctp_core.relations import predicates

GUIDED = ("ctp", "b2")  # methods that see the guide
OPTIMISED = ("ctp", "geometry")  # methods that run align() and take a preset and ablations
B2_STARTS = 5  # the paper's N for the multi-start baseline
EVAL_VIEWS = 8  # fixed evaluation views of the semantic metric (paper)
POSE_SAMPLES = 2000  # source surface samples for ADD-S
RELATION_SAMPLES = 2000  # target samples per object for the relation metrics (the default preset's loss samples)

# name -> (preset replacing --preset or None, config overrides). Each reuses an optimiser switch.
ABLATIONS: dict[str, tuple[str | None, dict]] = {
    "no-guidance": (None, {"loss": {"lambda_clip": 0.0}}),
    "no-icp": (None, {"loss": {"lambda_icp": (0.0, 0.0)}}),
    "no-pen": (None, {"loss": {"lambda_pen": (0.0, 0.0)}}),
    "no-phases": (None, {"optim": {"phases": 1}}),
    "no-camera-schedule": (None, {"camera": {"schedule": False}}),
    "selection-only": (None, {"loss": {"selection_only": True}}),
    "no-relation": (None, {"relation": False}),  # the prompt's relation judges no pose (the verdict stays)
    "paper": ("paper", {}),
}
RESULTS = "results.jsonl"


@dataclass
class BenchOptions:
    methods: list[str] = field(default_factory=lambda: ["ctp"])
    protocol: protocol.Protocol = "rigid"
    inits: int = 1
    seed: int = 0
    preset: str = "default"
    model: str | None = None  # ctp's (and b2's) encoder; None: the default model (config.DEFAULT_MODEL)
    guide: str = "text"
    metrics_models: list[str] = field(default_factory=list)
    ablation: str | None = None
    device: str = "cpu"
    threads: int | None = None
    runtime: str | None = None  # forward-only runtime of every guide (AlignConfig.runtime); None: the preset's
    count: int = 1  # copies of the source per run (``ctp_core.assembly.copies``): ctp and geometry, the text guide
    arrangement: str = "auto"  # how the copies stand together (``reading.counts.CHOICES``)

    def __post_init__(self) -> None:
        unknown = [m for m in self.methods if m not in METHODS]
        if unknown or not self.methods:
            raise ConfigError(f"methods must be among {', '.join(METHODS)}, got {self.methods}", field="method")
        if self.guide not in GUIDES:
            raise ConfigError(f"guide must be one of {', '.join(GUIDES)}, got {self.guide!r}", field="guide")
        if self.ablation is not None and self.ablation not in ABLATIONS:
            raise ConfigError(f"ablation must be one of {', '.join(ABLATIONS)}, got {self.ablation!r}",
                              field="ablation")
        if self.protocol not in protocol.PROTOCOLS:
            raise ConfigError(f"protocol must be one of {', '.join(protocol.PROTOCOLS)}", field="protocol")
        if self.inits < 1:
            raise ConfigError("inits must be at least 1", field="inits")
        counts.choose(None, self.count, self.arrangement)  # count_out_of_range, invalid_arrangement
        if self.count > 1 and (set(self.methods) - set(OPTIMISED) or ("ctp" in self.methods and self.guide != "text")):
            raise ConfigError("several copies (count > 1) are placed by ctp and geometry with the text guide only: "
                              "the baselines and the reference-image guides place one source", field="count")

    def config(self, method: str) -> AlignConfig:
        """The AlignConfig of an optimised method: preset, ablation, then the bench's own settings."""
        preset, overrides = ABLATIONS[self.ablation] if self.ablation else (None, {})
        top = {"seed": self.seed, "device": self.device, "threads": self.threads, "runtime": self.runtime,
               "scale": self.protocol == "scale"}
        top["model"] = self.model or DEFAULT_MODEL  # a benchmark names its encoder: never auto's per-machine pick
        config = AlignConfig.from_preset(preset or self.preset, **{k: v for k, v in top.items() if v is not None},
                                         **overrides)
        if method == "geometry":
            config = config.model_copy(update={"loss": config.loss.model_copy(update={"lambda_clip": 0.0})})
        return config

    @property
    def encoder(self) -> str:
        """What encodes the guided methods' views: the model spec, or "none (pixels)" for the pixels guide."""
        return "none (pixels)" if self.guide == "pixels" else self.config("ctp").model

    def load_encoder(self):
        """The guided methods' encoder: a cached ``guidance.Guide``, or the pixels guide's stand-in."""
        from ctp_core.guide import loaders

        if self.guide == "pixels":
            return PixelGuide(device=self.device)
        return loaders.guide_for(self.config("ctp"))  # the one ctp's runs use (same cache entry)


def identity(case: Case, init: int, method: str, options: BenchOptions) -> dict:
    """The fields that name a row: a rerun with ``--resume`` skips rows whose identity is done."""
    optimised = method in OPTIMISED
    guided = method in GUIDED and not (method == "ctp" and options.config("ctp").loss.lambda_clip == 0)
    return {
        "case": case.id, "init": init, "method": method, "protocol": options.protocol, "seed": options.seed,
        "ablation": options.ablation if optimised else None,
        "preset": options.config(method).preset if optimised else None,
        "guide": options.guide if guided else None,
        "encoder": options.encoder if guided else None,
        "copies": f"{options.count} {options.arrangement}" if options.count > 1 else None,
    }


def row_key(row: dict) -> tuple:
    return tuple(row.get(k) for k in ("case", "init", "method", "protocol", "seed", "ablation", "preset", "guide",
                                      "encoder", "copies"))


@dataclass
class _CaseData:
    case: Case
    target: trimesh.Trimesh
    source: trimesh.Trimesh
    points: np.ndarray  # source surface samples, source file frame (ADD-S)
    inits: list[np.ndarray]
    semantic: list[tuple[str, object, object]]  # (spec, guide, text embedding) per metrics encoder
    notes: dict[str, str]
    guide: GuideInputs | None = None
    guide_error: str | None = None
    judge: tuple | None = None  # (prepared pair, relation reading, penetrates): the relation metrics (``_judge``)


def _judge(data: _CaseData) -> tuple:
    """What the relation metrics judge every method's answer by: the pair in the *reference's* frame (the case's
    files as they are, +Y up: glTF's convention, in which the case's reference is authored), never turned as a run
    may turn it, so a run that took the wrong up fails here instead of holding on its own turned pair; and the
    relation the priors read from the case's prompt (the rules provider), not the case's coarse ``relation`` label:
    the label's vocabulary ("on_top", "attached", "other") is the benchmark's, it does not say whether the source
    is the figure, and the priors' relation is what a run would use."""
    if data.judge is None:
        from ctp_core import orientation, pairs

        case, target, source = data.case, data.target, data.source
        prior = priors.resolve_priors(priors.get_provider("rules"), case.target_name, case.source_name, case.prompt,
                                      target_extent=float(target.extents.max()),
                                      source_extent=float(source.extents.max()))
        frame = orientation.orient(target, orientation.Axes("+y"))  # the front: the file's convention (glTF's +Z)
        frame.reason = "the case's frame (the reference's): the file's +Y up"
        pair = pairs.prepare_pair(target, source, samples=RELATION_SAMPLES, seed=0, target_up=frame)
        data.judge = (pair, prior.reading, prior.penetration)
    return data.judge


def relation_metrics(data: _CaseData, pose: np.ndarray, iou: float) -> dict:
    """``relation`` (the priors' relation or None), ``relation_score``, ``relation_holds``, ``stable`` (None
    where the relation is unknown, or for ``stable`` one it does not apply to: ``Relation.steady``) and
    ``valid``: the relation holds, stable where that applies, and (unless the relation goes into the target)
    the intersection ratio ``iou`` at most ``metrics.PLACEMENT_IOU``; None without a relation."""
    pair, reading, penetrates = _judge(data)
    verdict = predicates.verdict(pair, pair.local_to_normalised(pose), reading)
    if verdict is None:
        return {"relation": None, "relation_score": None, "relation_holds": None, "stable": None, "valid": None}
    valid = verdict.holds and verdict.stable is not False and (penetrates or iou <= metrics.PLACEMENT_IOU)
    return {"relation": verdict.name, "relation_score": verdict.score, "relation_holds": verdict.holds,
            "stable": verdict.stable, "valid": bool(valid)}


def _metric_encoders(specs: Iterable[str], prompt: str, config: AlignConfig) -> tuple[list, dict[str, str]]:
    """The metrics encoders, on the run's device and forward-only runtime (they only score)."""
    from ctp_core.errors import ModelError
    from ctp_core.guide import loaders

    loaded, notes = [], {}
    for spec in specs:
        try:
            guide = loaders.get_guide(spec, device=config.device, runtime=config.runtime, threads=config.threads)
        except ModelError as exc:
            notes[spec] = f"semantic score skipped: {exc.message}"
            continue
        loaded.append((spec, guide, guide.encode_text([prompt])[0]))
    return loaded, notes


def evaluate(data: _CaseData, pose: np.ndarray, alternatives: list[np.ndarray] = ()) -> dict:
    """Every metric of one final pose (source file -> target file); ``alternatives``: the run's other distinct
    placements (``AlignResult.alternatives``, the answer first) for ``placement_at_k`` (any of them places)."""
    from ctp_core import pairs

    placed = data.source.copy()
    placed.apply_transform(pose)
    out = metrics.intersection_over_union(data.target, placed).to_dict()
    out["contact"] = metrics.contact_distance(data.target, placed)
    out.update(relation_metrics(data, pose, out["iou"]))
    if data.case.reference is not None:
        out.update(metrics.pose_errors(data.points, pose, data.case.reference))
        out["placement_success"] = metrics.placement_success(out["centroid_error"], out["iou"])
        out["placement_at_k"] = out["placement_success"] or any(_places(data, other) for other in alternatives[1:])
        out["alternatives"] = max(len(alternatives), 1)
    semantic = {}
    if data.semantic:
        images = pairs.render_arrangement(data.target, data.source, pose, views=EVAL_VIEWS, image_size=224)
        semantic = {spec: metrics.semantic_score(images, text, guide) for spec, guide, text in data.semantic}
    out["semantic"] = semantic
    return out


def _places(data: _CaseData, pose: np.ndarray) -> bool:
    """Whether ``pose`` is a placement success against the case's reference (``metrics.placement_success``)."""
    placed = data.source.copy()
    placed.apply_transform(pose)
    errors = metrics.pose_errors(data.points, pose, data.case.reference)
    return metrics.placement_success(errors["centroid_error"], metrics.intersection_over_union(data.target, placed).iou)


def _run_align(method: str, init: np.ndarray, index: int, data: _CaseData, options: BenchOptions) -> dict:
    """ctp or geometry: ``align`` with restart 0 at the protocol start (the others stay random)."""
    from ctp_core.align import align

    started = time.perf_counter()
    config = options.config(method)
    inputs = data.guide if method == "ctp" and config.loss.lambda_clip > 0 else None
    if options.count > 1:
        return _run_copies(config, inputs, data, options, started)
    result = align(data.target, data.source, data.case.prompt, config, init=init,
                   guide=inputs.guide if inputs else None, image=inputs.image if inputs else None,
                   goal=inputs.goal if inputs else None,
                   target_name=data.case.target_name, source_name=data.case.source_name)
    return {"source_to_target": result.source_to_target, "time_s": time.perf_counter() - started,
            "clip_images": int(result.clip_images), "timings": result.timings,
            "alternatives": [np.asarray(a["source_to_target"]) for a in result.alternatives],
            "extra": {"best_restart": result.best_restart, "guidance": result.guided_by,
                      "hparams": priors.to_report(result.priors), "scale": result.scaling,
                      "guide_say": result.guide_say}}


def _run_copies(config: AlignConfig, inputs: GuideInputs | None, data: _CaseData, options: BenchOptions,
                started: float) -> dict:
    """``count`` copies (``copies.place_copies``): the first is judged against the case's reference as one
    placement (``evaluate``); every copy's verdict and the set's measures (all hold, none intersect, spacing) go
    in the row's ``copy_set`` (its ``copies`` names the count and the arrangement asked for)."""
    from ctp_core.assembly.copies import place_copies

    placed = place_copies(data.target, data.source, data.case.prompt, config, count=options.count,
                          arrangement=options.arrangement, target_name=data.case.target_name,
                          source_name=data.case.source_name, guide=inputs.guide if inputs else None)
    per_copy = [{"name": c.name, "on": c.on, "holds": None if c.relation is None else bool(c.relation["holds"]),
                 "score": None if c.relation is None else c.relation["score"], "seconds": c.seconds}
                for c in placed.copies]
    return {"source_to_target": placed.copies[0].source_to_target, "time_s": time.perf_counter() - started,
            "clip_images": sum(int(c.result.clip_images) for c in placed.copies if c.result is not None),
            "timings": placed.timings,
            "copy_set": {"arrangement": placed.arrangement, "per_copy": per_copy, "set": placed.metrics}}


def _run_b1(method: str, init: np.ndarray, index: int, data: _CaseData, options: BenchOptions) -> dict:
    started = time.perf_counter()
    pose = baselines.shrinkwrap(data.target, data.source, [init], seed=options.seed)[0]
    return {"source_to_target": pose, "time_s": time.perf_counter() - started, "clip_images": 0}


def _run_b2(method: str, init: np.ndarray, index: int, data: _CaseData, options: BenchOptions) -> dict:
    """b1 from the protocol start and B2_STARTS - 1 uninformed ones, the best by ctp's guide and encoder."""
    started = time.perf_counter()
    rng = protocol.case_rng(options.seed, data.case.id, f"b2-{index}")
    scale = float(np.cbrt(abs(np.linalg.det(init[:3, :3]))))
    starts = [init, *protocol.random_starts(data.target.bounds, data.source.bounds, scale, B2_STARTS - 1, rng)]
    poses = baselines.shrinkwrap(data.target, data.source, starts, seed=options.seed)
    guide = options.load_encoder()
    scorer = SelectionScore(data.guide, data.target, data.source, guide, data.case.reference, views=EVAL_VIEWS)
    best, scores = baselines.best_of(poses, scorer)
    return {"source_to_target": poses[best], "time_s": time.perf_counter() - started,
            "clip_images": len(poses) * EVAL_VIEWS, "extra": {"best_start": best, "scores": scores}}


# method -> runner(method, init pose, init index, case data, options) -> row fields: the final
# "source_to_target", "time_s", "clip_images" and whatever else the method reports.
RUNNERS = {"ctp": _run_align, "geometry": _run_align, "b1": _run_b1, "b2": _run_b2}
METHODS: tuple[str, ...] = tuple(RUNNERS)


def _load(case: Case, options: BenchOptions, need_guide: bool) -> _CaseData:
    target, source = case.load()
    inits = protocol.initial_poses(case.reference, source.bounds, protocol=options.protocol, count=options.inits,
                                   seed=options.seed, case_id=case.id)
    semantic, notes = _metric_encoders(options.metrics_models, case.prompt, options.config("ctp"))
    data = _CaseData(case, target, source, sampling.surface_samples(source, POSE_SAMPLES, options.seed)[0],
                     inits, semantic, notes)
    if need_guide:
        try:
            data.guide = guide_inputs(options.guide, case, target, source,
                                      protocol.case_rng(options.seed, case.id, "guide"))
        except ConfigError as exc:
            data.guide_error = exc.message
    return data


def case_rows(case: Case, options: BenchOptions, skip: frozenset = frozenset()) -> Iterator[dict]:
    """Rows of one case (inits x methods) as each finishes, minus those whose key is in ``skip``."""
    planned = [(i, m) for i in range(options.inits) for m in options.methods
               if row_key(identity(case, i, m, options)) not in skip]
    if not planned:
        return
    data = _load(case, options, need_guide=any(m in GUIDED for _, m in planned))
    for i, method in planned:
        row = identity(case, i, method, options)
        row.update(origin=case.origin, relation=case.relation, has_reference=case.reference is not None,
                   initial_pose=data.inits[i].tolist(), guide_description=None, metric_notes=data.notes)
        if row["guide"] is not None:
            if data.guide is None:
                yield {**row, "status": "skipped", "error": data.guide_error}
                continue
            row["guide_description"] = data.guide.description
        try:
            info = RUNNERS[method](method, data.inits[i], i, data, options)
            alternatives = info.pop("alternatives", [])
            row.update(status="ok", **info, metrics=evaluate(data, info["source_to_target"], alternatives))
        except Exception as exc:  # one failing case must not end a long benchmark; the row records it
            traceback.print_exc(file=sys.stderr)
            row.update(status="error", error=f"{type(exc).__name__}: {exc}")
        yield row


def run_case(case: Case, options: BenchOptions, skip: frozenset = frozenset()) -> list[dict]:
    """All rows of one case at once (what a worker process sends back)."""
    return list(case_rows(case, options, skip))


def read_results(path: Path) -> list[dict]:
    """Rows of a results.jsonl, the last one per key (a resumed run may have retried a row)."""
    if not Path(path).exists():
        return []
    rows = {}
    for line in Path(path).read_text().splitlines():
        if line.strip():
            row = json.loads(line)
            rows[row_key(row)] = row
    return list(rows.values())


def _worker_init(threads: int) -> None:
    import torch

    torch.set_num_threads(threads)


def _check_models(options: BenchOptions) -> None:
    """Fail before the first case if the guided methods' encoder cannot load (every row would error)."""
    guided = [m for m in options.methods if m in GUIDED]
    if guided and not (guided == ["ctp"] and options.config("ctp").loss.lambda_clip == 0):
        options.load_encoder()


def run_bench(cases: list[Case], options: BenchOptions, out: Path, *, jobs: int = 1, resume: bool = False,
              on_case: Callable[[int, int, str], None] | None = None) -> list[dict]:
    """Run every case, appending each row to ``out/results.jsonl`` as it finishes; returns all rows.

    ``resume`` keeps the finished (status ok) rows already in the file and runs only the rest.
    ``jobs`` > 1 runs cases in that many processes, splitting the CPU threads between them.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / RESULTS
    if not resume:
        path.unlink(missing_ok=True)
    skip = frozenset(row_key(r) for r in read_results(path) if r.get("status") == "ok")
    _check_models(options)
    total, done = len(cases), 0

    def write(rows: Iterable[dict]) -> None:
        for row in rows:  # one line at a time: an interrupted run keeps every finished row
            with path.open("a") as f:
                f.write(json.dumps(_plain(row)) + "\n")

    def finished(case_id: str) -> None:
        nonlocal done
        done += 1
        if on_case:
            on_case(done, total, case_id)

    if on_case:
        on_case(0, total, "")
    if jobs <= 1:
        for case in cases:
            write(case_rows(case, options, skip))
            finished(case.id)
    else:
        threads = max(1, (os.cpu_count() or 1) // jobs)
        with ProcessPoolExecutor(jobs, mp_context=get_context("spawn"), initializer=_worker_init,
                                 initargs=(threads,)) as pool:
            futures = {pool.submit(run_case, case, options, skip): case.id for case in cases}
            for future in as_completed(futures):
                write(future.result())
                finished(futures[future])
    return read_results(path)


def _plain(value):
    """JSON-ready: numpy arrays and scalars become lists and Python numbers."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value
