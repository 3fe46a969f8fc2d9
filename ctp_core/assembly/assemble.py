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

import copy
import functools
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np
import trimesh

from ctp_core.assembly.plan import Also, check_plan
from ctp_core.config import AUTO, AlignConfig
from ctp_core.errors import Canceled, ConfigError, CtpError
from ctp_core.geometry import frames, once
from ctp_core.guide import selection
from ctp_core.progress import CancelCheck, ProgressCallback
from ctp_core.reading import cues, passes
from ctp_core.reading.names import ground_names
from ctp_core.reading.records import ALONGSIDE, ORIENTED_NEAR, RELATIONS, Kind, RelationName
from ctp_core.reading.relation import RelationReading

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
    also: Sequence[Also] = ()  # relations said of it besides its own: judged with it and on the final scene


@dataclass
class Placed:
    """An object of the scene: its mesh in its own file frame and where it sits."""

    name: str
    mesh: trimesh.Trimesh
    to_scene: frames.Similarity  # the object's file frame -> scene
    front: np.ndarray | None = None  # (3,) its front in the scene frame, where given or set by a convention


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
    # what keeping the answer took (``_keeping``): {"alternative": the one kept (0: the answer), "broke": what the
    # answer broke, in words, and where so "lifted", "made_room", "none_clean" or "dropped": true}; None where the
    # answer was kept as the run left it
    kept: dict[str, Any] | None = None


@dataclass
class Assembly:
    """The placed objects (base first) and the record of every step."""

    objects: list[Placed]
    results: list[StepResult]
    timings: dict[str, float] = field(default_factory=dict)
    whole: dict[str, Any] | None = None  # every step's relation judged on the final scene (``judged``)
    preview: np.ndarray | None = None  # (V, H, W, 3) uint8 views of the final scene (None: no step placed)

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


@once.scene()  # what every step and every check asks of the placed objects again, made once
def assemble(base: trimesh.Trimesh, steps: Sequence[Step], config: AlignConfig, *, base_name: str = "base",
             guide=None, on_event: ProgressCallback | None = None, on_step: StepCallback | None = None,
             should_cancel: CancelCheck | None = None, choice: selection.GuideChoice | None = None) -> Assembly:
    """Place ``steps`` one after another around ``base`` (its file frame is the scene frame).

    ``on_step(index, count, step)`` is called as each step starts; ``on_event`` gets every step's
    optimiser events. The guidance model is loaded once for all steps (every step uses
    ``config.model``). A step's ``CtpError`` is re-raised with the step named in its message (as "stage k/n",
    the word the report and the API use) and
    ``field`` ``steps.<i>[.<its field>]``; ``Canceled`` passes through. Model ``auto`` is chosen once for all
    steps (``choice``: already chosen, a worker's), so every step has the same guide. What the steps, the checks of
    their candidates and the final judgement ask again of objects that have not moved (their copies in the scene,
    samples, render meshes, up and front, and a verdict of the same scene) is made once (``once``).
    """
    from ctp_core.align import align

    started = time.perf_counter()
    configs = [step.config or config for step in steps]
    check_plan(base_name, [(s.name, ground_names(s.on),
                            s.prompt is not None or s.image is not None or c.loss.lambda_clip == 0)
                           for s, c in zip(steps, configs, strict=True)])
    _check_also(base_name, steps)
    if any(c.model != config.model for c in configs):
        raise ConfigError("every stage must use the assembly's model (it is loaded once)", field="model")
    if choice is None and config.model == AUTO and any(selection.asks_model(c, s.image is not None)
                                                       for s, c in zip(steps, configs, strict=True)):
        choice = selection.choose()  # once for every step (a worker's choice comes with the job)
    resolved = [selection.resolve(c, image=s.image is not None, choice=choice)[0]
                for s, c in zip(steps, configs, strict=True)]
    guided = [c for c in resolved if c.loss.lambda_clip > 0]
    if guide is None and guided:
        from ctp_core.guide.loaders import guide_for

        guide = guide_for(guided[0])
    placed = [Placed(base_name, base, frames.Similarity(np.eye(4), frames.SCENE, frames.SCENE))]
    results: list[StepResult] = []
    rooms = _rooms(base_name, steps)
    for index, (step, step_config) in enumerate(zip(steps, configs, strict=True), start=1):
        scene = scene_of(placed)
        on = cues.grounds(step.prompt, ground_names(step.on), [p.name for p in placed]) or [placed[-1].name]
        if on_step is not None:
            on_step(index, len(steps), step)
        try:
            result = align(scene, step.source, step.prompt, step_config, on=on,
                           image=step.image, target_name=on[0], source_name=step.name, guide=guide, on_event=on_event,
                           should_cancel=should_cancel, choice=choice, pictures=False)
        except Canceled:
            raise
        except CtpError as exc:
            where = f"steps.{index - 1}" + (f".{exc.field}" if exc.field else "")
            raise type(exc)(f"stage {index}/{len(steps)} ({step.name}): {exc.message}", code=exc.code,
                            field=where) from exc
        if index == 1 and result.target_upright is not None and result.target_upright.front_trusted:
            placed[0].front = np.asarray(result.target_upright.front, dtype=np.float64)  # the scene is the base
        result, kept = _keeping(placed, results, step, result, on, rooms[index - 1])
        placed.append(_placed(step, result))
        results.append(StepResult(index, len(steps), step, on[0], result, on, kept))
    whole, preview = judged(placed, results), _preview(placed)
    return Assembly(placed, results, {"total_s": round(time.perf_counter() - started, 3)}, whole, preview)


