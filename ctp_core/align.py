"""The align entry point: the one function the CLI, the worker and the bench call.

``align(target, source, prompt, config)`` takes meshes in their *file frames* (as ``io.load_mesh``
returns them) and returns an ``AlignResult`` whose transform maps the source file frame to the target
file frame. Everything in between (normalisation, canonical pose, optimisation) is internal.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
import trimesh

from ctp_core import contact, priors
from ctp_core.config import MAX_ALTERNATIVES, PENETRATION, AlignConfig
from ctp_core.errors import ConfigError
from ctp_core.geometry import frames
from ctp_core.guide import selection
from ctp_core.progress import CancelCheck, ProgressCallback, ProgressEvent
from ctp_core.reading import cues
from ctp_core.reading.names import ground_names
from ctp_core.relations import parts

if TYPE_CHECKING:  # the stages import these lazily: importing align stays light
    from ctp_core.config.schedule import Phase
    from ctp_core.geometry.pose import Poses
    from ctp_core.guide.goals import Goal
    from ctp_core.guide.guidance import Guide
    from ctp_core.objective import Scorer
    from ctp_core.optimise import Outcome
    from ctp_core.orientation import canonical
    from ctp_core.pairs import PreparedPair
    from ctp_core.reading.relation import RelationReading
    from ctp_core.search.ordering import GuideSay
    from ctp_core.search.proposals import Proposals
    from ctp_core.search.scaling import ScalePlan

__all__ = ["AlignResult", "ProgressEvent", "align", "scale_ratio_warning"]

# Source/target size ratios (AABB diagonals, the source as placed) the method does well within. The search's
# views frame the whole scene (coarse and fine at 128-160 px at the default preset; the tile stage's at least a
# third of it), so beyond 1e-3 either way the smaller object renders under a pixel in every one of them: the
# guide cannot see it, and its placement rests on the geometry (contact) alone. The run still ends, with a
# ``scale_ratio_extreme`` warning.
SIZE_RATIO_RANGE = (1e-3, 1e3)
# Relations whose figure stands as it is set down: in a scene step, a source with a clear up
# (``canonical.clear_up``) placed by one of these (or by no relation) keeps it (``PreparedPair.source_keeps_up``).
# Not the others: leaning, lying, hanging, held, worn, wrapped, driven in, attached, and "in" (a rake goes into a
# bucket any way it fits).
STANDING = frozenset({"stand", "sit", "on", "under", "beside", "front", "behind", "left", "right", "above", "below",
                      "near", "far", "facing", "facing_away", "aligned", "between"})


@dataclass
class AlignResult:
    """The answer in file frames, plus what a report and an export need."""

    source_to_target: np.ndarray  # (4, 4): p_target_file = M @ [p_source_file; 1]
    objective: float
    target: trimesh.Trimesh  # file frame, untouched
    source: trimesh.Trimesh  # source file frame (apply source_to_target to place it)
    prompt: str | None
    config: AlignConfig
    priors: dict[str, Any]  # ScenePrior.to_dict() and the names the priors read (the report's ``hparams``)
    restarts: list[dict[str, Any]]
    timings: dict[str, float]
    preview: np.ndarray | None = None  # (V, H, W, 3) uint8 views of the final scene
    best_restart: int | None = None  # the restart the answer comes from (``ordering.select_answer``'s pick)
    on: str | None = None  # the placed object an assembly step relates to (the first, where there are several)
    grounds: list[str] = field(default_factory=list)  # every placed object it relates to ("between": two)
    ground_parts: list[str] = field(default_factory=list)  # the ground's named parts, with why (``parts.describe``)
    guided_by: str | None = None  # what guided the run, in words (the report's "guidance")
    model: str | None = None  # the guidance model; None for a geometry-only run
    guide: str = "none"  # the guide chosen for the run: a model spec or "none" (selection.GuideChoice)
    guide_why: str = ""  # why that guide
    runtime: str | None = None  # the guide's runtime ("torch", "onnx"); None without a guide
    clip_images: int = 0  # images the encoder scored
    phase_timings: list[dict[str, float]] = field(default_factory=list)  # per refinement phase
    target_upright: canonical.Upright | None = None  # the target's up and front (file frame -> upright frame, why)
    source_upright: canonical.Upright | None = None  # the source's up and front (its starting orientation, why)
    # the answer's relation verdict (predicates.RelationVerdict.to_dict: name, role figure/ground, score, holds,
    # stable); None when the priors read no relation
    relation: dict[str, Any] | None = None
    # whether the answer touches the target (``contact_of``: gap in source diagonals, touching); None: not measured
    contact: dict[str, Any] | None = None
    warnings: list[dict[str, Any]] = field(default_factory=list)  # {"code", "message", ...}: the run went on
    # the best distinct placements the run refined, the answer first (``alternatives``): restart, source_to_target
    # (file frames, 4x4), objective, the guide's and geometry's terms, relation verdict
    alternatives: list[dict[str, Any]] = field(default_factory=list)
    thumbnails: np.ndarray | None = None  # (K, H, W, 3) uint8: one view of each alternative
    # the guide's say over the geometry as the search measured it (``ordering.GuideSay.to_dict``: spread, noise,
    # override, who chose, a summary line); None without a guide or a search
    guide_say: dict[str, Any] | None = None
    # a scene step: whether the source kept its own up (turns about +Y only) and why (``canonical.clear_up``);
    # None where nothing was asked (a single pair, or a relation that tips its figure)
    keeps_up: dict[str, Any] | None = None
    # scale mode: the initial scale, where it came from (the priors' names and ratio, the geometry's constraint),
    # the ladder the search tried and the final scale (``scaling.ScalePlan.to_dict`` + "final"); None: rigid
    scaling: dict[str, Any] | None = None

    def alternative(self, k: int) -> AlignResult:
        """This result with alternative ``k`` as its answer (0: the answer itself): its pose, objective, restart and
        relation verdict."""
        chosen = self.alternatives[k]
        return replace(self, source_to_target=np.asarray(chosen["source_to_target"], dtype=np.float64),
                       objective=chosen["objective"], best_restart=chosen["restart"],
                       relation=chosen.get("relation", self.relation), contact=chosen.get("contact", self.contact))

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




@dataclass
class Run:
    """What the stages share: the prepared pair, the priors, the objective and the phase plan."""

    config: AlignConfig
    pair: PreparedPair
    prior: priors.ScenePrior
    scorer: Scorer
    plan: list[Phase]  # one per refinement phase
    goal: Goal | None  # None: geometry only
    started: float
    timings: dict[str, float] = field(default_factory=dict)
    names: dict[str, Any] = field(default_factory=dict)  # target, source, on, grounds: what the priors read
    warnings: list[dict[str, Any]] = field(default_factory=list)  # AlignResult.warnings
    scale: ScalePlan | None = None  # scale mode: the scales the run starts from and searches (``scaling``)

    @property
    def reading(self) -> RelationReading | None:
        """The prompt's relation as the run uses it (``ScenePrior.reading``), read from the priors."""
        return self.prior.reading


