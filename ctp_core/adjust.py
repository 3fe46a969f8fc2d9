"""Adjust a result by hand: a placement a person moved (the page's handles), measured as the search measures
its poses, and, when asked, brought into contact first with the search's own ``contact.settle``.

Frames: the transform in and out maps the *source file* frame to the *target file* frame (a report's
``transform.matrix``, a result GLB's source node matrix); a ``direction`` is in the target file frame too (the
page's 3D view shows the GLB in it). Settling happens in the *normalised* frame (``pairs``), whose +Y is the
target's up: its upright turn as the job made it (``upright``, the report's ``extra.target_upright``), so "drop"
falls the way the run's views looked down.

``settle``:
- ``none``: measured where it is (the person moved it and wants it kept there);
- ``drop``: lowered along the target's up until it touches the target, or rests on the plane the target stands
  on (the search's floor proposals) when nothing of the target is under it; a source sunk into the target comes
  up out of it first;
- ``push``: moved along ``direction`` (the page sends its view direction, eye into the scene) until it touches;
  when nothing is met that way it is left where it was (``settled`` False).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any, Literal, get_args

import numpy as np
import torch
import trimesh

from ctp_core import contact, objective, orientation
from ctp_core.config import AlignConfig, schedule
from ctp_core.errors import ConfigError
from ctp_core.geometry import frames
from ctp_core.geometry.pose import Poses, apply_pose
from ctp_core.orientation import canonical
from ctp_core.pairs import PreparedPair, Target, prepare_pair
from ctp_core.reading.relation import RelationReading
from ctp_core.relations import predicates

Settle = Literal["none", "drop", "push"]
SETTLES: tuple[str, ...] = get_args(Settle)
ROUNDS = 8  # ``contact.settle`` calls at most: each runs its own few sphere-tracing steps
STILL = 1e-3  # source diagonals: a round that moved the source less than this ends the settling
FLOOR_POINTS = 256  # source samples whose lowest is kept on the floor plane


@dataclass(frozen=True)
class Adjusted:
    """An adjusted placement and how it sits (lengths in source diagonals, as the search's progress reports)."""

    source_to_target: np.ndarray  # (4, 4) source file -> target file
    settle: str
    settled: bool | None  # drop / push: whether it came to rest touching (False: nothing met, left as given)
    moved: float  # how far settling moved it (0 for ``none``)
    on_floor: bool  # drop: it rests on the plane the target stands on, not on the target
    penetration: float  # the search's ``sunk``: penetration over the posed source's diagonal (``ordering.SUNK``)
    contact_gap: float  # ``contact.contact_gap``: 0 when touching, within the target's sample spacing
    touching: bool  # ``contact_gap`` within ``contact.TOUCH``: what the answer's selection counts as touching
    relation: dict[str, Any] | None  # ``predicates.RelationVerdict`` of the report's relation here; None without

    @property
    def transform(self) -> frames.Similarity:
        return frames.Similarity(self.source_to_target, frames.SOURCE_FILE, frames.TARGET_FILE)

    def to_dict(self) -> dict[str, Any]:
        """The measures as JSON (the transform is the caller's to write, ``export.transform``)."""
        return {k: v for k, v in asdict(self).items() if k != "source_to_target"}


def adjust(target: Target, source: trimesh.Trimesh, source_to_target: np.ndarray, config: AlignConfig, *,
           settle: Settle = "none", direction: np.ndarray | None = None, upright: np.ndarray | None = None,
           on: str | Sequence[str] | None = None, reading: RelationReading | None = None) -> Adjusted:
    """Measure (and with ``settle``, first settle) the source at ``source_to_target`` against ``target``.

    ``config``: the job's (its loss samples, seed and penetration terms); ``upright``: (3, 3) target file ->
    upright rotation the job used (None: from the files first, by the job's up and front options,
    ``orientation``); ``on``, ``reading``: the job's (``RelationReading.from_verdict`` of its report), for the
    verdict. Runs on the CPU: one pose, no model.
    """
    if settle not in SETTLES:
        raise ConfigError(f"settle is one of {', '.join(SETTLES)}, not {settle!r}", field="settle")
    try:
        start = frames.checked_similarity(source_to_target, frames.SOURCE_FILE, frames.TARGET_FILE)
    except ValueError as exc:
        raise ConfigError(f"transform: {exc}", code="invalid_transform", field="transform") from None
    target_up = None
    if upright is not None:
        rotation = np.asarray(upright, dtype=np.float64)
        target_up = canonical.Upright(rotation, not np.allclose(rotation, np.eye(3)), "as the job turned it")
    pair = prepare_pair(target, source, samples=config.loss.samples, seed=config.seed, device="cpu",
                        canonicalise=config.upright, on=on, target_up=target_up, **orientation.configured(config))
    pose = predicates.poses_of(pair.local_to_normalised(start.matrix))
    settled, on_floor, moved, gap = None, False, 0.0, None
    if settle != "none":
        normal = _approach_normal(pair, settle, direction)
        placed, on_floor = _settle(pair, pose, normal, config.seed, floor=settle == "drop")
        placed_gap = float(contact.contact_gap(pair, placed)[0])
        settled = contact.touching(placed_gap) or on_floor
        if settled:
            moved = float((placed.t - pose.t).norm() / contact.source_diagonal(pair, pose)[0])
            pose, gap = placed, placed_gap
    with torch.no_grad():
        # one pose: a search of its samples' nearest costs less than the distance fields' builds (the verdict's
        # measure is the samples', as ``loss.distances`` samples measures); only the penetration is read: soft-ICP
        # off (ratio 0), so the search asks for the whole target's nearest samples alone
        scorer = objective.Scorer(pair, config.merged({"loss": {"distances": "samples"}}), contact_ratio=0.0)
        sunk = float(scorer.sunk(pose, schedule.phases(config, allow_penetration=False)[-1])[0])
        if gap is None:  # the pose as given (none, or a settling that met nothing)
            gap = float(contact.contact_gap(pair, pose)[0])
    verdict = predicates.verdict(pair, pose, reading)
    return Adjusted(source_to_target=pair.source_to_target(pose.matrices()[0]), settle=settle, settled=settled,
                    moved=round(moved, 5), on_floor=on_floor, penetration=round(sunk, 6), contact_gap=round(gap, 5),
                    touching=contact.touching(gap), relation=None if verdict is None else verdict.to_dict())


def read_back(scene: trimesh.Scene, source_to_target: np.ndarray, node: str | None = None
              ) -> tuple[Target, trimesh.Trimesh, str]:
    """A result scene (``export.arrangement_glb``, ``export.copies_glb``) as ``io.load_objects`` reads it back,
    every node moved into the target file frame, split into the target (its one mesh, or the other objects in their
    order), the source in its own file frame (the node ``node``, default the last, moved back by
    ``source_to_target``, the report's transform) and the source's node name."""
    names = list(scene.geometry)  # load_objects: one geometry per node, named as it, in the file's order
    if len(names) < 2:
        raise ConfigError(f"a result scene holds a target and a source; this one holds {len(names)} object(s)",
                          field="result.glb")
    name = names[-1] if node is None else node
    if name not in names:
        raise ConfigError(f"the result scene has no object {name!r}", field="result.glb")
    before = [n for n in names if n != name]
    back = frames.Similarity(source_to_target, frames.SOURCE_FILE, frames.TARGET_FILE).inverse()
    source = scene.geometry[name].copy().apply_transform(back.matrix)
    if len(before) == 1:
        target = scene.geometry[before[0]]
        target.metadata["name"] = before[0]  # saved again under its own name (export.arrangement_glb)
    else:
        target = trimesh.Scene()
        for part in before:
            target.add_geometry(scene.geometry[part], node_name=part, geom_name=part)
    return target, source, name


def _approach_normal(pair: PreparedPair, settle: str, direction: np.ndarray | None) -> torch.Tensor:
    """(3,) the normal ``contact.settle`` approaches against (it moves along -normal), normalised frame: +Y (up)
    for a drop, the opposite of ``direction`` (target file frame) for a push."""
    if settle == "drop":
        return torch.tensor([0.0, 1.0, 0.0])
    try:
        d = frames.checked_direction(direction)
    except ValueError as exc:
        raise ConfigError(f"push needs a direction (target file frame): {exc}", code="invalid_direction",
                          field="direction") from None
    along = pair.target_to_normalised.apply_directions(d[None])[0]
    return torch.as_tensor(-along / np.linalg.norm(along), dtype=torch.float32)


def _settle(pair: PreparedPair, pose: Poses, normal: torch.Tensor, seed: int, *,
            floor: bool) -> tuple[Poses, bool]:
    """``pose`` moved along -``normal`` by ``contact.settle`` (straight approach, the search's contact samples)
    until it stops moving; with ``floor``, never below the plane the target stands on (normalised +Y up). Returns
    the pose and whether the floor stopped it."""
    index = contact.contact_index(pair, seed=seed)
    diagonal = float(contact.source_diagonal(pair, pose)[0])
    level = pair.floor
    samples = pair.source_subset(FLOOR_POINTS) if floor else None
    t = pose.t.detach().clone()
    far = float(t.norm()) + 2 * (pair.target_radius + diagonal)  # past this it is only moving away from the target
    for _ in range(ROUNDS):
        centre, _ = contact.settle(pair, index, pose.q, t, normal[None], pose.log_s, on_surface=False,
                                     approach="straight")
        if floor:
            lowest = float(apply_pose(samples, centre, pose.q, pose.log_s)[0, :, 1].min())
            if lowest < level:  # nothing of the target under it: it rests where the target stands
                centre = centre + torch.tensor([0.0, level - lowest, 0.0])
                return Poses(centre, pose.q, pose.log_s), True
        still = float((centre - t).norm()) < STILL * diagonal
        t = centre
        if still or float(t.norm()) > far:
            break
    return Poses(t, pose.q, pose.log_s), False