def _preview(placed: list[Placed]) -> np.ndarray | None:
    """The final scene's preview (``pairs.preview``): every object where it was kept; None with the base alone."""
    from ctp_core import pairs

    if len(placed) < 2:
        return None
    last = placed[-1]
    return pairs.preview(scene_of(placed[:-1]), last.mesh, np.asarray(last.to_scene.matrix, dtype=np.float64))


def _placed(step: Step, result: AlignResult) -> Placed:
    """The step's object where its run puts it (the run's target file frame is the scene frame)."""
    matrix = np.asarray(result.source_to_target, dtype=np.float64)
    upright = result.source_upright
    front = matrix[:3, :3] @ upright.front if upright is not None and upright.front_trusted else None
    return Placed(step.name, step.source, frames.Similarity(matrix, frames.SOURCE_FILE, frames.SCENE), front)


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


def _keeping(placed: list[Placed], results: list[StepResult], step: Step, result: AlignResult, on: list[str],
             rooms: Sequence[Room] = ()) -> tuple[AlignResult, dict[str, Any] | None]:
    """The run's answer, or where it breaks an earlier relation or sinks (``_breaks``), the first of its
    alternatives that breaks nothing; each turned first as the description turns it (``_turned``) and tried as
    placed where turned it breaks something; a placement that leaves too little room for an object a later step
    puts between it and another (``rooms``) breaks that. An answer that sinks is first raised straight up by how
    deep it sinks (``LIFTS`` times at most, kept where that breaks nothing: a lamp 6 mm into a chest's top then
    stands on it rather than at a lower-ranked place). Where none is clean, the
    first (of ``LIFTED``, the least bad first) that breaks nothing once moved: raised as the answer is, or moved
    straight away from the other object by the room missing (a cabinet right of a workbench moved right to make
    room for the oil drum between them); else the one that breaks the fewest, then sinks the least (the answer on a
    tie), with what the answer broke. The one kept is then dropped into contact with what it stands on where that
    breaks nothing more (``_Keeper.dropped``: a drum left 2 cm over the floor, a teapot 3 mm into a tray)."""
    keeper = _Keeper(placed, results, step, result, on, rooms)
    chosen, kept = _choosing(keeper)
    dropped = keeper.dropped(chosen)
    if dropped is None:
        return chosen, kept
    return dropped, {**(kept or {"alternative": 0, "broke": []}), "dropped": True}