def grounds(target: trimesh.Trimesh | trimesh.Scene, prompt: str | None, on: str | Sequence[str] | None
            ) -> str | Sequence[str] | None:
    """The placed objects the source relates to: ``on`` as given, or, where a scene target's prompt names two of its
    objects as grounds ("between the sofa and the armchair") and ``on`` names fewer, those two
    (``cues.grounds``)."""
    from ctp_core import pairs

    if isinstance(target, trimesh.Trimesh):
        return on
    return cues.grounds(prompt, ground_names(on), [name for name, _ in pairs.objects(target)]) or on


def prepare(target: trimesh.Trimesh | trimesh.Scene, source: trimesh.Trimesh, prompt: str | None,
            config: AlignConfig, *, on: str | Sequence[str] | None = None, image: np.ndarray | None = None,
            target_name: str = "target", source_name: str = "source", guide: Guide | None = None,
            goal: Goal | None = None) -> Run:
    """Priors, the normalised and canonicalised pair, the guide and its goal, the objective and the plan.

    A scene target's priors read the object ``on`` (its name is ``target_name``, its size the extent). A prompt
    that places the source between two placed objects ("between the sofa and the armchair") relates it to both
    where ``on`` names fewer (``grounds``). In scale mode the files' sizes set nothing (``scaling``): the size ratio
    comes from the names and the prompt."""
    from ctp_core import objective, orientation, pairs
    from ctp_core.config import schedule
    from ctp_core.guide import goals, loaders
    from ctp_core.guide.upright import upright_judge
    from ctp_core.search import scaling

    started = time.perf_counter()
    if config.threads:
        torch.set_num_threads(config.threads)
    if config.device == "cuda" and not torch.cuda.is_available():
        raise ConfigError("device 'cuda' was requested but no CUDA device is available", field="device")
    on = grounds(target, prompt, on)
    prior = priors.resolve_priors(
        priors.get_provider(config.hparams_provider), target_name, source_name, prompt or "",
        size_ratio=config.size_ratio, contact_ratio=config.contact_ratio,
        penetration=PENETRATION[config.penetration],
        **({} if config.scale else {"target_extent": float(pairs.attachment(target, on).extents.max()),
                                    "source_extent": float(source.extents.max())}),
    )
    judge = None
    if config.upright and config.upright_judge:
        guide = guide or loaders.guide_for(config)
        # a scene's up is its base's (pairs.base), judged under the base's own name
        base_name, base = (target_name, target) if isinstance(target, trimesh.Trimesh) else pairs.objects(target)[0]
        judge = upright_judge(base, guide, base_name, device=config.device)
    pair = pairs.prepare_pair(target, source, samples=config.loss.samples, seed=config.seed, device=config.device,
                              canonicalise=config.upright, judge=judge, on=on, keep_up=keeps_up(target, prior.reading),
                              **orientation.configured(config))
    prepared = time.perf_counter()

    if goal is None and config.loss.lambda_clip > 0:
        if image is not None:
            goal = goals.ImageGoal(image)
        elif prompt:
            goal = goals.TextGoal(prompt)
    if goal is not None and config.loss.lambda_clip > 0:
        guide = guide or loaders.guide_for(config)
        goal.prepare(pair, guide)
    else:
        goal = None
    loaded = time.perf_counter()
    named = ground_names(on)
    names = {"target": target_name, "source": source_name, "on": named[0] if named else None, "grounds": list(named)}
    read = {key: names[key] for key in ("target", "source", "on")}  # the names the priors read
    scales = scaling.plan(pair, prior, read, config.seed, guided=goal is not None) if config.scale else None
    scorer = objective.Scorer(pair, config, prior.contact_ratio, guide=guide, goal=goal, reading=prior.reading,
                              scale=scales)
    plan = schedule.phases(config, allow_penetration=prior.penetration)
    return Run(config, pair, prior, scorer, plan, goal, started,
               {"prepare_s": round(prepared - started, 3), "model_s": round(loaded - prepared, 3)}, names,
               scale=scales)


