"""The prompt's relation judged by the geometry: how far a posed source is from satisfying it.

``relation_score(pair, poses, reading)`` gives one value per pose, shape (B,), in the objective's batched layout:
0 when the relation holds, growing with the violation, in diagonals of the relation's *figure* (the thing placed;
the source unless the reading makes it the ground, ``RelationReading.source_is_figure``), so the same
arrangement scores the same at any file scale. Each score is a sum of smooth hinges (``hinge``) on distances
and heights measured in the normalised frame (+Y up, the target upright; ``pairs``), from surface samples and
their outward normals; it is differentiable in the pose (nearest-sample *selection* carries no gradient, as in
``losses``), so it can be a refinement term as well as a ranking key and a report. ``holds(score)`` is the
verdict; ``verdict`` packs one pose's verdict for reports (``RelationVerdict``). ``stable`` is the
centre-of-mass-over-support check, usable as a metric and as an objective term.

Roles: with the source as the figure ("a cup on a table") the figure is the posed source and the *ground* is
the target (the related object of a scene, ``PreparedPair.anchor``); with the source as the ground ("a table
under a vase") the same definitions are read the other way round: the target is the figure and the posed
source its ground. The definitions, in words, are in ``docs/relations.md`` and in each ``_score_*`` docstring.

Each relation's score and preference are its spec's (``registry.SPECS``: the kind modules ``resting``, ``contained``,
``attached``, ``apart``), under the name of its record in ``records.RELATIONS`` (which says the rest: resting,
stability, region weights); the measures they share are ``measures``'.

Directions (sides, orientations) are the ground's own (``axes``: its front from ``PreparedPair.target_front`` or the
posed source's ``source_front``), or the viewer's where the pair's fronts cannot be trusted; a reading of two
relations (``front+facing``) scores their sum.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import NamedTuple

import numpy as np
import torch

from ctp_core.geometry.pose import Poses
from ctp_core.pairs import PreparedPair
from ctp_core.reading.places import Place
from ctp_core.reading.records import RelationName, Role
from ctp_core.reading.relation import RelationReading
from ctp_core.relations.measures import Context, context, stability, surface_gap
from ctp_core.relations.registry import SPECS
from ctp_core.relations.spec import Spec

# --- constants (figure diagonals unless said otherwise) ------------------------------------------------------
HOLDS = 0.02  # a relation holds when its score is at most this (hinges are exactly 0 once within tolerance)


@dataclass(frozen=True)
class RelationVerdict:
    """One pose's relation, as reports show it: the name, the source's role, the score and the verdict."""

    name: str
    role: Role  # the source's: the figure (the thing placed) or the ground (the target is placed on/in/... it)
    score: float  # figure diagonals; 0 when it holds
    holds: bool
    stable: bool | None = None  # centre of mass over its support; None where the relation is not a resting one
    side: RelationName | None = None  # the side of the ground the figure is on, where the reading names one
    frame: str | None = None  # whose front sides and orientations are judged in: "target" (its own) or "viewer"
    each: list[dict] | None = None  # each relation of a reading of several ("front+facing"): name, score, holds
    note: str | None = None  # what the verdict cannot judge here (``UNHELD``: nothing in the pair holds the figure up)
    place: Place | None = None  # the place the prompt names (``reading.places``: "middle shelf", "edge"), if any
    pose: str | None = None  # how the source stands against how it is set down (its own up), where it is placed
    usual: str | None = None  # the ground's part the usual place is on, with why (``Spec.where``), else ``Spec.usual``

    def to_dict(self) -> dict:
        """The verdict as reports write it: ``side``, ``frame``, ``each``, ``note``, ``place``, ``usual`` and
        ``pose`` only where they say something."""
        out = asdict(self)
        optional = ("side", "frame", "each", "note", "place", "usual", "pose")
        return {k: v for k, v in out.items() if v is not None or k not in optional}


# the verdict's ``note`` where a relation that asks no support (not ``steady``: above, below, hang, ...) leaves its
# figure touching neither its ground nor the floor: what holds it (a cord, a bracket, the wall behind) is not in the
# pair, so ``stable`` is None rather than a claim either way
UNHELD = ("nothing in the pair holds it up (it touches neither its ground nor the floor): a cord, bracket or wall "
          "that would is not modelled, and stability is not judged")


def frame(pair: PreparedPair) -> str:
    """Whose front the sides and orientations are judged in: the target's own where it can be trusted
    (``PreparedPair.front_trusted``), else the viewer's (the preview's first camera)."""
    return "target" if pair.front_trusted else "viewer"


def holds(scores: torch.Tensor | float) -> torch.Tensor | bool:
    """The verdict of scores from ``relation_score``: at most ``HOLDS``."""
    if isinstance(scores, torch.Tensor):
        return scores <= HOLDS
    return bool(scores <= HOLDS)


# --- the relations ------------------------------------------------------------------------------------------------
def relation_score(pair: PreparedPair, poses: Poses, reading: RelationReading | None) -> torch.Tensor:
    """(B,) how far each pose is from satisfying the ``reading`` (figure diagonals; 0 when it holds).

    A reading that makes the source the ground reads it the other way round (the target placed relative to the
    posed source). An unknown relation or None has no term: zeros. Differentiable in ``poses``.
    """
    if reading is None:
        return torch.zeros(len(poses), device=poses.t.device)
    return _score(context(pair, poses, reading), reading)


class RelationTerms(NamedTuple):
    """The objective's relation terms of B poses, each (B,) (``terms``)."""

    rel: torch.Tensor  # ``relation_score``
    stable: torch.Tensor  # ``stable`` where the reading asks it besides its score
    prefer: torch.Tensor  # ``preference``


