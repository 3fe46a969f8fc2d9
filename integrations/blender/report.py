"""What the add-on reads from a job's ``report.json``: the placements (the answer and its alternatives, or one per
copy of several of a kind) and the verdict and the guide's say in words for the panel."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

SOURCE_TO_TARGET = ("source_file", "target_file")


@dataclass(frozen=True)
class Placement:
    """One pose of the source: the report's 4x4 (row-major, source file -> target file) and what it says of it."""

    label: str
    matrix: list[list[float]]
    verdict: str


def placements(report: dict[str, Any]) -> list[Placement]:
    """Several of a kind: one per copy (``copies``), in order. Otherwise the answer and its alternatives, the answer
    first (``alternatives``; a report without them has the answer alone, ``transform``)."""
    if report.get("copies"):
        return [Placement(copy["name"], _matrix(copy["transform"]), verdict(copy.get("relation")))
                for copy in report["copies"]]
    found = report.get("alternatives") or [{"transform": report["transform"], "relation": report.get("relation"),
                                            "contact": report.get("contact")}]
    return [Placement("answer" if k == 0 else f"alternative {k + 1}", _matrix(alt["transform"]),
                      verdict(alt.get("relation"), alt.get("contact"))) for k, alt in enumerate(found)]


def _matrix(transform: dict[str, Any]) -> list[list[float]]:
    frames = (transform.get("from_frame"), transform.get("to_frame"))
    if frames != SOURCE_TO_TARGET:  # the frames placed_world is written for; anything else is not ours to guess
        raise ValueError(f"the report's transform maps {frames[0]} to {frames[1]}, not the source file to the "
                         "target file: this add-on does not know that service version")
    return transform["matrix"]


def verdict(relation: dict[str, Any] | None, contact: dict[str, Any] | None = None) -> str:
    """``'on' holds, stable, touching``: the geometry's judgement of the prompt's relation (``relations.predicates``)
    and whether the placement touches the target (the report's ``contact``, where it has one; a gap said as a share of
    the source's size, the diagonal its ``gap`` is measured in)."""
    words = ([f"'{relation['name']}' {'holds' if relation['holds'] else 'does not hold'}"] if relation else
             ["no relation read from the prompt"])
    if relation and relation.get("stable") is not None:
        words.append("stable" if relation["stable"] else "not stable")
    if contact:
        words.append("touching" if contact["touching"] else f"not touching: a gap of {100 * contact['gap']:.0f} % of "
                     "its size")
    if relation and relation.get("note"):
        words.append(relation["note"])
    return ", ".join(words)


def summary(report: dict[str, Any]) -> str:
    """The whole result in a line: the relation's verdict, or for copies how many hold and whether they intersect."""
    if report.get("copies"):
        m = report.get("metrics") or {}
        return (f"{m.get('relation_holds', 0)} of {m.get('judged', 0)} copies: '{report.get('relation')}' holds; "
                f"{'none intersect' if m.get('none_intersect') else 'some intersect'}")
    return verdict(report.get("relation"), report.get("contact"))


def guide(report: dict[str, Any]) -> str:
    """Which guide ran and, where it had one, its say in the choice (``ordering.GuideSay``'s summary)."""
    say = (report.get("guide_say") or {}).get("summary")
    return f"guide: {report.get('guide', 'unknown')}" + (f"; {say}" if say else "")