def keeps_up(target: trimesh.Trimesh | trimesh.Scene, reading: RelationReading | None) -> bool:
    """Whether a source placed on ``target`` by ``reading`` keeps its own up where it is clear: in a scene step
    (a ``trimesh.Scene`` target: an assembly's or a set of copies'), by no relation or only by ``STANDING`` ones.
    A single pair is left free (a pair's benchmarks turn sources over on purpose)."""
    if not isinstance(target, trimesh.Scene):
        return False
    return reading is None or all(str(name) in STANDING for name in reading.relations)


def ground_parts(run: Run) -> parts.Parts | None:
    """The ground's parts (``parts.parts``, kept per pair) where the run places the source relative to a ground
    by a relation; None otherwise."""
    return parts.find_parts(run.pair) if run.reading is not None and run.reading.source_is_figure else None


def propose(run: Run, init: np.ndarray | None = None) -> Proposals:
    """Search on: contact proposals (``proposals.propose``); off: the random starts (``optimise.initial_poses``).

    ``init`` (source file -> target file 4x4) is one candidate (search) or replaces restart 0 (no search); rigid,
    it fixes the source scale either way. In scale mode every start takes the plan's scale and the search proposes
    at its rungs (``scaling``: the ladder with a guide, its centre without): an incoming pose's scale is never used.
    """
    from ctp_core import optimise
    from ctp_core.relations import builders
    from ctp_core.search import proposals

    config, pair = run.config, run.pair
    generator = torch.Generator().manual_seed(config.seed)
    starts = optimise.initial_poses(pair, config, run.scale.centre if run.scale else 0.0, generator, init=init)
    ratio = math.exp(float(starts.log_s[0])) * pair.source_radius / max(pair.target_radius, 1e-30)
    warning = scale_ratio_warning(ratio)
    if warning is not None and not any(w["code"] == warning["code"] for w in run.warnings):
        run.warnings.append(warning)
    if not config.search.enabled:
        return contact.Proposals(starts, ["random"] * len(starts))
    t0 = time.perf_counter()
    ground_parts(run)  # found once here, timed, and kept with the pair for the builders and preferences
    run.timings["parts_s"] = round(time.perf_counter() - t0, 3)
    t0 = time.perf_counter()
    weights = proposals.region_weights(run.reading)
    given = starts.select(slice(0, 1)) if init is not None else None
    rungs = run.scale.rungs if run.scale else float(starts.log_s[0])
    proposed = proposals.propose(pair, config, weights, rungs, generator, init=given)
    # the relation's own poses, where the regions do not reach them ("lean")
    proposed = builders.extend(pair, config, proposed, run.reading, config.seed)
    kept = proposals.standing(pair, proposed.poses).tolist() if pair.source_keeps_up else []
    if kept:  # a builder's own turns (a stick stood on end) tip a source that keeps its up
        proposed = proposed.select(kept)
    run.timings["propose_s"] = round(time.perf_counter() - t0, 3)
    return proposed