def terms(pair: PreparedPair, poses: Poses, reading: RelationReading | None) -> RelationTerms:
    """``rel`` (``relation_score``), ``stable`` (``stable`` for the readings it applies to that do not rest on
    their ground, ``Relation.steady`` but not ``rests``: the resting ones include it in their score; zeros
    otherwise) and ``prefer`` (``preference``), from one posing of the samples and one support footprint per pose
    (the objective's relation terms)."""
    zeros = torch.zeros(len(poses), device=poses.t.device)
    if reading is None:
        return RelationTerms(zeros, zeros, zeros)
    c = context(pair, poses, reading)
    steady = stability(c) if reading.steady and not reading.rests else zeros
    return RelationTerms(_score(c, reading), steady, sum(_prefer(c, p) for p in reading.relations))


def stable(pair: PreparedPair, poses: Poses, reading: RelationReading | None = None) -> torch.Tensor:
    """(B,) how far the figure's centre of mass is from being over its support (figure diagonals, hinged; 0 when
    stable): its horizontal projection against the convex footprint of the samples touching ground surface that
    does not face down, or the floor. The figure is the reading's (the source without one). Differentiable in
    ``poses``; ``holds`` gives the verdict."""
    return stability(context(pair, poses, reading))


def preference(pair: PreparedPair, poses: Poses, reading: RelationReading | None) -> torch.Tensor:
    """(B,) how far each pose is from the *usual* arrangement of a relation that holds in many places (lower is
    better, about 0 to 2; zeros where the relation says nothing more): "a cup on the table" holds on the whole
    top, the corner included, and geometry at contact (soft-ICP) favours corners and edges, where more target
    samples fall near the source. Read among poses where the relation holds; never part of the verdict.

    - resting (``on``, ``stand``, ``sit``, ``lie``): standing as it is set down, steadily, on the *usual surface*
      (``parts.usual_spot``: a table's top, a chair's seat, the shelf the prompt names) in the middle of its
      free area; on the top near the middle where no surface holds the figure (a spire, a head);
    - ``front``, ``behind``, ``left``, ``right``, ``beside``: standing, centred on that side (``beside``: a lateral
      one), a hand's width out (``parts.side_place``);
    - ``lean``: heavy end down, nearly upright, centred on a side a person leans things on (``lean_order``);
    - ``in``, ``under``: near the middle; ``in`` also *held by its sides* (1 less ``_enclosure``: the
      share of horizontal directions from the figure's foot that meet the ground: 1 in a mug, a bun, a candle
      holder's cup; a candle within the convex hull of a candelabra's open frame, where "in" holds too, is
      half surrounded at best);
    - ``wear``: on the top (``drop``: the highest summit, a head's, not a shoulder);
    - ``hang``: hung freely from something that bears it (``_borne``): a ring on a peg, its centre straight
      below the peg, rather than flat against the wall the peg stands out from (where the contact above its
      centre is with the wall's side) or hooked over the wall's top edge with its centre out in front;
    - ``penetrate``: near the middle, *end first* (``_end_first``: a stick stuck into a block stands in its top
      rather than lying sunk along it) and *from above the floor* (the figure's depth below the floor the ground
      stands on, in figure diagonals: driven up through a block's base it would pass through the floor);
    - ``below``: on the floor (a box below a hung lamp stands under it), near the middle;
    - the others (``attach``, ``hold``, ``wrap``, ``above``, ``near``, ``far``, the orientations): zeros (their
      ``Judge`` has no preference).
    Differentiable in ``poses`` but for the counts (a refinement term: ``objective.PREFER`` x ``lambda_rel``,
    and with a guide only as far as it cannot tell poses apart, ``Scorer.relation_terms``).
    """
    if reading is None or all(SPECS[p].judge.preference is None for p in reading.relations):
        return torch.zeros(len(poses), device=poses.t.device)
    c = context(pair, poses, reading)
    return sum(_prefer(c, p) for p in reading.relations)


