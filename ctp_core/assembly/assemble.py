"""Iterative assembly (../shared/docs/method.md, "Other applications"): build a scene one object at a time.

``assemble(base, steps, config)`` places each step's source in turn (the plan a user writes, and its
checks, are ``plan``'s). Step k runs the one ``align`` pipeline with the scene of the objects placed in
steps 0..k-1 as its target: the soft-ICP term
attaches the source to the objects the step relates to (``on``: one, or two for "between"; default the last
placed one, and a "between" prompt naming two placed objects relates it to both), the
penetration term and the renders see every placed object with its own materials, and the priors get
the source's name and the related object's name and size. Placed objects never move.

Judged as a whole (``whole``): once a step is placed, the relations of the steps before it that held are judged
again with it in the scene; where it breaks one (or sinks into an object), its run's other distinct placements
(``AlignResult.alternatives``) are tried in order and the first that breaks nothing is kept (``StepResult.kept``
says which and what the answer broke). After the last step every relation is judged on the final scene
(``Assembly.whole``, the report's ``whole``: each verdict, ``all_hold``, ``none_intersect``).

Frames (``frames``): the *scene* frame is the base's file frame. Every object keeps its own file
frame; ``Placed.to_scene`` maps it into the scene (the identity for the base). A step's target is
already in the scene frame, so its answer (source file -> target file) is the source's ``to_scene``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np
import trimesh

from ctp_core.assembly.plan import check_plan
from ctp_core.config import AUTO, AlignConfig
from ctp_core.errors import Canceled, ConfigError, CtpError
from ctp_core.geometry import frames
from ctp_core.guide import selection
from ctp_core.progress import CancelCheck, ProgressCallback
from ctp_core.reading import cues
from ctp_core.reading.names import ground_names

if TYPE_CHECKING:  # the engine (torch) loads only when a step runs: the API checks plans with plan.check_plan
    from ctp_core.align import AlignResult

__all__ = ["Assembly", "Placed", "Step", "StepResult", "assemble", "scene_of"]


@dataclass(frozen=True)
class Step:
    """One object to add: its mesh (own file frame), its name, what guides it and what it relates to."""

    source: trimesh.Trimesh
    name: str
    prompt: str | None = None
    image: np.ndarray | None = None  # (H, W, 3) uint8 reference picture instead of the prompt
    on: str | Sequence[str] | None = None  # the placed object(s) it relates to (two: "between"); None: the last
    # placed one, or the two a "between" prompt names
    config: AlignConfig | None = None  # this step's options; None: the assembly's config


@dataclass
class Placed:
    """An object of the scene: its mesh in its own file frame and where it sits."""

    name: str
    mesh: trimesh.Trimesh
    to_scene: frames.Similarity  # the object's file frame -> scene


@dataclass
class StepResult:
    """What step ``index`` (1-based) of ``count`` did: the step, the objects it related to (``on`` the first,
    ``grounds`` all of them), the run."""

    index: int
    count: int
    step: Step
    on: str
    result: AlignResult
    grounds: list[str] = field(default_factory=list)
    # where the run's answer broke an earlier relation: {"alternative": the one kept (0: none did better, the
    # answer), "broke": what the answer broke, in words}; None where the answer broke nothing
    kept: dict[str, Any] | None = None


@dataclass
class Assembly:
    """The placed objects (base first) and the record of every step."""

    objects: list[Placed]
    results: list[StepResult]
    timings: dict[str, float] = field(default_factory=dict)
    whole: dict[str, Any] | None = None  # every step's relation judged on the final scene (``judged``)

    @property
    def preview(self) -> np.ndarray | None:
        """(V, H, W, 3) uint8 views of the whole scene: the last step renders every object."""
        return self.results[-1].result.preview if self.results else None

    def scene(self) -> trimesh.Scene:
        """Every object as its own named node: its mesh (own file frame, own materials) under ``to_scene``."""
        return scene_of(self.objects)


def scene_of(objects: Sequence[Placed]) -> trimesh.Scene:
    """A ``trimesh.Scene`` (scene frame) of placed objects, one named node each, in placing order."""
    out = trimesh.Scene()
    for placed in objects:
        out.add_geometry(placed.mesh, node_name=placed.name, geom_name=placed.name,
                         transform=np.array(placed.to_scene.matrix))
    return out


StepCallback = Callable[[int, int, Step], None]


def assemble(base: trimesh.Trimesh, steps: Sequence[Step], config: AlignConfig, *, base_name: str = "base",
             guide=None, on_event: ProgressCallback | None = None, on_step: StepCallback | None = None,
             should_cancel: CancelCheck | None = None, choice: selection.GuideChoice | None = None) -> Assembly:
    """Place ``steps`` one after another around ``base`` (its file frame is the scene frame).

    ``on_step(index, count, step)`` is called as each step starts; ``on_event`` gets every step's
    optimiser events. The guidance model is loaded once for all steps (every step uses
    ``config.model``). A step's ``CtpError`` is re-raised with the step named in its message (as "stage k/n",
    the word the report and the API use) and
    ``field`` ``steps.<i>[.<its field>]``; ``Canceled`` passes through. Model ``auto`` is chosen once for all
    steps (``choice``: already chosen, a worker's), so every step has the same guide.
    """
    from ctp_core.align import align

    started = time.perf_counter()
    configs = [step.config or config for step in steps]
    check_plan(base_name, [(s.name, ground_names(s.on),
                            s.prompt is not None or s.image is not None or c.loss.lambda_clip == 0)
                           for s, c in zip(steps, configs, strict=True)])
    if any(c.model != config.model for c in configs):
        raise ConfigError("every stage must use the assembly's model (it is loaded once)", field="model")
    if choice is None and config.model == AUTO:
        choice = selection.choose()
    resolved = [selection.resolve(c, image=s.image is not None, choice=choice)[0]
                for s, c in zip(steps, configs, strict=True)]
    guided = [c for c in resolved if c.loss.lambda_clip > 0]
    if guide is None and guided:
        from ctp_core.guide.loaders import guide_for

        guide = guide_for(guided[0])
    placed = [Placed(base_name, base, frames.Similarity(np.eye(4), frames.SCENE, frames.SCENE))]
    results: list[StepResult] = []
    for index, (step, step_config) in enumerate(zip(steps, configs, strict=True), start=1):
        scene = scene_of(placed)
        on = cues.grounds(step.prompt, ground_names(step.on), [p.name for p in placed]) or [placed[-1].name]
        if on_step is not None:
            on_step(index, len(steps), step)
        try:
            result = align(scene, step.source, step.prompt, step_config, on=on,
                           image=step.image, target_name=on[0], source_name=step.name, guide=guide, on_event=on_event,
                           should_cancel=should_cancel, choice=choice)
        except Canceled:
            raise
        except CtpError as exc:
            where = f"steps.{index - 1}" + (f".{exc.field}" if exc.field else "")
            raise type(exc)(f"stage {index}/{len(steps)} ({step.name}): {exc.message}", code=exc.code,
                            field=where) from exc
        result, kept = _keeping(placed, results, step, _on_floor(result, step.source, placed[0]), on)
        placed.append(_placed(step, result))
        results.append(StepResult(index, len(steps), step, on[0], result, on, kept))
    return Assembly(placed, results, {"total_s": round(time.perf_counter() - started, 3)}, judged(placed, results))


def _placed(step: Step, result: AlignResult) -> Placed:
    """The step's object where its run puts it (the run's target file frame is the scene frame)."""
    return Placed(step.name, step.source, frames.Similarity(result.source_to_target, frames.SOURCE_FILE, frames.SCENE))


def _on_floor(result: AlignResult, source: trimesh.Trimesh, base: Placed) -> AlignResult:
    """The run's answer raised onto the floor where it ends under it (the floor is the base's bottom: its file frame
    is the scene frame): nothing placed goes below the floor. The search charges it as penetration (a mean over the
    source's samples: a chair's leg tips sunk a centimetre cost it little), so the last of it is lifted here, straight
    up, by its lowest vertex's depth."""
    floor = float(base.mesh.bounds[0][1])
    matrix = np.asarray(result.source_to_target, dtype=np.float64)
    lowest = float(trimesh.transform_points(np.asarray(source.vertices), matrix)[:, 1].min())
    if lowest >= floor:
        return result
    lifted = matrix.copy()
    lifted[1, 3] += floor - lowest
    return replace(result, source_to_target=lifted)