def score(run: Run, proposals: Proposals, *, say: GuideSay | None = None, on_event: ProgressCallback | None = None,
          should_cancel: CancelCheck | None = None) -> tuple[Poses, GuideSay | None]:
    """The optimiser's starts: the search's diverse best ``optim.restarts`` (forward-only scoring), or the
    proposals as they are when the search is off; and the guide's say the search measured (None: none measured),
    or ``say`` as given (measured by an earlier search of the run: not measured again).

    The search ranks by the prompt's relation first, then by the guide where there is one and it tells the
    candidates apart (``ordering.search_key``, ``ordering.GuideSay``), otherwise by the first phase's objective:
    its proposals already touch without interpenetrating.
    """
    from ctp_core.search import coarse_to_fine

    if not run.config.search.enabled:
        return proposals.poses, None
    scorer = run.scorer if say is None else run.scorer.with_say(say)
    ranked = coarse_to_fine.search(scorer, proposals, run.plan[0], k=run.config.optim.restarts, on_event=on_event,
                            should_cancel=should_cancel, phases=len(run.plan), started=run.started,
                            name=run.names.get("source") or "source")
    run.timings["search_s"] = round(ranked.seconds, 3)
    run.timings["search_candidates"] = ranked.scored
    if ranked.screened:  # the geometry's screen before the full measure (and a guide) saw its shortlist
        run.timings["search_screened"] = ranked.screened
    if run.scorer.reading is not None:
        run.timings["search_relation_holds"] = ranked.holding  # of the coarse and sweep candidates
    if ranked.say is not None:  # the guide's spread over the candidates, its noise, how far it may override
        said = ranked.say.to_dict()
        run.timings.update({f"guide_{k}": said[k] for k in ("spread", "noise", "override")})
    return ranked.poses, ranked.say


def refine(run: Run, starts: Poses, say: GuideSay | None = None, *, on_event: ProgressCallback | None = None,
           should_cancel: CancelCheck | None = None) -> Outcome:
    """The phased optimiser from ``starts`` (one restart each) under the search's ``say`` (``score``; None: not
    measured); returns its ``Outcome``."""
    from ctp_core import optimise

    runner = optimise.Optimiser(run.scorer, run.plan, on_event=on_event, should_cancel=should_cancel, say=say)
    return runner.run(starts)