def _choosing(keeper: _Keeper) -> tuple[AlignResult, dict[str, Any] | None]:
    """``_keeping``'s choice, before it is dropped into contact."""
    result = keeper.result
    answer, answer_broke, answer_sunk = keeper.judged(0)
    if not answer_broke:
        return answer, None
    up = keeper.lifted(answer, answer_sunk)  # only sunk a little into what it rests on: raised out of it first
    if up is not None:
        return up, {"alternative": 0, "broke": answer_broke, "lifted": True}
    best, best_key = 0, (len(answer_broke), answer_sunk)
    tried = [(answer, answer_sunk)]
    for k in range(1, len(result.alternatives)):
        other, broke, sunk = keeper.judged(k)
        tried.append((other, sunk))
        if not broke:
            return other, {"alternative": k, "broke": answer_broke}
        if (len(broke), sunk) < best_key:
            best, best_key = k, (len(broke), sunk)
    # none is clean: one sunk into what it rests on (a cushion into a sofa's seat) comes up out of it, one too
    # close to what it must leave room beside moves away
    for k in sorted(range(len(tried)), key=lambda i: (i != best, i))[:LIFTED]:
        up = keeper.lifted(*tried[k]) if k else None
        if up is not None:
            return up, {"alternative": k, "broke": answer_broke, "lifted": True}
        moved = keeper.made_room(tried[k][0])
        if moved is not None:
            return moved, {"alternative": k, "broke": answer_broke, "made_room": True}
    return tried[best][0], {"alternative": best, "broke": answer_broke, "none_clean": True}


@dataclass(frozen=True)
class _Keeper:
    """A step's candidates judged against the scene so far (``_keeping``)."""

    placed: list[Placed]
    results: list[StepResult]
    step: Step
    result: AlignResult
    on: list[str]
    rooms: Sequence[Room]
    # each candidate's answer, by its placement and verdict: a verdict re-prepares the scene, and the same
    # candidate is asked again (turned or not, before and after dropping it)
    seen: dict[tuple[bytes, str], tuple[list[str], float]] = field(default_factory=dict)

    def breaks(self, candidate: AlignResult) -> tuple[list[str], float]:
        """``_breaks``, and the room a later step needs that ``candidate`` does not leave."""
        key = (np.asarray(candidate.source_to_target, dtype=np.float64).tobytes(), repr(candidate.relation))
        if key not in self.seen:
            step = self.step
            broke, sunk = _breaks([*self.placed, _placed(step, candidate)], self.results, candidate, self.on,
                                  step.also)
            self.seen[key] = (broke + [r.said(step.name, gap) for r in self.rooms
                                       if (gap := r.gap(self.placed, step, candidate)) < r.width], sunk)
        broke, sunk = self.seen[key]
        return list(broke), sunk

    def judged(self, k: int) -> tuple[AlignResult, list[str], float]:
        """Alternative ``k`` (0: the answer) on the floor, turned (``_turned``), or as placed where that breaks
        less; what it breaks and how deep it sinks."""
        step, placed = self.step, self.placed
        plain = _on_floor(self.result.alternative(k) if k else self.result, step.source, placed[0])
        turned = _on_floor(_turned(plain, step, placed), step.source, placed[0])
        broke, sunk = self.breaks(turned)
        if broke and turned is not plain:
            plain_broke, plain_sunk = self.breaks(plain)
            if (len(plain_broke), plain_sunk) < (len(broke), sunk):
                return plain, plain_broke, plain_sunk
        return turned, broke, sunk

    def lifted(self, candidate: AlignResult, sunk: float) -> AlignResult | None:
        """``candidate`` raised straight up by how deep it sinks, ``LIFTS`` times at most, where that breaks
        nothing."""
        for _ in range(LIFTS):
            if sunk <= 0:
                return None
            candidate = _raised(candidate, sunk / 1000 + LIFT_CLEAR * self.step.source.scale)
            broke, sunk = self.breaks(candidate)
            if not broke:
                return candidate
        return None

    def dropped(self, candidate: AlignResult) -> AlignResult | None:
        """``candidate`` moved straight up or down into contact with what is under it (``_to_contact``), where it
        stands on something (a relation that rests, or one beside, between or facing its grounds) and that breaks
        no more than it did; None where it does not move."""
        reading = RelationReading.from_verdict(candidate.relation)
        if reading is None or not (RELATIONS[reading.position].rests or RELATIONS[reading.position].kind in ALONGSIDE):
            return None
        matrix = np.asarray(candidate.source_to_target, dtype=np.float64)
        shift = _to_contact(trimesh.transform_points(np.asarray(self.step.source.vertices), matrix), self.placed)
        if shift == 0.0:
            return None
        moved = _raised(candidate, shift)
        before, sunk_before = self.breaks(candidate)
        after, sunk_after = self.breaks(moved)
        return moved if (len(after), sunk_after) <= (len(before), sunk_before) else None

    def made_room(self, candidate: AlignResult) -> AlignResult | None:
        """``candidate`` moved away from each object it must leave room beside (``Room.made``), where that
        breaks nothing."""
        moved = candidate
        for room in self.rooms:
            moved = room.made(self.placed, self.step, moved)
        return moved if moved is not candidate and not self.breaks(moved)[0] else None


