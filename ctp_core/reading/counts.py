"""Several of a kind: how many copies of the source a run places and how they stand together.

"three apples in the bowl", "a pair of vases on the shelf", "four chairs around the table", "5 books in a row on
the shelf", "a dozen eggs", "a stack of plates". ``read_count`` finds the number (a numeral, a number word up to twenty,
"a pair/couple of", "a dozen", "half a dozen") and an arrangement cue; ``choose`` settles a run's count and
arrangement (the options over the prompt, bounded by ``MAX_COPIES``); ``one_copy`` is the prompt each copy is
read and guided by: the number and the arrangement's words taken out, so the relation reader sees "apples in the
bowl", "books on the shelf" (not "in" from "in a row"), and "around" becomes "beside ..., facing it" (chairs stand
beside a table and face it; the reader's "around" is ``wrap``, a scarf around a neck). Torch-free: the API and
the CLI check a submission with it before the engine loads.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from ctp_core.errors import ConfigError
from ctp_core.reading.records import RelationName
from ctp_core.reading.relation import RelationReading

ARRANGEMENTS = ("scatter", "around", "row", "stack")  # how copies stand together (``ctp_core.assembly.copies``)
CHOICES = ("auto", *ARRANGEMENTS)  # the option's values: auto is the prompt's cue, else scatter
MAX_COPIES = 12  # a run's copies at most: each is a placement of its own, and the set's checks are pairwise
SEVERAL = 3  # copies where a collective noun says several but no number ("a stack of plates", "a row of books")
# what each copy around the target is judged by, whatever the prompt's words
AROUND = RelationReading(RelationName.BESIDE, orientation=RelationName.FACING)

NUMBER_WORDS = {"one": 1, "two": 2, "three": 3, "four": 4, "five": 5, "six": 6, "seven": 7, "eight": 8, "nine": 9,
                "ten": 10, "eleven": 11, "twelve": 12, "thirteen": 13, "fourteen": 14, "fifteen": 15, "sixteen": 16,
                "seventeen": 17, "eighteen": 18, "nineteen": 19, "twenty": 20}
_PHRASES = {"half a dozen": 6, "a dozen": 12, "one dozen": 12, "a pair of": 2, "a couple of": 2, "a trio of": 3}
# one object named as a pair: "a pair of glasses" is one pair of glasses, not two
ONE_PAIR = {"glasses", "sunglasses", "spectacles", "goggles", "binoculars", "scissors", "shears", "pliers", "tongs",
             "tweezers", "trousers", "pants", "jeans", "shorts", "leggings", "tights", "pajamas", "pyjamas",
             "headphones", "earphones", "handcuffs", "overalls", "dungarees"}
# a number before a word (an object), not before a unit ("2 m", "3 cm tall") or a time
_UNITS = r"(?:mm|cm|m|km|in|inch(?:es)?|ft|feet|foot|meters?|metres?|centimet(?:er|re)s?|times|o'clock|percent|%)\b"
_COUNT = re.compile(
    r"\b(?P<phrase>" + "|".join(sorted(map(re.escape, _PHRASES), key=len, reverse=True)) + r")\b"
    r"|\b(?P<number>\d{1,3}|" + "|".join(NUMBER_WORDS) + r")\b(?=\s+(?!" + _UNITS + r")[a-z])", re.IGNORECASE)
_AROUND = re.compile(r"(?<!wrapped )(?<!coiled )(?<!tied )(?<!wound )(?<!looped )\b(?:a)?round\b"
                     r"|\b(?:surrounding|encircling|circling)\b", re.IGNORECASE)
_ROW = re.compile(r"\bin (?:a |one )?(?:row|line)\b|\b(?:a )?(?:row|line) of\b|\blined up\b|\bside by side\b",
                  re.IGNORECASE)
_STACK = re.compile(r"\b(?:a )?(?:stack|pile|tower) of\b|\bstacked(?: up)?\b|\bpiled(?: up)?\b"
                    r"|\bon top of (?:each|one) other\b", re.IGNORECASE)
_CUES = (("stack", _STACK), ("row", _ROW), ("around", _AROUND))
# what says several without a number: "a stack of", "a row of" (not "around": "a necklace around her neck" is one)
_COLLECTIVE = re.compile(r"\b(?:stack|pile|tower|row|line)s? of\b", re.IGNORECASE)


@dataclass(frozen=True)
class CountReading:
    """What a prompt says about several of a kind: the number (None: not said), the arrangement (None: not said),
    the words each came from, and whether a collective noun says several ("a stack of plates")."""

    count: int | None
    arrangement: str | None
    why: str
    several: bool = False

    def to_dict(self) -> dict:
        return {"count": self.count, "arrangement": self.arrangement, "why": self.why, "several": self.several}


def read_count(prompt: str | None, source_name: str | None = None) -> CountReading:
    """The number of copies and the arrangement a prompt names; the first number said of the source counts (one of
    the three words after it is a word of the source's name: "two swords" does not count men holding them), any
    number where the source has no name ("source")."""
    text = prompt or ""
    count, said = None, []
    words = {w for w in re.split(r"[^a-z]+", (source_name or "").lower()) if len(w) >= 3} - {"source"}
    found = next((m for m in _COUNT.finditer(text) if _names(text[m.end():], words) and not _one_pair(m, text)),
                 None)
    if found is not None:
        if found.group("phrase"):
            count = _PHRASES[found.group("phrase").lower()]
        else:
            word = found.group("number").lower()
            count = int(word) if word.isdigit() else NUMBER_WORDS[word]
        said.append(f"'{found.group(0)}' -> {count}")
    arrangement = None
    for name, cue in _CUES:
        hit = cue.search(text)
        if hit is not None:
            arrangement = name
            said.append(f"'{hit.group(0)}' -> {name}")
            break
    return CountReading(count, arrangement, "; ".join(said) or "no number or arrangement said",
                        _COLLECTIVE.search(text) is not None)


def _one_pair(found: re.Match, text: str) -> bool:
    """Whether ``found`` is "a pair of" before a thing that is one object called a pair (``ONE_PAIR``)."""
    after = re.findall(r"[a-z]+", text[found.end():].lower())[:1]
    return (found.group("phrase") or "").lower() == "a pair of" and bool(after) and after[0] in ONE_PAIR


def _names(after: str, words: set[str]) -> bool:
    """Whether one of the first three words of ``after`` is one of ``words`` (singular or plural); True for no
    words (a source without a name)."""
    return not words or any({w, w.removesuffix("s"), w.removesuffix("es")} & words
                            for w in re.findall(r"[a-z]+", after.lower())[:3])


def one_copy(prompt: str | None, arrangement: str) -> str | None:
    """The prompt one copy is read and guided by: the number and ``arrangement``'s words taken out; for
    ``around``, the copy stands beside the target and faces it (``beside+facing``)."""
    if prompt is None:
        return None
    text = _COUNT.sub("", prompt)
    if arrangement == "around":
        text = _AROUND.sub("beside", text) + ", facing it"
    elif arrangement == "row":
        text = _ROW.sub("", text)
    elif arrangement == "stack":
        text = _STACK.sub("", text)
    return re.sub(r"\s+", " ", text).strip(" ,")


def check_count(count: int) -> int:
    """``count`` if it is 1 to ``MAX_COPIES``; ``ConfigError`` ``count_out_of_range`` otherwise."""
    if isinstance(count, bool) or not isinstance(count, int) or not 1 <= count <= MAX_COPIES:
        raise ConfigError(f"count must be 1 to {MAX_COPIES} copies, got {count!r}", code="count_out_of_range",
                          field="count")
    return count


def choose(prompt: str | None, count: int | None = None, arrangement: str = "auto", source_name: str | None = None
           ) -> tuple[int, str, CountReading]:
    """(count, arrangement, the prompt's reading, ``counts.read_count``): the options win over the prompt; ``auto``
    is the prompt's cue or ``scatter``; a collective noun without a number ("a stack of") is ``SEVERAL`` copies."""
    if arrangement not in CHOICES:
        raise ConfigError(f"arrangement is one of {', '.join(CHOICES)}, not {arrangement!r}",
                          code="invalid_arrangement", field="arrangement")
    reading = read_count(prompt, source_name)
    if count is None:
        count = reading.count or (SEVERAL if reading.several else 1)
    kind = arrangement if arrangement != "auto" else reading.arrangement or "scatter"
    return check_count(count), kind, reading