def _score(c: Context, reading: RelationReading) -> torch.Tensor:
    """The sum of the scores of the relations a reading names (each 0 when it holds)."""
    return sum(SPECS[p].judge.score(c) for p in reading.relations)


def _prefer(c: Context, relation: RelationName) -> torch.Tensor:
    """One relation's ``preference`` (zeros where it says nothing more)."""
    prefer = SPECS[relation].judge.preference
    return torch.zeros_like(c.unit) if prefer is None else prefer(c)


def verdict(pair: PreparedPair, pose: Poses | np.ndarray, reading: RelationReading | None) -> RelationVerdict | None:
    """One pose's verdict (a 1-pose ``Poses`` or a 4x4 source local -> normalised); None without a known relation."""
    if reading is None:
        return None
    if not isinstance(pose, Poses):
        pose = poses_of(pose, pair.source_samples.device)
    named = reading.relations
    with torch.no_grad():
        c = context(pair, pose, reading)
        each = [float(SPECS[p].judge.score(c)[0]) for p in named]
        steady = bool(holds(float(stability(c)[0]))) if reading.steady else None
        unheld = not reading.steady and not bool(_held(c)[0])
        usual = _usual(c, SPECS[reading.position])
        stands = None if c.upright is None else _stands(pair, float(c.upright[0]))
    return RelationVerdict(
        reading.name, reading.role, round(sum(each), 4), bool(holds(sum(each))),
        steady, reading.side, frame(pair) if reading.directional else None,
        [{"name": p, "score": round(e, 4), "holds": bool(holds(e))} for p, e in zip(named, each, strict=True)]
        if len(named) > 1 else None, UNHELD if unheld else None, place=reading.place, usual=usual, pose=stands)


UPRIGHT_DEG = 10.0  # ``_stands``: within this of its own up, a source stands as it is set down


def _stands(pair: PreparedPair, upright: float) -> str:
    """How the source stands against how it is set down (``measures.Context.upright``: 1 less the cosine between its
    own up and +Y), with where its own up comes from (``source_upright``'s reason)."""
    angle = math.degrees(math.acos(max(-1.0, min(1.0, 1.0 - upright))))
    why = pair.source_upright.reason
    if angle <= UPRIGHT_DEG:
        return f"standing as it is set down ({why})"
    return f"turned {angle:.0f} deg from how it is set down ({why})"


def _usual(c: Context, spec: Spec) -> str | None:
    """The part of the ground the usual place is on, with why (``Spec.where``), else the spec's usual place in
    words (``Spec.usual``); None where it has neither."""
    where = spec.where(c) if spec.where is not None else None
    return where or spec.usual or None


def _held(c: Context) -> torch.Tensor:
    """(B,) whether anything in the pair can hold the figure up: it touches its ground (any surface: it rests on
    it, hangs from it or is fixed to it) or stands on the floor."""
    gap, _ = surface_gap(c.figure.points, c.ground)
    on_floor = c.figure.points[..., 1] - c.floor[:, None] <= c.tol()[:, None]
    return ((gap <= c.reach()[:, None]) | on_floor).any(-1)


def poses_of(matrix: np.ndarray, device: str | torch.device = "cpu") -> Poses:
    """A 1-pose ``Poses`` from a (4, 4) similarity, source local -> normalised."""
    from ctp_core.geometry.pose import matrix_to_quaternion

    m = np.asarray(matrix, dtype=np.float64)
    scale = float(np.cbrt(abs(np.linalg.det(m[:3, :3]))))
    q = matrix_to_quaternion(m[:3, :3] / scale)
    as_t = lambda a: torch.as_tensor(np.array(a), dtype=torch.float32, device=device)  # noqa: E731
    return Poses(as_t(m[None, :3, 3]), as_t(q[None]), as_t([math.log(scale)]))