LIFTS = 2  # times a sunk placement is raised by its depth before it is given up
LIFTED = 2  # where none is clean, placements raised or moved to make room: the least bad, then the first other
LIFT_CLEAR = 1e-4  # of the source's size: what a raised placement clears its depth by


@dataclass(frozen=True)
class Room:
    """Room a step's object leaves between itself and an object placed before it (``other``) for a later step's
    ``figure``, said to go between the two: ``width``, the figure's narrower side seen from above (scene units)."""

    other: str
    figure: str
    width: float

    def gap(self, placed: Sequence[Placed], step: Step, result: AlignResult) -> float:
        """The horizontal gap between the boxes (seen from above, scene frame) of ``step``'s object placed by
        ``result`` and ``other``."""
        mine = _box(step.source, np.asarray(result.source_to_target, dtype=np.float64))
        other = next(p for p in placed if p.name == self.other)
        theirs = _box(other.mesh, np.asarray(other.to_scene.matrix))
        return float(np.max(np.maximum(mine[0] - theirs[1], theirs[0] - mine[1])[[0, 2]]))

    def made(self, placed: Sequence[Placed], step: Step, result: AlignResult) -> AlignResult:
        """``result`` moved straight away from ``other`` (horizontally, from centre to centre) by the room missing."""
        missing = self.width - self.gap(placed, step, result)
        if missing <= 0:
            return result
        other = next(p for p in placed if p.name == self.other)
        away = _centre_of(step.source, np.asarray(result.source_to_target)) - _centre(other)
        away[1] = 0.0
        length = float(np.linalg.norm(away))
        if length == 0.0:
            return result
        shift = away / length
        # the gap between boxes grows along an axis only: move by the missing room over the axis the gap is along
        shift /= max(abs(shift[0]), abs(shift[2]))
        matrix = np.array(result.source_to_target, dtype=np.float64)
        matrix[:3, 3] += shift * (missing + ROOM_CLEAR * self.width)
        return replace(result, source_to_target=matrix)

    def said(self, name: str, gap: float) -> str:
        return (f"{name} leaves {max(gap, 0.0) * 1000:.0f} mm between it and {self.other}: the {self.figure} said "
                f"to go between them takes {self.width * 1000:.0f} mm")


ROOM_CLEAR = 0.25  # of the figure's width: the room made beyond it (a person leaves a hand's width or so)


