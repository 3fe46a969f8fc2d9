"""The relations' records: every relation the reader knows, with all that is known of it without the geometry.

A relation has a *figure* (the thing placed: the hat, the cup, the arrow) and a *ground* (the head, the table, the
target). Its record says how much of each touches the other, how large the figure usually is, whether it goes into
its ground, its *kind* (what it says of where the figure is), and the classifications the reader, the priors and
the planner read (``supports``, ``rests``, ``steady``, ``agent``, ``grounds``, ``aside``): nothing outside a record
sorts relations by name. What the geometry does with a relation (its score, preference, builder, scale bound and
usual place) is its spec's (``relations.registry.SPECS``), under the same ``RelationName``.

Adding a relation: its name in ``RelationName``, its record here, its wordings in ``cues.CUES``, its spec in the
kind module of ``relations`` it belongs to, its tests and its entry in docs/relations.md
(docs/relations.md, "Adding a relation"). Torch-free: the service reads it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum


class RelationName(StrEnum):
    """Every relation's name, as reports, plans and the priors write it."""

    PENETRATE = "penetrate"
    WEAR = "wear"
    HOLD = "hold"
    SIT = "sit"
    LIE = "lie"
    STAND = "stand"
    WRAP = "wrap"
    LEAN = "lean"
    HANG = "hang"
    ATTACH = "attach"
    UNDER = "under"
    BESIDE = "beside"
    IN = "in"
    ON = "on"
    FRONT = "front"
    BEHIND = "behind"
    LEFT = "left"
    RIGHT = "right"
    ABOVE = "above"
    BELOW = "below"
    NEAR = "near"
    FAR = "far"
    FACING = "facing"
    FACING_AWAY = "facing_away"
    ALIGNED = "aligned"
    BETWEEN = "between"


class Kind(StrEnum):
    """What a relation says of where the figure is.

    ``contact``: it touches or rests on its ground; ``side``: beside the ground on one of its sides, in its own
    frame; ``vertical``: over or under the ground, a gap between them; ``distance``: near, next to or far from it;
    ``orientation``: which way the figure's front points (said alone or after a position); ``between``: in the gap
    between two grounds."""

    CONTACT = "contact"
    SIDE = "side"
    VERTICAL = "vertical"
    DISTANCE = "distance"
    ORIENTATION = "orientation"
    BETWEEN = "between"


PLACING = frozenset({Kind.CONTACT, Kind.SIDE, Kind.VERTICAL, Kind.DISTANCE, Kind.BETWEEN})  # say where the figure is


class Penetration(StrEnum):
    """Whether the figure goes into its ground: ``yes`` (cut, pierce, embed ... unless the ground is a container: a
    key stuck in a lock goes into the keyhole), ``if_pointed`` ("in", "through": an arrow in a target yes, a spoon in
    a cup no) or ``no``."""

    YES = "yes"
    IF_POINTED = "if_pointed"
    NO = "no"


class Role(StrEnum):
    """Which part of a relation an object plays: the figure (the thing placed) or the ground."""

    FIGURE = "figure"
    GROUND = "ground"


@dataclass(frozen=True)
class Relation:
    """One relation's record.

    ``figure_contact``, ``ground_contact``: the share of the figure's and of the ground's surface in contact.
    ``figure_size``: the figure's size over the ground's when the lexicon does not know one of them; what sits on,
    in or hangs from something is usually the smaller of the two. ``penetration``, ``kind``: above.
    ``rests``: the figure rests on its ground from above (the resting family: its score includes stability).
    ``steady``: stability applies (``predicates.stable``): what stands on something, the ground or the floor, rather
    than hangs, is fixed or goes into it. ``supports``: the ground holds the figure up (it rests on, leans on, hangs
    from or is attached to it: where a ball touches at a point, a sheet lies on a face, ``priors.rules``).
    ``agent``: the role played by someone when the lexicon does not know the name (an unknown wearer or holder is
    the ground, an unknown sitter the figure: taken as a person). ``grounds``: how many objects the figure is placed
    relative to. ``aside``: a cue of it may be about another object named right after it ("a cup on the table to
    the left of the plate"): the reader then sets it aside (``passes``).
    ``figure_regions``, ``ground_regions``: the search's region weights (``proposals.REGIONS``) when the source is
    the figure and when it is the ground; regions not named weigh 1 (weights shift proposals toward where the
    relation puts the figure, never away from everywhere else).
    """

    name: RelationName
    figure_contact: float
    ground_contact: float
    figure_size: float
    penetration: Penetration = Penetration.NO
    kind: Kind = Kind.CONTACT
    rests: bool = False
    steady: bool = False
    supports: bool = False
    agent: Role | None = None
    grounds: int = 1
    aside: bool = False
    figure_regions: dict[str, float] = field(default_factory=dict)
    ground_regions: dict[str, float] = field(default_factory=dict)


_AROUND = {"gap": 4.0, "side": 2.0, "floor": 3.0}  # the floor around the ground: beside it, on a side, near, far


def _apart(name: RelationName, kind: Kind, size: float = 1.0, steady: bool = True) -> Relation:
    """A relation without contact said of where or which way (a cue of it may be about another object); every one
    but ``above`` and ``below`` stands on the floor around the ground."""
    around = _AROUND if kind in (Kind.SIDE, Kind.DISTANCE, Kind.ORIENTATION) else {}
    return Relation(name, 0.0, 0.0, size, kind=kind, steady=steady, aside=True, figure_regions=around,
                    ground_regions=around)