def result(run: Run, outcome: Outcome, prompt: str | None, *, on_event: ProgressCallback | None = None,
           pictures: bool = True) -> AlignResult:
    """The answer in file frames with its report fields and a preview, from the restart the optimiser selected
    (``Outcome.best``: ``ordering.select_answer``, the relation first, near the target, then the objective on the
    fixed evaluation views; not always the lowest objective). The report's ``best_restart``, the first
    alternative and the last progress readout are that restart. ``pictures``: render the preview and the
    alternatives' thumbnails (else None)."""
    from ctp_core import pairs
    from ctp_core.relations import predicates

    config, pair, best = run.config, run.pair, outcome.best
    matrices = outcome.poses.matrices()
    answers = [pair.source_to_target(m) for m in matrices]
    preview = pairs.to_uint8(pairs.render_pair(pair, matrices[best], views=4, image_size=224)) if pictures else None
    timings = {f"optimise_{k}_s": round(v, 3) for k, v in outcome.timings.items()}
    timings.update(run.timings, total_s=round(time.perf_counter() - run.started, 3))
    restarts = [
        {"restart": i, "objective": float(outcome.objectives[i]),
         **outcome.terms.row(i, ("clip", "icp", "pen", "rel", "sunk")), "source_to_target": answers[i].tolist()}
        for i in range(len(answers))
    ]
    goal = run.goal
    answer = AlignResult(
        source_to_target=answers[best], objective=float(outcome.objectives[best]),
        target=pair.target, source=pair.source, prompt=prompt, config=config,
        priors={**run.prior.to_dict(), "target_name": run.names.get("target"),  # the names the priors read
                 "source_name": run.names.get("source")},
        restarts=restarts, timings=timings, preview=preview, best_restart=best, on=run.names.get("on"),
        grounds=run.names.get("grounds", []),
        ground_parts=[] if ground_parts(run) is None else parts.describe(run.pair),
        guided_by=goal.description if goal is not None else "none (geometry only)",
        model=config.model if goal is not None else None,
        runtime=getattr(run.scorer.guide, "runtime", None),  # the pixels guide has none
        clip_images=outcome.clip_images,
        phase_timings=[{k: round(v, 3) for k, v in p.items()} for p in outcome.phase_timings],
        target_upright=pair.target_upright, source_upright=pair.source_upright,
        warnings=list(run.warnings),
        guide_say=None if outcome.say is None else outcome.say.to_dict(),
    )
    if run.scale is not None:
        answer.scaling = {**run.scale.to_dict(), "final": answer.scale}
    if pair.source_up_why:
        answer.keeps_up = {"kept": pair.source_keeps_up, "why": pair.source_up_why}
    verdict = predicates.verdict(pair, matrices[best], run.reading)
    answer.relation = verdict.to_dict() if verdict is not None else None
    gaps = contact.contact_gap(pair, outcome.poses)
    answer.contact = contact_of(float(gaps[best]))
    picks = alternatives(run, outcome)
    for i in picks:
        judged = predicates.verdict(pair, matrices[i], run.reading)
        answer.alternatives.append({
            "restart": i, "source_to_target": answers[i], "objective": float(outcome.objectives[i]),
            **outcome.terms.row(i, ("clip", "icp", "pen", "rel")),
            "relation": judged.to_dict() if judged is not None else None, "contact": contact_of(float(gaps[i]))})
    if pictures:
        answer.thumbnails = pairs.to_uint8(torch.stack([
            pairs.render_pair(pair, matrices[i], views=1, image_size=THUMBNAIL)[0] for i in picks]))
    if on_event:
        steps = sum(p.steps for p in run.plan)
        on_event(ProgressEvent(kind="done", phase=len(run.plan), phases=len(run.plan), step=outcome.steps_run,
                               steps=steps, restarts=len(answers),
                               elapsed_s=time.perf_counter() - run.started, eta_s=0.0,
                               best_objective=answer.objective, restart=best, message="done"))
    return answer


THUMBNAIL = 160  # pixels, one view of each alternative


def alternatives(run: Run, outcome: Outcome) -> list[int]:
    """Restart indices of the best distinct placements the run refined, the answer first, at most
    ``MAX_ALTERNATIVES``, in ``ordering.alternatives_key``'s order (the relation first, then the objective on
    the evaluation views): first the best at each distinct place (``search.distinct_translation`` source
    diagonals apart, any turn: the next places after the usual one), then other turns (near ones: that distance
    *and* ``distinct_rotation_deg``, as the search counts duplicates); those that ended far from the target (over
    ``contact.REACH`` source diagonals) left out; a source symmetric about its up (``PreparedPair.source_spin_axis``)
    has no other turn that differs by a spin about it alone. A prompt like "a cup on the table" has many right
    answers; a person picks among these."""
    from ctp_core.search import coarse_to_fine, ordering

    poses = outcome.poses
    far = contact.clearance(run.pair, run.pair.index, poses) > contact.REACH
    key = ordering.alternatives_key(outcome.terms, outcome.objectives, far, outcome.best)
    distance, angle = coarse_to_fine.distinct_of(run.pair, run.config, float(poses.log_s[0]))
    places = coarse_to_fine.diverse_top(poses, key, MAX_ALTERNATIVES, distance, 180.0, fill=False)
    turns = coarse_to_fine.diverse_top(poses, key, MAX_ALTERNATIVES, distance, angle, fill=False,
                                       spin_axis=run.pair.source_spin_axis)
    kept = (places + [i for i in turns if i not in places])[:MAX_ALTERNATIVES]
    finite = key.finite()
    return [i for i in kept if finite[i] or i == outcome.best]