def _rooms(base_name: str, steps: Sequence[Step]) -> list[list[Room]]:
    """For each step, the room it leaves (``Room``): for each later step between it and an object placed before
    it, that step's figure's narrower side seen from above (its own file frame stands upright: glTF's +Y)."""
    order = [base_name, *(s.name for s in steps)]
    out: list[list[Room]] = [[] for _ in steps]
    for later in steps:
        grounds = ground_names(later.on)
        if len(grounds) != 2 or not all(g in order for g in grounds) or later.prompt is None:
            continue
        reading = passes.read_prompt(grounds[0], later.name, later.prompt).reading
        if reading is None or RELATIONS[reading.position].kind != Kind.BETWEEN:  # "next to them": a group
            continue
        first, last = sorted(grounds, key=order.index)
        if last == base_name:
            continue
        extents = later.source.extents
        out[order.index(last) - 1].append(Room(first, later.name, float(min(extents[0], extents[2]))))
    return out


def _box(mesh: trimesh.Trimesh, matrix: np.ndarray) -> np.ndarray:
    """(2, 3) the scene-frame box of ``mesh`` (own file frame) placed by ``matrix``."""
    points = trimesh.transform_points(np.asarray(mesh.convex_hull.vertices), matrix)
    return np.array([points.min(0), points.max(0)])


def _centre_of(mesh: trimesh.Trimesh, matrix: np.ndarray) -> np.ndarray:
    return _box(mesh, matrix).mean(0)


CONTACT_BAND = 0.02  # of an object's height: its bottom, whose vertices are brought into contact (``_to_contact``)
CONTACT_REACH = 0.1  # of an object's diagonal: the farthest ``_to_contact`` moves it (a gap left by the search)


def _to_contact(vertices: np.ndarray, placed: Sequence[Placed]) -> float:
    """How far to move an object (its ``vertices``, scene frame) straight up (negative: down) so that its bottom
    touches what is under it: rays straight down from its bottom vertices (those within ``CONTACT_BAND`` of its
    height over its lowest) meet the level faces of the placed objects and the floor (the base's bottom); the move is
    the smallest gap between a bottom vertex and the face under it, negative where it is sunk (a level face above
    its vertex, within ``CONTACT_REACH`` of its diagonal), 0 where the move would be farther than that."""
    height = float(np.ptp(vertices[:, 1]))
    reach = CONTACT_REACH * float(np.linalg.norm(np.ptp(vertices, axis=0)))
    bottom = vertices[vertices[:, 1] <= vertices[:, 1].min() + CONTACT_BAND * height]
    origins = bottom + np.array([0.0, reach, 0.0])
    gaps = bottom[:, 1] - float(placed[0].mesh.bounds[0][1])  # the floor
    for other in placed:
        mesh = other.mesh.copy().apply_transform(np.asarray(other.to_scene.matrix))
        hits, rays, faces = mesh.ray.intersects_location(origins, np.tile([0.0, -1.0, 0.0], (len(origins), 1)))
        level = np.abs(mesh.face_normals[faces][:, 1]) > 0.5
        np.minimum.at(gaps, rays[level], bottom[rays[level], 1] - hits[level, 1])
    shift = -float(gaps.min())
    return shift if 0.0 < abs(shift) <= reach else 0.0


def _raised(result: AlignResult, height: float) -> AlignResult:
    """The run's placement moved straight up by ``height`` (scene units)."""
    matrix = np.array(result.source_to_target, dtype=np.float64)
    matrix[1, 3] += height
    return replace(result, source_to_target=matrix)


def _breaks(objects: list[Placed], earlier: list[StepResult], result: AlignResult, on: list[str],
            also: Sequence[Also] = ()) -> tuple[list[str], float]:
    """What the last of ``objects`` (placed by ``result``) breaks, in words: each earlier step whose relation held
    and now fails or whose object now intersects another, the new object where it intersects one or where its own
    relation, held in its run, fails (a placement raised or moved off it), and each relation said of it besides
    (``also``) whose objects are placed and that does not hold; and how deep the new object sinks (millimetres into
    another object or below the floor, the deeper: ``sinking``)."""
    from ctp_core.assembly import whole

    found = []
    for step in earlier:
        if step.result.relation is not None and step.result.relation.get("holds"):
            now = _verdict(objects, step.index, step.result, step.grounds)
            if not now["holds"] or now["intersects"]:
                found.append(whole.said(now))
    new = _verdict(objects, len(objects) - 1, result, on)
    if (result.relation or {}).get("holds") and new["holds"] is False:  # its run judged it holding: moved off it
        found.append(whole.said(new))
    sunk = max(new["penetration_mm"], new["below_floor_mm"])
    names = {p.name for p in objects}
    found += [whole.said(v) for a in also if set(a.on) <= names
              for v in [_also_verdict(objects, len(objects) - 1, result, a)] if v["holds"] is False]
    return ([*found, whole.said(new)] if new["intersects"] else found), sunk