def _keeping(placed: list[Placed], results: list[StepResult], step: Step, result: AlignResult, on: list[str]
             ) -> tuple[AlignResult, dict[str, Any] | None]:
    """The run's answer, or where it breaks an earlier relation or sinks (``_breaks``), the first of its
    alternatives that breaks nothing; where none does, the first (of ``LIFTED``, the least bad first) that breaks
    nothing once raised straight up by how deep it sinks (``LIFTS`` times at most: a cushion sunk into a sofa's seat
    then rests on it); else the one that breaks the fewest, then sinks the least (the answer on a tie), with what
    the answer broke."""
    answer_broke, answer_sunk = _breaks([*placed, _placed(step, result)], results, result, on)
    if not answer_broke:
        return result, None
    best, best_key = 0, (len(answer_broke), answer_sunk)
    tried = [(result, answer_sunk)]
    for k in range(1, len(result.alternatives)):
        other = _on_floor(result.alternative(k), step.source, placed[0])
        broke, sunk = _breaks([*placed, _placed(step, other)], results, other, on)
        tried.append((other, sunk))
        if not broke:
            return other, {"alternative": k, "broke": answer_broke}
        if (len(broke), sunk) < best_key:
            best, best_key = k, (len(broke), sunk)
    # none is clean: a placement sunk into what it rests on (a cushion into a sofa's seat) comes up out of it
    for k in sorted(range(len(tried)), key=lambda i: (i != best, i))[:LIFTED]:
        candidate, sunk = tried[k]
        for _ in range(LIFTS):
            if sunk <= 0:
                break
            candidate = _raised(candidate, sunk / 1000 + LIFT_CLEAR * step.source.scale)
            broke, sunk = _breaks([*placed, _placed(step, candidate)], results, candidate, on)
            if not broke:
                return candidate, {"alternative": k, "broke": answer_broke, "lifted": True}
    return tried[best][0], {"alternative": best, "broke": answer_broke, "none_clean": True}