R = RelationName
RELATIONS: dict[RelationName, Relation] = {r.name: r for r in (
    # the buried part of a blade, arrow or nail
    Relation(R.PENETRATE, 0.25, 0.1, 0.8, Penetration.YES, figure_regions={"top": 1.5, "side": 1.5, "drop": 1.5}),
    # a hat's inner band; garments that wrap get more (rules)
    Relation(R.WEAR, 0.35, 0.1, 0.2, steady=True, agent=Role.GROUND, figure_regions={"top": 4.0, "drop": 4.0},
             ground_regions={"bottom": 3.0}),
    Relation(R.HOLD, 0.1, 0.05, 0.3, agent=Role.GROUND, figure_regions={"side": 2.0}),  # a hand closes around a handle
    # a rider or sitter: seat, legs, hands
    Relation(R.SIT, 0.2, 0.2, 0.6, rests=True, steady=True, supports=True, agent=Role.FIGURE,
             figure_regions={"top": 3.0, "drop": 3.0}, ground_regions={"bottom": 3.0}),
    # lying or draped: one side
    Relation(R.LIE, 0.35, 0.05, 0.3, rests=True, steady=True, supports=True, figure_regions={"top": 3.0, "drop": 3.0},
             ground_regions={"bottom": 3.0}),
    # feet or a foot only
    Relation(R.STAND, 0.05, 0.02, 0.3, rests=True, steady=True, supports=True,
             figure_regions={"top": 4.0, "drop": 3.0}, ground_regions={"bottom": 4.0}),
    Relation(R.WRAP, 0.6, 0.2, 0.3, figure_regions={"side": 2.0}),  # coiled or tied around
    # an end or an edge
    Relation(R.LEAN, 0.05, 0.02, 0.8, steady=True, supports=True, figure_regions={"side": 3.0, "floor": 2.0}),
    # a loop on a hook
    Relation(R.HANG, 0.05, 0.02, 0.2, supports=True, figure_regions={"side": 2.0, "bottom": 2.0}),
    # glued, taped, mounted: a face or a foot
    Relation(R.ATTACH, 0.3, 0.05, 0.2, supports=True, figure_regions={"side": 2.0, "drop": 2.0}),
    # "a ball under the table" does not touch it: on the floor below the ground
    Relation(R.UNDER, 0.0, 0.05, 0.5, kind=Kind.VERTICAL, steady=True,
             figure_regions={"bottom": 3.0, "gap": 2.0, "floor": 4.0}, ground_regions={"top": 4.0, "drop": 3.0}),
    # next to: no contact
    Relation(R.BESIDE, 0.0, 0.0, 1.0, kind=Kind.DISTANCE, steady=True, figure_regions=_AROUND, ground_regions=_AROUND),
    # contained: the bottom and some of the walls
    Relation(R.IN, 0.25, 0.15, 0.5, Penetration.IF_POINTED, steady=True,
             figure_regions={"inside": 4.0, "top": 1.5, "drop": 2.0}),
    # resting on: its base
    Relation(R.ON, 0.15, 0.05, 0.3, rests=True, steady=True, supports=True, figure_regions={"top": 4.0, "drop": 4.0},
             ground_regions={"bottom": 4.0}),
    # where, without contact: beside the ground on one of its sides, above or below it, near or far from it
    *(_apart(side, Kind.SIDE) for side in (R.FRONT, R.BEHIND, R.LEFT, R.RIGHT)),
    _apart(R.ABOVE, Kind.VERTICAL, 0.5, steady=False),  # a painting above a sofa, a lamp over a table: hung or fixed
    _apart(R.BELOW, Kind.VERTICAL, 0.5, steady=False),
    _apart(R.NEAR, Kind.DISTANCE),
    _apart(R.FAR, Kind.DISTANCE),
    # which way the figure's front points, relative to the ground
    *(_apart(name, Kind.ORIENTATION) for name in (R.FACING, R.FACING_AWAY, R.ALIGNED)),
    # two grounds: on the floor in the gap between them, clear of both
    Relation(R.BETWEEN, 0.0, 0.0, 0.5, kind=Kind.BETWEEN, steady=True, grounds=2, aside=True,
             figure_regions={"floor": 4.0, "gap": 2.0}),
)}
del R
# the kinds whose figure stands where its ground stands (on the same table, on the floor): beside, the sides, near,
# between, facing
ALONGSIDE = frozenset({Kind.SIDE, Kind.DISTANCE, Kind.BETWEEN, Kind.ORIENTATION})
# where an orientation said alone puts the figure: "a chair facing the desk" stands near the desk, not across the room
ORIENTED_NEAR = RelationName.NEAR


def check() -> list[str]:
    """What is inconsistent among the records (empty when nothing is): every name has one record, filed under it."""
    problems = [f"{name}: a name without a record" for name in RelationName if name not in RELATIONS]
    problems += [f"{name}: filed under another name" for name, record in RELATIONS.items() if record.name != name]
    problems += [f"{name}: {record.grounds} grounds for a relation of kind {record.kind}"
                 for name, record in RELATIONS.items() if (record.grounds == 2) != (record.kind == Kind.BETWEEN)]
    return problems