def judged(objects: list[Placed], results: list[StepResult]) -> dict[str, Any]:
    """Every step's relation judged on the scene ``objects``, and every relation said of it besides (``also``,
    marked so): the verdicts (``whole.verdict``), ``all_hold`` (None where no step has a relation) and
    ``none_intersect``."""
    relations = [{**_verdict(objects, s.index, s.result, s.grounds), "also": False} for s in results]
    relations += [{**_also_verdict(objects, s.index, s.result, a), "also": True} for s in results for a in s.step.also]
    known = [r for r in relations if r["holds"] is not None]
    return {"relations": relations, "all_hold": all(r["holds"] for r in known) if known else None,
            "none_intersect": not any(r["intersects"] for r in relations)}


def _verdict(objects: list[Placed], index: int, result: AlignResult, grounds: Sequence[str],
             reading: RelationReading | None = None) -> dict[str, Any]:
    """``whole.verdict`` of ``objects[index]`` (placed by ``result``; judged by ``reading``, else the run's) against
    the base, its ``grounds`` and every other object near it (``_near``). Judged once per scene (``once``) for the
    same objects where they are, relation and options: the last step's answer is judged with every earlier step
    when it is kept, the final scene is that scene, and an object placed far from an earlier one leaves its
    verdict as it was."""
    from ctp_core.assembly import whole

    placed = objects[index]
    box = _box(placed.mesh, np.asarray(placed.to_scene.matrix))
    # the base (the scene's frame and floor), the grounds and what comes near it: an object farther away can neither
    # touch it, hold it up nor sink into it, and adding one does not judge the others again
    others = [p for i, p in enumerate(objects) if i != index and (i == 0 or p.name in grounds or _near(p, box))]
    floor = float(objects[0].mesh.bounds[0][1])  # the base's bottom: its file frame is the scene frame
    reading = reading or RelationReading.from_verdict(result.relation)  # what ``whole.verdict`` reads of the run

    def judge() -> dict[str, Any]:
        return whole.verdict(scene_of(others), placed.name, placed.mesh, np.asarray(placed.to_scene.matrix), result,
                             grounds, placed=[(p.name, p.mesh, np.asarray(p.to_scene.matrix)) for p in others],
                             floor=floor, reading=reading)

    judged_with = [placed, *others]
    where = tuple((p.name, id(p.mesh), hash(p.mesh), np.asarray(p.to_scene.matrix, dtype=np.float64).tobytes())
                  for p in judged_with)
    key = ("verdict", where, tuple(grounds), reading, result.config.model_dump_json())
    return copy.deepcopy(once.value(key, judge, pin=[p.mesh for p in judged_with]))  # the caller's own copy


NEARBY = 0.1  # of a judged object's diagonal: what another object's box must come within to be judged with it (as
# ``contact.TOUCH`` counts touching)


def _near(other: Placed, box: np.ndarray) -> bool:
    """Whether ``other``'s scene box (``_box``) comes within ``NEARBY`` of ``box``'s diagonal of ``box`` (2, 3)."""
    margin = NEARBY * float(np.linalg.norm(box[1] - box[0]))
    theirs = _box(other.mesh, np.asarray(other.to_scene.matrix))
    return bool(np.all(theirs[0] <= box[1] + margin) and np.all(theirs[1] >= box[0] - margin))


def _also_verdict(objects: list[Placed], index: int, result: AlignResult, also: Also) -> dict[str, Any]:
    """A relation said of ``objects[index]`` besides its own, judged as ``_verdict`` judges the step's."""
    return _verdict(objects, index, result, also.on, _also_reading(objects[index].name, also))