def contact_of(gap: float) -> dict[str, Any]:
    """A placement's contact as reports say it: its ``contact.contact_gap`` (source diagonals; 0 within the
    target samples' spacing) and whether that is touching (``contact.touching``, as ``adjust`` says it)."""
    return {"gap": round(gap, 5), "touching": contact.touching(gap)}


def scale_ratio_warning(ratio: float) -> dict[str, Any] | None:
    """The report's ``scale_ratio_extreme`` warning where the source/target size ratio (AABB diagonals, the
    source as placed) is outside ``SIZE_RATIO_RANGE``; None inside it."""
    low, high = SIZE_RATIO_RANGE
    if low <= ratio <= high:
        return None
    small, large = ("source", "target") if ratio < low else ("target", "source")
    return {"code": "scale_ratio_extreme", "size_ratio": float(ratio), "range": [low, high],
            "message": f"the source is {ratio:.3g} times the size of the target (outside {low:g} to {high:g}): the "
                       f"{small} renders under a pixel in the views that frame the {large}, so the prompt cannot "
                       f"guide where it goes; the placement rests on contact alone"}


def align(
    target: trimesh.Trimesh | trimesh.Scene,
    source: trimesh.Trimesh,
    prompt: str | None,
    config: AlignConfig,
    *,
    on: str | Sequence[str] | None = None,
    image: np.ndarray | None = None,
    target_name: str = "target",
    source_name: str = "source",
    guide: Guide | None = None,
    goal: Goal | None = None,
    init: np.ndarray | None = None,
    on_event: ProgressCallback | None = None,
    should_cancel: CancelCheck | None = None,
    choice: selection.GuideChoice | None = None,
    pictures: bool = True,
) -> AlignResult:
    """Place ``source`` relative to ``target`` (both in file frames) so renders agree with the prompt.

    The stages: ``prepare`` -> ``propose`` -> ``score`` -> ``refine`` -> ``result``.
    ``image`` (H, W, 3 uint8) guides by a reference picture instead of the text; ``goal`` (a
    ``goals`` object) overrides both (the benchmark's oracle). ``guide`` is a preloaded
    vision-language model (``loaders.get_guide``); without one the configured model is loaded (and
    cached per process). ``init`` (4x4, source file -> target file) is one more search candidate (or,
    search off, replaces the first random start); rigid, it fixes the source's scale, while with ``config.scale``
    its scale is ignored (``scaling``: the priors' ratio or the geometry set it).
    A ``trimesh.Scene`` target is a scene of placed objects (``pairs.objects``): ``on`` names the one
    the source relates to, or the two of "between" (``grounds``; soft-ICP attaches to them, the search proposes
    on them; ``target_name`` and their size feed the priors), while renders and the penetration term see them all.
    Model ``auto`` is resolved first (``selection.resolve``; ``choice``: ``auto``'s pick made already for this
    run, a worker's); the result says which guide ran and why. ``pictures``: render the preview and the
    alternatives' thumbnails (off for a step of a scene or a set of copies, whose preview is the whole's).
    Raises ``errors.Canceled`` when ``should_cancel()`` turns true, other ``CtpError`` on bad input.
    """
    config, chosen = selection.resolve(config, image=image is not None, choice=choice)
    run = prepare(target, source, prompt, config, on=on, image=image, target_name=target_name,
                  source_name=source_name, guide=guide, goal=goal)
    proposals = propose(run, init)
    starts, say = score(run, proposals, on_event=on_event, should_cancel=should_cancel)
    if say is not None and say.amount <= 0 and run.scale is not None and len(run.scale.rungs) > 1:
        # a guide its say silences chooses no rung, and across rungs the geometry would pick where the relation
        # holds most easily (``scaling``): search again as without a guide, every proposal at the centre
        run.scale = run.scale.at_centre()
        starts, say = score(run, propose(run, init), say=say, on_event=on_event, should_cancel=should_cancel)
    outcome = refine(run, starts, say, on_event=on_event, should_cancel=should_cancel)
    answer = result(run, outcome, prompt, on_event=on_event, pictures=pictures)
    answer.guide, answer.guide_why = chosen.guide, chosen.why
    return answer