LIFTS = 2  # times a sunk placement is raised by its depth before it is given up
LIFTED = 2  # placements raised: the least bad, then the answer (or the first alternative)
LIFT_CLEAR = 1e-4  # of the source's size: what a raised placement clears its depth by


def _raised(result: AlignResult, height: float) -> AlignResult:
    """The run's placement moved straight up by ``height`` (scene units)."""
    matrix = np.array(result.source_to_target, dtype=np.float64)
    matrix[1, 3] += height
    return replace(result, source_to_target=matrix)


def _breaks(objects: list[Placed], earlier: list[StepResult], result: AlignResult, on: list[str]
            ) -> tuple[list[str], float]:
    """What the last of ``objects`` (placed by ``result``) breaks, in words: each earlier step whose relation held
    and now fails or whose object now intersects another, and the new object where it intersects one; and how deep
    the new object sinks (millimetres into another object or below the floor, the deeper: ``sinking``)."""
    from ctp_core.assembly import whole

    found = []
    for step in earlier:
        if step.result.relation is not None and step.result.relation.get("holds"):
            now = _verdict(objects, step.index, step.result, step.grounds)
            if not now["holds"] or now["intersects"]:
                found.append(whole.said(now))
    new = _verdict(objects, len(objects) - 1, result, on)
    sunk = max(new["penetration_mm"], new["below_floor_mm"])
    return ([*found, whole.said(new)] if new["intersects"] else found), sunk


def judged(objects: list[Placed], results: list[StepResult]) -> dict[str, Any]:
    """Every step's relation judged on the scene ``objects``: the verdicts (``whole.verdict``), ``all_hold`` (None
    where no step has a relation) and ``none_intersect``."""
    relations = [_verdict(objects, s.index, s.result, s.grounds) for s in results]
    known = [r for r in relations if r["holds"] is not None]
    return {"relations": relations, "all_hold": all(r["holds"] for r in known) if known else None,
            "none_intersect": not any(r["intersects"] for r in relations)}


def _verdict(objects: list[Placed], index: int, result: AlignResult, grounds: list[str]) -> dict[str, Any]:
    """``whole.verdict`` of ``objects[index]`` (placed by ``result``) against every other object."""
    from ctp_core.assembly import whole

    placed = objects[index]
    others = [p for i, p in enumerate(objects) if i != index]
    floor = float(objects[0].mesh.bounds[0][1])  # the base's bottom: its file frame is the scene frame
    return whole.verdict(scene_of(others), placed.name, placed.mesh, np.asarray(placed.to_scene.matrix), result,
                         grounds, placed=[(p.name, p.mesh, np.asarray(p.to_scene.matrix)) for p in others],
                         floor=floor)
