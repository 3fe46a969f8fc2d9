"""Where on (or beside) the ground the prompt asks for, when it says so: the words that override the usual place.

A relation's usual place (``relations.spec.Spec.usual``) is where people put the figure when nothing more is said:
the middle of a table's top, the middle of a side. A prompt may name another: "at the edge of", "in the corner of",
"on the middle shelf", "on the left end". ``read`` gives that place (one of ``_PATTERNS``' names; None where the prompt
names none); the relations' preferences read it (``relations.parts``). Torch-free.
"""

from __future__ import annotations

import re

# (place, pattern), first match wins; the patterns read the prompt lower-cased
_PATTERNS: tuple[tuple[str, str], ...] = (
    ("lower shelf", r"\b(?:lower|lowest|bottom) (?:shelf|board|tier|level)\b"),
    ("middle shelf", r"\b(?:middle|centre|center|second) (?:shelf|board|tier|level)\b"),
    ("upper shelf", r"\b(?:upper|uppermost|highest) (?:shelf|board|tier|level)\b"),
    ("top shelf", r"\btop (?:shelf|board|tier|level)\b"),
    ("edge", r"\b(?:at|on|by|near) the (?:very )?(?:edge|rim|brink|lip)\b|\bedge of\b"),
    ("corner", r"\b(?:in|at|on) (?:the|a|one) (?:far |near )?corner\b"),
    ("left end", r"\b(?:at|on) the left(?:-hand)? (?:end|side of the top)\b"),
    ("right end", r"\b(?:at|on) the right(?:-hand)? (?:end|side of the top)\b"),
    ("end", r"\b(?:at|on) (?:the|one|either) (?:far |near )?end\b"),
    ("head", r"\b(?:at|by) the head of\b"),
    ("foot", r"\b(?:at|by) the foot of\b"),
    ("top", r"\bon (?:the )?top of\b|\batop\b|\bon top\b"),
)
SHELVES = {"lower shelf": 0.0, "middle shelf": 0.5, "upper shelf": 1.0, "top shelf": 1.0}  # order from the bottom
ENDS = ("edge", "corner", "end", "left end", "right end", "head", "foot")  # away from the middle


def read(prompt: str) -> str | None:
    """The place the prompt names (the first of ``_PATTERNS`` that matches), or None."""
    text = " ".join(prompt.lower().split())
    return next((place for place, pattern in _PATTERNS if re.search(pattern, text)), None)