@functools.lru_cache(maxsize=256)
def _also_reading(figure: str, also: Also) -> RelationReading | None:
    """The relation ``also`` says, read as a pair prompt with ``figure`` the figure; an orientation said alone
    ("facing the monitor", read as near it and facing it) is judged as the orientation only: where the figure
    stands is its step's relation's to say."""
    reading = passes.read_prompt(also.on[0], figure, also.prompt).reading
    if (reading is not None and reading.orientation is not None and reading.leant is None
            and reading.position == ORIENTED_NEAR):
        return RelationReading(reading.orientation)
    return reading


def _turned(result: AlignResult, step: Step, placed: list[Placed]) -> AlignResult:
    """The run's placement turned about the vertical through its centre as the description turns it: its front at
    (or away from) the object its relation or one said besides names ("to the left of the workbench, facing it":
    exactly, where the search leaves 45 degrees; "in front of the desk, facing the monitor": the step's own
    relation is about the desk); else, resting on an object with a front and told no way to face,
    facing as that object faces (a monitor on a desk, a clock on a mantelpiece: squared to it as people set them,
    and its left and right then the desk's). Unchanged where the figure has no front it was given or that a
    convention gives (``Upright.front_trusted``), or where the object it turns by is not placed yet."""
    upright = result.source_upright
    if upright is None or not upright.front_trusted:
        return result
    scene = {p.name: p for p in placed}
    matrix = np.asarray(result.source_to_target, dtype=np.float64)
    centre = _centre_of(step.source, matrix)
    want = _facing_way(step, scene, centre, result)
    if want is None:
        return result
    front = matrix[:3, :3] @ np.asarray(upright.front, dtype=np.float64)
    turn = np.arctan2(want[0], want[2]) - np.arctan2(front[0], front[2])
    about = trimesh.transformations.rotation_matrix(turn, (0.0, 1.0, 0.0), point=centre)
    return replace(result, source_to_target=about @ matrix)


def _facing_way(step: Step, scene: dict[str, Placed], centre: np.ndarray, result: AlignResult) -> np.ndarray | None:
    """The horizontal direction (scene frame) the step's object should face (``_turned``), or None."""
    own = RelationReading.from_verdict(result.relation)
    grounds = tuple(result.grounds) or ((result.on,) if result.on else ())
    resting = [(grounds, own)] if grounds and own is not None and set(grounds) <= set(scene) else []
    readings = [(a.on, r) for a in step.also if set(a.on) <= set(scene)
                for r in [_also_reading(step.name, a)] if r is not None]
    for on, reading in [*resting, *readings]:  # its own "facing X" exactly (the search leaves it 45 degrees)
        turn = reading.orientation or reading.position
        if turn in (RelationName.FACING, RelationName.FACING_AWAY):
            toward = _centre(scene[on[0]]) - centre
            return -toward if turn == RelationName.FACING_AWAY else toward
    if own is None or own.orientation is not None:
        return None
    for on, reading in [*resting, *readings]:
        support = scene.get(on[0])
        if RELATIONS[reading.position].rests and reading.leant is None and support is not None:
            return support.front
    return None


def _centre(placed: Placed) -> np.ndarray:
    """The centre of a placed object's box, in the scene frame."""
    return _centre_of(placed.mesh, np.asarray(placed.to_scene.matrix))


def _check_also(base_name: str, steps: Sequence[Step]) -> None:
    """Every object a step's ``also`` relates to is an object of the assembly."""
    names = {base_name, *(s.name for s in steps)}
    for i, step in enumerate(steps):
        for k, also in enumerate(step.also):
            unknown = [n for n in also.on if n not in names]
            if unknown:
                raise ConfigError(f"step {i + 1} ({step.name}): also relates to {unknown[0]!r}, no object of the "
                                  f"assembly ({', '.join(sorted(names))})", field=f"steps.{i}.also.{k}.on")
