"""Where on (or beside) the ground the prompt asks for, when it says so: the words that override the usual place.

A relation's usual place (``relations.spec.Spec.usual``) is where people put the figure when nothing more is said:
the middle of a table's top, the middle of a side. A prompt may name another: "at the edge of", "in the corner of",
"on the middle shelf", "on the left end". ``read_place`` gives that place (a ``Place``; None where the prompt names
none); the relations' preferences read it (``relations.parts``, whose ``PARTS`` registry says which part each place
selects). Torch-free.
"""

from __future__ import annotations

import re
from enum import StrEnum


class Place(StrEnum):
    """Where on or beside the ground a prompt may name (the parts that select each are ``relations.parts.PARTS``'s)."""

    LOWER_SHELF = "lower shelf"
    MIDDLE_SHELF = "middle shelf"
    UPPER_SHELF = "upper shelf"
    TOP_SHELF = "top shelf"
    EDGE = "edge"
    CORNER = "corner"
    LEFT_END = "left end"
    RIGHT_END = "right end"
    END = "end"
    HEAD = "head"
    FOOT = "foot"
    TOP = "top"


class PartName(StrEnum):
    """The parts of a ground the geometry names (``relations.parts.PARTS``: each with its detector and the places
    that select it)."""

    TOP = "top"
    SHELF = "shelf"
    SEAT = "seat"
    SURFACE = "surface"
    SIDE = "side"
    BAR = "bar"
    OPENING = "opening"
    RIM = "rim"


# Words for a ground's parts and places, never an object's name ("on top of it", "to its left", "in the middle of").
PLACE_WORDS = frozenset({"top", "front", "back", "left", "right", "side", "sides", "middle", "centre", "center",
                         "edge", "corner", "end", "rear", "other", "bottom", "one", "way", "foot", "head", "rim"})

# A ground's parts a possessive names ("on its seat", "the bench's seat", "on the top shelf of the bookcase"): the
# ground is the possessor; the words are its place where ``read_place`` reads one, else dropped.
PART_WORDS = frozenset({"seat", "seats", "shelf", "shelves", "surface", "tabletop", "worktop", "countertop", "lid",
                        "ledge", "armrest", "backrest", "mattress", "tier", "board", "deck", "platform", "base",
                        "arm", "arms", "leg", "legs", "handle", "drawer", "drawers", "doors", "roof", "hood"})

P = Place
# (place, pattern), first match wins; the patterns read the prompt lower-cased
_PATTERNS: tuple[tuple[Place, str], ...] = (
    (P.LOWER_SHELF, r"\b(?:lower|lowest|bottom) (?:shelf|board|tier|level)\b"),
    (P.MIDDLE_SHELF, r"\b(?:middle|centre|center|second) (?:shelf|board|tier|level)\b"),
    (P.UPPER_SHELF, r"\b(?:upper|uppermost|highest) (?:shelf|board|tier|level)\b"),
    (P.TOP_SHELF, r"\btop (?:shelf|board|tier|level)\b"),
    (P.EDGE, r"\b(?:at|on|by|near) the (?:very )?(?:edge|rim|brink|lip)\b|\bedge of\b"),
    (P.CORNER, r"\b(?:in|at|on) (?:the|a|one) (?:far |near )?corner\b"),
    (P.LEFT_END, r"\b(?:at|on) the left(?:-hand)? (?:end|side of the top)\b"),
    (P.RIGHT_END, r"\b(?:at|on) the right(?:-hand)? (?:end|side of the top)\b"),
    (P.END, r"\b(?:at|on) (?:the|one|either) (?:far |near )?end\b"),
    (P.HEAD, r"\b(?:at|by) the head of\b"),
    (P.FOOT, r"\b(?:at|by) the foot of\b"),
    (P.TOP, r"\bon (?:the )?top of\b|\batop\b|\bon top\b"),
)
del P
# a shelf named by its order from the bottom (0: the lowest, 1: the highest)
SHELVES = {Place.LOWER_SHELF: 0.0, Place.MIDDLE_SHELF: 0.5, Place.UPPER_SHELF: 1.0, Place.TOP_SHELF: 1.0}
# away from the middle of a surface
OFF_MIDDLE = frozenset({Place.EDGE, Place.CORNER, Place.END, Place.LEFT_END, Place.RIGHT_END, Place.HEAD, Place.FOOT})


def read_place(prompt: str) -> Place | None:
    """The place the prompt names (the first of ``_PATTERNS`` that matches), or None."""
    text = " ".join(prompt.lower().split())
    return next((place for place, pattern in _PATTERNS if re.search(pattern, text)), None)
