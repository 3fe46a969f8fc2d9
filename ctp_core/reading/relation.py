"""The relation a run uses: one small record, read once from the priors and passed as one value.

A reading says where the figure is (its ``position``: one relation), and may say more about the same ground: the
side of the ground a lean touches ("against the back of the sofa": lean, ``leant`` behind) and which way the figure
is turned ("in front of the sofa, facing it": front, ``orientation`` facing). Reports write it as one name, the
relations joined by ``JOIN`` (``front+facing``, ``lean+behind``); ``parse`` reads that name back. An orientation
said alone reads with the distance it implies (``parse``: "facing" is near, then facing). Torch-free.
"""

from __future__ import annotations

from dataclasses import dataclass

from ctp_core.reading.places import Place
from ctp_core.reading.records import ORIENTED_NEAR, RELATIONS, Kind, Relation, RelationName, Role

JOIN = "+"  # between the relations of a reading, in the name reports write


@dataclass(frozen=True)
class RelationReading:
    """``position``: where the figure is (or an orientation's implied distance); ``leant``: the side of the ground a
    lean touches; ``orientation``: which way the figure's front points; ``role``: what the source plays; ``place``:
    where on or beside the ground the prompt names (``places.read_place``), None for the usual place."""

    position: RelationName
    leant: RelationName | None = None
    orientation: RelationName | None = None
    role: Role = Role.FIGURE
    place: Place | None = None

    @classmethod
    def of(cls, *relations: RelationName | str, role: Role | str = Role.FIGURE, place: str | None = None
           ) -> RelationReading:
        """The reading of these relations, the position first: the others are the side a lean touches and an
        orientation. An orientation said alone ("a chair facing the desk") places its figure ``ORIENTED_NEAR`` its
        ground too: which way a front points says nothing of where, and a user who names the ground by it means the
        figure to stand by it. ValueError for a name of no relation, or more than a reading says."""
        position, *more = [_record(r).name for r in relations]
        if RELATIONS[position].kind == Kind.ORIENTATION:
            position, more = ORIENTED_NEAR, [position, *more]
        leant = next((r for r in more if RELATIONS[r].kind == Kind.SIDE), None)
        orientation = next((r for r in more if RELATIONS[r].kind == Kind.ORIENTATION), None)
        if len(more) != (leant is not None) + (orientation is not None):
            raise ValueError(f"a reading is a position, the side a lean touches and an orientation: {relations}")
        return cls(position, leant, orientation, Role(role), None if place is None else Place(place))

    @classmethod
    def parse(cls, name: str, role: Role | str = Role.FIGURE, place: str | None = None) -> RelationReading:
        """The reading a report's name stands for (``front+facing``, ``on``: ``of`` its relations)."""
        return cls.of(*name.split(JOIN), role=role, place=place)

    @classmethod
    def from_verdict(cls, verdict: dict | None) -> RelationReading | None:
        """The reading a report's ``relation`` (``predicates.RelationVerdict.to_dict``) was judged with; None
        without one."""
        if not verdict or verdict.get("name") is None:
            return None
        return cls.parse(verdict["name"], Role.GROUND if verdict.get("role") == "ground" else Role.FIGURE,
                         verdict.get("place"))

    @property
    def name(self) -> str:
        """The name reports write: its relations joined by ``JOIN``."""
        return JOIN.join(self.relations)

    @property
    def relations(self) -> tuple[RelationName, ...]:
        """The relations it names, the position first."""
        return tuple(r for r in (self.position, self.leant, self.orientation) if r is not None)

    @property
    def records(self) -> tuple[Relation, ...]:
        """The record of each relation it names."""
        return tuple(RELATIONS[r] for r in self.relations)

    @property
    def source_is_figure(self) -> bool:
        return self.role == Role.FIGURE

    @property
    def side(self) -> RelationName | None:
        """The side of the ground it puts the figure on (``front``, ``behind``, ``left``, ``right``), if any."""
        return next((r.name for r in self.records if r.kind == Kind.SIDE), None)

    @property
    def rests(self) -> bool:
        """Whether a relation it names rests on the ground (its score includes stability)."""
        return any(r.rests for r in self.records)

    @property
    def steady(self) -> bool:
        """Whether stability applies to a relation it names."""
        return any(r.steady for r in self.records)

    @property
    def directional(self) -> bool:
        """Whether a relation it names is judged in a frame (a side or an orientation): the verdict says whose."""
        return any(r.kind in (Kind.SIDE, Kind.ORIENTATION) for r in self.records)

    @property
    def regions(self) -> dict[str, float]:
        """The search's region weights of its position, for the source's role (unnamed regions weigh 1)."""
        record = RELATIONS[self.position]
        return record.figure_regions if self.source_is_figure else record.ground_regions


def _record(name: str) -> Relation:
    """The record of a relation named ``name``; ValueError where there is none."""
    record = RELATIONS.get(name)  # type: ignore[call-overload]  # a name as read, its record's key if it has one
    if record is None:
        raise ValueError(f"no relation is named {name!r}")
    return record
