"""A scene as people describe it, read by its sentence structure: who is placed where, relative to what.

"Put the teapot on the tea tray in the middle of the kitchen table, and the wine crate under the table", "a park
bench with a litter bin to its right and a pizza box on its seat", "two traffic cones stand next to the crowd
barrier with the wet floor sign between them". ``read_scene(text, keys)`` reads a description over the objects it
may name (``keys``: each upload's name as words) into ``Said`` records, one per relation said of an object:

- **Phrases.** The words are tokens; an object's phrase is an upload's name (plurals too, a head word only one
  upload has, a one-word name's last part after a determiner: "the bench" of a workbench), a reference back ("it",
  "them", "each", "both"), a part of an object named by a possessive ("its seat", "on its top", "the bench's seat",
  "the top shelf of the bookcase": the ground is the possessor, the part its place), a place of the room ("the
  wall", "the corner", "the floor": no object), or a phrase after a determiner that names no upload (an error for
  the plan: never a guess). A count before a name makes copies ("two boxes", "a pair of shoes"; "a pair of
  glasses" is one, ``counts``); "and one on ..." is noted, not guessed. The relation cues are the pair reader's
  (``cues.CUES``), every one found in the sentence, the most specific first where they overlap; a one-word verb
  opening a clause before its object ("hang the mirror above the sink") is the order, not the relation.
- **Clauses.** A sentence splits at ";", "." and "then"; within it, a clause is its figures (one phrase, or several
  joined by "and": "a trophy and a wooden bird stand on the chest", "a laptop, a mug and a lamp on the desk") and
  the relations said of them, each a cue and its grounds ("between the teapot and the paper bag": two). A cue with
  no figure of its own modifies the clause before ("..., facing the monitor"); a bare phrase with "too" or "as
  well" repeats the clause before for it ("the mug too"); a phrase with no cue is only named ("a workbench, ...");
  "with" attaches the clauses after it to the clause's subject ("a bench with a bin to its right"). A relation
  fronted before its figures ("next to the bed, a lamp"; "on the desk are a laptop and a lamp") is theirs all the
  same. A cue's ground follows it (never across a comma or "and").
- **A clause with two relations.** The first is the figure's. A second relation of support after a first ("the
  teapot on the tray in the middle of the table") says where the first ground is: a step of its own (the tray on
  the table, in its middle); after "between" or a group ("between the teapot and the bag on the table") it is where
  the grounds stand (each on the table); where the lexicon's sizes allow it (no sofa on an armchair). Any other
  second relation is said of the figure too ("the lamp on the desk to its right": on the desk, and right of the
  monitor): kept as ``also``.
- **References.** "it"/"its" is the subject of the clause it is said in (the object "with" attaches to), else the
  scene's topic (a first phrase named with no relation: "a workbench, a toolbox on it"), else the object named last
  that the clause does not already relate ("the lamp on the desk to its right": not the desk; "the cups next to it
  on the tray": not the tray; a way to face may be of the place's ground: "in front of the desk, facing it");
  never the figure itself, never a group of copies nor one of the figures joined by "and" in the clause before;
  "in it" prefers a container; beside (left of, near ...) it, found by recency, prefers a thing of the figure's
  size among the last three ("the laptop on the desk and the phone beside it": the laptop). "them" and "both" are
  the group named last (the copies of a count, figures or grounds joined by "and"), else the clause's subject and
  its ground, else the last clause's figure and its ground ("put the teapot next to the bag and the bowl in front
  of them": not the table a fronted "on the table" named), else the last two objects named; "each" one ground copy
  per figure copy. A cue with its ground left out ("a stool in front", "a metronome on top") is of the topic, else
  of the object most often a ground so far.

Why no parser library: spaCy 3.8 is on the registry, but without a trained pipeline it has no parser, and its
English pipelines are published outside the registry (GitHub releases) under their own licence terms; a service
that reads a sentence before queueing would depend on a model file it cannot fetch or pin from the registry. The
sentences are short, their vocabulary (object names, relation cues, references) is closed and known to the reader,
so the structure above is read from tokens here. Torch-free.
"""

from __future__ import annotations

import re
import unicodedata
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

from ctp_core.reading import counts, cues, lexicon, records
from ctp_core.reading.places import PART_WORDS, PLACE_WORDS, read_place
from ctp_core.reading.records import Kind, RelationName

__all__ = ["DETERMINERS", "FLOOR", "MAX_GROUNDS", "ROOM", "Said", "SceneReading", "SceneReadingError", "clean",
           "is_support", "read_scene"]

MAX_GROUNDS = 2  # objects one relation relates a figure to: one, or two ("between")
DETERMINERS = frozenset({"a", "an", "the", "another", "some", "both", "every", "his", "her", "its", "their", "my",
                         "your", "our", "this", "that", "these", "those", "each", *counts.NUMBER_WORDS})
# A count said as a noun before "of" ("a pair of shoes", "a couple of chairs"): part of the determiner
_QUANTITY = frozenset({"pair", "couple", "trio", "dozen", "set", "stack", "pile", "row", "line", "few", "number"})
# Words that end an object's phrase: prepositions, conjunctions, verbs of placing.
_PHRASE_ENDS = frozenset({
    "and", "with", "of", "to", "on", "in", "at", "by", "under", "beside", "behind", "near", "next", "between",
    "above", "below", "over", "inside", "atop", "facing", "against", "into", "onto", "from", "around", "for", "while",
    "that", "which", "is", "are", "stands", "stand", "sits", "sit", "rests", "rest", "lies", "lie", "hangs", "leans",
    "go", "goes", "it", "them", "each", "beneath", "underneath", "opposite", "across", "too", "then", "up", "down",
    "faces", "face", "standing", "sitting", "lying", "resting", "along", "beyond", "past", "toward", "towards"})
FLOOR = frozenset({"floor", "ground", "room", "carpet"})  # "a rug on the floor": stands on the floor
ROOM = frozenset({"wall", "walls", "ceiling", "window", "door", "doorway", "entrance", "corner", "camera", "viewer"})
_ALSO = frozenset({"too", "also"})
# places of a ground a possessive names as a part ("on its top", "at its edge"; its sides are the cues' words)
_PLACES_OF = frozenset({"top", "edge", "corner", "end", "middle", "centre", "center", "rim", "bottom", "head", "foot"})
_BREAK_WORDS = frozenset({"then", "afterwards", "finally", "next"})
_POSSESSIVE = frozenset({"its", "their", "his", "her"})
# what "them", "both" and "each" said alone are
_GROUP_WORDS = frozenset({"them", "both", "each"})


class SceneReadingError(ValueError):
    """A description the reader cannot read (a relation of an object to itself, a reference with nothing to refer
    to): ``code`` as the plan's errors write it."""

    def __init__(self, message: str, code: str = "unclear_clause") -> None:
        super().__init__(message)
        self.message, self.code = message, code


@dataclass(frozen=True)
class Said:
    """One relation said of an object: its ``figure`` (an upload's key), the relation's cue as said (``cue``; its
    relation ``relation``), its ``grounds`` (keys; ``group``: one object made of them all, "next to them"; ``each``:
    one ground copy per figure copy), the words of the ground's part or place ("top shelf", "seat"; ``part``),
    whether it stands on the floor (``floor``), whether it is the figure's own relation (``primary``; else said of
    it as well: ``also``) and the clause it comes from."""

    figure: str
    relation: RelationName
    cue: str
    grounds: tuple[str, ...]
    clause: str
    part: str = ""
    group: bool = False
    each: bool = False
    floor: bool = False
    primary: bool = True
    room: str = ""  # a ground that is part of the room, no object ("the wall")
    derived: bool = False  # said of a ground by a relation after the figure's ("the tray ... in the middle of the
    # table"): yields to a relation said of it directly
    det: str = "the"  # how the figure was said: "the", or "a" for one of several or one said with "a"

    @property
    def supports(self) -> bool:
        """Whether the ground holds the figure up (on, in, ...)."""
        return is_support(self.relation)


def is_support(relation: RelationName) -> bool:
    """A relation whose ground holds its figure up: it rests on it, is in it, hangs from it, is fixed to it."""
    return records.RELATIONS[relation].supports or relation == RelationName.IN


@dataclass
class SceneReading:
    """What a description says: every relation (``said``, in the order said), the copies of each object said with
    a count (``counts``), the objects in the order named (``named``), the phrases naming no upload (``unknown``:
    (phrase, clause)), and what the reader assumed (``notes``)."""

    said: list[Said] = field(default_factory=list)
    counts: dict[str, int] = field(default_factory=dict)
    named: list[str] = field(default_factory=list)
    unknown: list[tuple[str, str]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def clean(text: str) -> str:
    """Lower case, accents dropped ("café" -> "cafe"), spaces single."""
    text = unicodedata.normalize("NFKD", text).encode("ascii", "ignore").decode()
    return " ".join(text.lower().split())


# -- tokens and phrases -------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class _Tok:
    start: int
    end: int
    word: str


@dataclass(frozen=True)
class _Phrase:
    """An object phrase: ``key`` an upload's key, a reference ("it", "them", "each", "both"), or a phrase naming no
    upload (``known`` False). ``part``: the part or place of it named ("seat"); ``each``: "each chair"; ``det``:
    the determiner said; ``count``: the number said before it (0: none)."""

    start: int
    end: int
    key: str
    known: bool = True
    part: str = ""
    each: bool = False
    det: str = ""
    count: int = 0
    room: bool = False

    @property
    def back(self) -> bool:
        return self.key in ("it", "them", "each", "both", "one")


@dataclass(frozen=True)
class _Cue:
    start: int
    end: int
    match: cues.CueMatch

    @property
    def relation(self) -> RelationName:
        return self.match.cue.relation

    @property
    def implied(self) -> bool:
        """A cue that names its ground by a possessive before a side ("to its right", "on their left"): the ground
        is a reference back."""
        words = self.match.text.split()
        return (len(words) >= 2 and any(w in _POSSESSIVE for w in words[:-1]) and words[-1] in PLACE_WORDS | {"side",
                "end"} and self.relation != RelationName.FACING_AWAY)

    @property
    def open_side(self) -> bool:
        """A side said without "of" ("in front", "on top"): its ground may be left out."""
        return self.match.text.split()[-1] in PLACE_WORDS


@dataclass
class _Element:
    kind: str  # "np", "cue", "and", "comma", "with", "too", "break", "word", "floor"
    start: int
    end: int
    phrase: _Phrase | None = None
    cue: _Cue | None = None


def _tokens(text: str) -> list[_Tok]:
    return [_Tok(m.start(), m.end(), m.group()) for m in re.finditer(r"[a-z]+|\d+|[,;.:!?]", text)]


class _Names:
    """Finds the uploads' names in tokens."""

    def __init__(self, keys: Sequence[str]) -> None:
        self.keys = [k for k in keys if k]
        self.longest_first = sorted(self.keys, key=lambda k: -len(k.split()))

    def at(self, toks: list[_Tok], i: int) -> tuple[int, str] | None:
        """(tokens, key) of an upload's name starting at token ``i``: the whole name (or its words as one: "tool
        box" said "toolbox"), else its last word where no other upload's name ends with it."""
        for key in self.longest_first:
            words = key.split()
            said = [t.word for t in toks[i:i + len(words)]]
            if len(said) == len(words) and said[:-1] == words[:-1] and words[-1] in lexicon.singulars(said[-1]):
                return len(words), key
            if len(words) > 1 and "".join(words) in lexicon.singulars(toks[i].word):
                return 1, key
        heads = [k for k in self.keys if k.split()[-1] in lexicon.singulars(toks[i].word)]
        return (1, heads[0]) if len(heads) == 1 else None

    def tail(self, toks: list[_Tok], i: int) -> str | None:
        """The one upload whose one-word name ends with the word at ``i`` ("bench" of "workbench"), where no name is
        said there."""
        if i >= len(toks) or self.at(toks, i) is not None or len(toks[i].word) < 4:
            return None
        if i + 1 < len(toks) and self.at(toks, i + 1) is not None:
            return None
        ends = [k for k in self.keys if " " not in k and any(
            k.endswith(form) and k != form for form in lexicon.singulars(toks[i].word))]
        return ends[0] if len(ends) == 1 else None


def _phrases(text: str, toks: list[_Tok], names: _Names) -> list[_Phrase]:
    """The object phrases of a sentence, in order (see the module's docstring)."""
    found: list[_Phrase] = []
    i = 0
    det, det_at = "", -1
    each_of = False  # "each of the ...": the next name is each of its copies
    while i < len(toks):
        word = toks[i].word
        hit = names.at(toks, i)
        if hit is not None:
            phrase, i = _named(text, toks, i, hit, det, det_at)
            found.append(replace(phrase, each=phrase.each or each_of))
            det, det_at, each_of = "", -1, False
            continue
        if word in ("one", "another") and (i + 1 == len(toks) or toks[i + 1].word in _PHRASE_ENDS) and (
                i > 0 and toks[i - 1].word in ("and", ",")):
            found.append(_Phrase(toks[i].start, toks[i].end, "one"))  # "two cushions on the sofa and one on ..."
        elif word in ("it", "them") or word == "both" and (i + 1 == len(toks) or toks[i + 1].word in _PHRASE_ENDS
                                                          or not toks[i + 1].word.isalpha()):
            found.append(_Phrase(toks[i].start, toks[i].end, word))
        elif (word == "each" and i + 2 < len(toks) and toks[i + 1].word == "of"
              and (names.at(toks, i + 2) is not None or toks[i + 2].word in DETERMINERS)):
            i += 2  # "each of the nightstands": the nightstands, one copy on each
            each_of = True
            continue
        elif word == "each" and (i + 1 == len(toks) or toks[i + 1].word in _PHRASE_ENDS | {"one"}
                                 or not toks[i + 1].word.isalpha()):
            found.append(_Phrase(toks[i].start, toks[i].end, "each"))
        elif word in _POSSESSIVE and (at_part := _part_at(toks, i + 1, names, possessive=True)) is not None:
            n, part = at_part  # "its seat", "its top shelf": a part of what "its" refers to
            found.append(_Phrase(toks[i].start, toks[i + n].end, "them" if word == "their" else "it", part=part))
            i += n + 1
            continue
        elif word == "the" and (at_part := _part_at(toks, i + 1, names)) is not None:
            n, part = at_part  # "the seat of the bench": the bench, its seat
            j = i + 1 + n
            if j + 1 < len(toks) and toks[j].word == "of":
                k = j + 1 + (toks[j + 1].word in DETERMINERS)
                owner = names.at(toks, k) if k < len(toks) else None
                if owner is not None:
                    m, key = owner
                    found.append(_Phrase(toks[i].start, toks[k + m - 1].end, key, part=part, det="the"))
                    i = k + m
                    continue
        elif word in DETERMINERS and word != "each":
            if i + 2 < len(toks) and toks[i + 1].word in _QUANTITY and toks[i + 2].word == "of":
                det, det_at = word, i  # "a pair of shoes": the count is read with the name
                i += 3
                continue
            tail = names.tail(toks, i + 1)
            if tail is not None:  # "the bench" of a workbench
                found.append(_Phrase(toks[i + 1].start, toks[i + 1].end, tail, det=word))
                i += 2
                continue
            words = _phrase_words(toks, i + 1, names)
            if words:
                end = toks[i + len(words)].end
                room = words[-1] in FLOOR | ROOM
                found.append(_Phrase(toks[i + 1].start, end, " ".join(words), known=False, room=room))
                i += len(words) + 1
                continue
            det, det_at = word, i
        i += 1
    return found


def _named(text: str, toks: list[_Tok], i: int, hit: tuple[int, str], det: str, det_at: int) -> tuple[_Phrase, int]:
    """The phrase of an upload's name at token ``i`` (``hit``: its tokens and key), with the count said before it
    and a part said after it ("the bench's seat"), and the token after it."""
    n, key = hit
    start = toks[det_at].start if det_at >= 0 and det_at >= i - 4 else toks[i].start
    said = counts.read_count(text[start:toks[i + n - 1].end], key).count or 0
    each = i > 0 and toks[i - 1].word == "each"
    end = i + n
    part = ""
    if end + 1 < len(toks) and text[toks[end - 1].end:toks[end].start] == "  " and toks[end].word in PART_WORDS:
        part, end = toks[end].word, end + 1
    return _Phrase(toks[i].start, toks[end - 1].end, key, det=det, count=said, each=each, part=part), end


def _part_at(toks: list[_Tok], i: int, names: _Names, possessive: bool = False) -> tuple[int, str] | None:
    """(tokens, words) of a part's or place's name starting at token ``i`` ("seat", "top shelf"), None where an
    upload's name starts there."""
    if i >= len(toks) or names.at(toks, i) is not None:
        return None
    if (i + 1 < len(toks) and toks[i + 1].word in PART_WORDS and names.at(toks, i + 1) is None
            and toks[i].word in PLACE_WORDS | {"lower", "upper", "bottom", "second", "lowest", "highest", "uppermost"}):
        return 2, f"{toks[i].word} {toks[i + 1].word}"  # "top shelf"
    if toks[i].word in PART_WORDS or possessive and toks[i].word in _PLACES_OF:
        return 1, toks[i].word
    return None


def _phrase_words(toks: list[_Tok], i: int, names: _Names) -> list[str]:
    """The words of a phrase naming no upload from token ``i`` (up to three, to a word that ends a phrase); [] for a
    part or place of a ground ("the top", "its left") or where an upload's name starts."""
    words: list[str] = []
    while (i < len(toks) and len(words) < 3 and toks[i].word.isalpha()
           and toks[i].word not in _PHRASE_ENDS | DETERMINERS):
        if names.at(toks, i) is not None:
            return []
        words.append(toks[i].word)
        i += 1
    if words and words[-1] in ROOM and (i >= len(toks) or toks[i].word != "of"):
        return words  # "in the corner": of the room
    if not words or words[-1] in PLACE_WORDS | PART_WORDS or words[0] in _QUANTITY:
        return []
    return words


def _cues(text: str, phrases: list[_Phrase]) -> list[_Cue]:
    """Every relation cue of a sentence, the most specific first where two overlap; none inside an object's
    phrase, nor a participle that describes a noun ("a hanging lamp")."""
    taken: list[_Cue] = []
    spans = [(p.start, p.end) for p in phrases]
    for cue in cues.CUES:
        for m in cues._compiled(cue).finditer(cues.clean(text)):
            found = cues.CueMatch(cue, m.start(), m.end(), m.group(0))
            if any(c.start < found.end and found.start < c.end for c in taken):
                continue
            if any(s < found.end and found.start < e for s, e in spans):
                continue
            if cues._adjective(text, found):
                continue
            if _imperative(text, found):
                continue
            top = _ON_TOP.match(text, found.end)
            if top is not None and found.text.split()[-1] in ("on", "upon", "at", "in"):  # "sits on top of",
                # "sits at the edge of": the place of the ground said with the cue
                found = cues.CueMatch(cue, found.start, top.end(), text[found.start:top.end()])
            taken.append(_Cue(found.start, found.end, found))
    return sorted(taken, key=lambda c: c.start)


_ON_TOP = re.compile(r" (?:top(?: of)?|the (?:very )?(?:top|edge|rim|brink|lip|corner|far end|end|middle|centre|center)"
                     r" of)(?![a-z])")
_PREPOSITIONS = frozenset({"on", "in", "at", "by", "under", "behind", "beside", "above", "below", "near", "inside",
                           "atop", "onto", "upon", "over", "along", "among", "within", "against", "around", "through",
                           "between", "beneath", "underneath", "opposite", "outside", "into", "alongside", "amongst"})
_CLAUSE_START = re.compile(r"(?:^|[,;:.]|\b(?:and|then|please|now|also))\s*$")
_DETERMINER_NEXT = re.compile(r"\s+(?:" + "|".join(sorted(DETERMINERS)) + r")\b")


def _imperative(text: str, cue: cues.CueMatch) -> bool:
    """A one-word cue that opens a clause before its object ("hang the mirror above the sink"): the verb of an
    order, not the relation."""
    return (" " not in cue.text and not cue.text.endswith(("ing", "s", "ed"))  # "facing the monitor" is a relation
            and cue.text not in _PREPOSITIONS  # "on the desk are ...": a relation said first
            and _CLAUSE_START.search(text[:cue.start]) is not None
            and _DETERMINER_NEXT.match(text, cue.end) is not None)


def _elements(text: str, toks: list[_Tok], phrases: list[_Phrase], found: list[_Cue]) -> list[_Element]:
    """The sentence as a sequence of phrases, cues and the words that join them."""
    out: list[_Element] = []
    at = {p.start: p for p in phrases}
    cue_at = {c.start: c for c in found}
    covered = 0
    for t in toks:
        if t.start < covered:
            continue
        if t.start in at:
            p = at[t.start]
            out.append(_Element("np", p.start, p.end, phrase=p))
            covered = p.end
        elif t.start in cue_at:
            c = cue_at[t.start]
            out.append(_Element("cue", c.start, c.end, cue=c))
            covered = c.end
        elif t.word == "and":
            out.append(_Element("and", t.start, t.end))
        elif t.word in (",", ":"):
            out.append(_Element("comma", t.start, t.end))
        elif t.word == "with":
            out.append(_Element("with", t.start, t.end))
        elif t.word in _ALSO or t.word == "well" and out and out[-1].kind == "word" and text[out[-1].start:
                                                                                             out[-1].end] == "as":
            out.append(_Element("too", t.start, t.end))
        elif t.word in FLOOR:
            out.append(_Element("floor", t.start, t.end))
        else:
            out.append(_Element("word", t.start, t.end))
    return out


# -- clauses ------------------------------------------------------------------------------------------------------

@dataclass
class _Relation:
    cue: _Cue
    grounds: list[_Phrase] = field(default_factory=list)
    floor: bool = False
    room: str = ""

    @property
    def wants(self) -> int:
        return records.RELATIONS[self.cue.relation].grounds

    @property
    def filled(self) -> int:
        """Grounds said so far ("them" and "both": two)."""
        return sum(2 if g.key in ("them", "both") else 1 for g in self.grounds)


@dataclass
class _Clause:
    figures: list[_Phrase]
    relations: list[_Relation] = field(default_factory=list)
    host: str | None = None  # what "it" is in a clause attached by "with"
    start: int = 0
    end: int = 0
    too: bool = False  # "the mug too": the clause before, said of its figures
    inverted: bool = False  # its relation said before its figures ("on the desk are a laptop and a lamp")


def _sentences(text: str) -> list[tuple[int, int]]:
    """(start, end) of each part of the description between ";", ".", "!", "?" and "then"."""
    out, start = [], 0
    for m in re.finditer(r"[;.!?\n]|,?\s*(?:and\s+)?\b(?:then|afterwards|finally)\b", text):
        if m.start() > start:
            out.append((start, m.start()))
        start = m.end()
    if start < len(text):
        out.append((start, len(text)))
    return [(s, e) for s, e in out if text[s:e].strip(" ,")]


def _clauses(text: str, elements: list[_Element]) -> tuple[list[_Clause], list[_Phrase]]:
    """The clauses of one sentence (see the module's docstring), and the phrases named with no relation."""
    parser = _Parser(text, elements)
    for k, el in enumerate(elements):
        getattr(parser, f"on_{el.kind}")(k, el)
        if el.kind in ("np", "cue", "floor") and parser.current is not None:
            parser.current.end = max(parser.current.end, el.end)
        if el.kind != "word" or parser.previous not in ("and", "comma") or text[el.start:el.end] in ("is", "are"):
            parser.previous = el.kind
    return parser.done()


class _Parser:
    """One sentence's elements read left to right into clauses."""

    def __init__(self, text: str, elements: list[_Element]) -> None:
        self.text, self.elements = text, elements
        self.clauses: list[_Clause] = []
        self.figures: list[_Phrase] = []  # named, waiting for their cue
        self.loose: list[_Phrase] = []  # named with no relation of their own
        self.listed: list[_Phrase] = []  # named before a comma, figures if the list goes on to "and"
        self.current: _Clause | None = None
        self.fronted: _Clause | None = None  # a relation said before its figure ("next to the bed, a lamp")
        self.host: str | None = None  # what "with" attaches to
        self.subject: str | None = None
        self.previous = ""

    def close(self) -> None:
        if self.current is not None:
            self.clauses.append(self.current)
        self.current = None

    def done(self) -> tuple[list[_Clause], list[_Phrase]]:
        self.close()
        self.loose.extend([*self.listed, *self.figures])
        if self.fronted is not None and self.fronted.figures:
            self.clauses.append(self.fronted)
        return self.clauses, self.loose

    def on_np(self, k: int, el: _Element) -> None:
        p = el.phrase
        assert p is not None
        current, fronted, joined = self.current, self.fronted, self.previous == "and"
        rel = current.relations[-1] if current is not None and current.relations else None
        if fronted is not None and (fronted.relations[-1].grounds or fronted.relations[-1].floor) and not (
                joined and fronted.relations[-1].filled < fronted.relations[-1].wants):
            fronted.figures = [p]  # "next to the bed, a lamp": the lamp is the figure
            fronted.inverted = True
            self.current, self.fronted = fronted, None
        elif (current is not None and current.inverted and joined and current.figures[-1].end >= current.end
              and not _ahead(self.elements, k)):
            current.figures.append(p)  # "on the desk are a laptop and a lamp"
        elif rel is not None and (not rel.grounds and not rel.floor and not rel.cue.implied
                                  and self.previous not in ("comma", "and", "with")
                                  or joined and 0 < rel.filled < rel.wants):
            rel.grounds.append(p)
        elif fronted is not None:
            fronted.relations[-1].grounds.append(p)
        elif (rel is not None and joined and self.host is None and not _ahead(self.elements, k)
              and rel.cue.relation != RelationName.BETWEEN and not any(g.back for g in rel.grounds)):
            rel.grounds.append(p)  # "next to the sofa and the armchair": one ground made of both
        elif joined and self.figures and current is None:
            self.figures.append(p)  # "a trophy and a bird stand on the chest"
        else:
            self.close()
            if self.previous == "comma" and self.figures and current is None:
                self.listed.extend(self.figures)  # "a laptop, a mug and a lamp on the desk", if "and" ends the list
            else:
                self.loose.extend([*self.listed, *self.figures])
                self.listed = []
            self.figures = [p]
            if self.subject is None and not p.back:
                self.subject = p.key

    def on_cue(self, k: int, el: _Element) -> None:
        cue = el.cue
        assert cue is not None
        if cue.match.cue.figure_after and self.figures:  # "a basket filled with apples": the apples in the basket
            self.close()
            self.fronted = _Clause([], [_Relation(cue, list(self.figures))], host=self.host,
                                   start=self.figures[0].start, end=el.end)
            self.figures = []
        elif self.figures:
            self.close()
            if len(self.figures) > 1:  # "a laptop, a mug and a lamp on the desk": the whole list
                self.figures = [*self.listed, *self.figures]
            else:  # "a workbench, a toolbox on it": the workbench only named
                self.loose.extend(self.listed)
            self.listed = []
            self.current = _Clause(self.figures, [_Relation(cue)], host=self.host, start=self.figures[0].start,
                                   end=el.end)
            self.figures = []
        elif self.current is not None:
            self.current.relations.append(_Relation(cue))  # "..., facing the monitor": of the clause's figure
        elif self.clauses and self.previous in ("comma", "word"):
            self.current = self.clauses.pop()
            self.current.relations.append(_Relation(cue))
        else:
            self.fronted = _Clause([], [_Relation(cue)], host=self.host, start=el.start, end=el.end)
        if self.current is not None and cue.implied:
            self.current.relations[-1].grounds.append(_Phrase(cue.start, cue.end, "it"))

    def on_floor(self, k: int, el: _Element) -> None:
        target = self.current if self.current is not None else self.fronted
        if target is not None and target.relations and not target.relations[-1].grounds:
            target.relations[-1].floor = True

    def on_with(self, k: int, el: _Element) -> None:
        current, figures = self.current, self.figures
        self.host = (current.figures[0].key if current is not None and current.figures and not current.figures[0].back
                     else figures[0].key if figures and not figures[0].back else self.subject or self.host)
        if current is None and figures:
            self.loose.extend([*self.listed, *figures])  # "a park bench with ...": named, placed by no relation
            self.figures, self.listed = [], []
        self.close()

    def on_too(self, k: int, el: _Element) -> None:
        if self.figures and (self.clauses or self.current is not None):
            self.close()
            before = self.clauses[-1]
            self.clauses.append(_Clause(self.figures, [_Relation(r.cue, list(r.grounds), r.floor)
                                                       for r in before.relations],
                                        host=before.host, start=self.figures[0].start, end=el.end, too=True))
            self.figures = []

    def on_and(self, k: int, el: _Element) -> None:
        pass

    on_comma = on_word = on_and


def _ahead(elements: list[_Element], k: int) -> bool:
    """Whether the phrase at ``k`` has a cue of its own before the next phrase or joint ("and the lamp on ...")."""
    for el in elements[k + 1:]:
        if el.kind == "cue":
            return True
        if el.kind in ("np", "and", "comma", "with"):
            return False
        if el.kind == "too":
            return True
    return False


# -- references ---------------------------------------------------------------------------------------------------

class _Reader:
    """The clauses read one after another, references resolved against what was named before."""

    def __init__(self, keys: Sequence[str]) -> None:
        self.names = _Names(keys)
        self.out = SceneReading()
        self.recent: list[str] = []  # objects in the order named, references resolved
        self.groups: list[tuple[str, ...]] = []  # groups named ("two boxes": one key; "a trophy and a bird": two)
        self.topic: str | None = None
        self.joined: set[str] = set()  # the figures joined by "and" in the clause before: no "it"
        self.joined_next: set[str] = set()

    def read(self, text: str) -> SceneReading:
        for start, end in _sentences(text):
            self.sentence(text, start, end)
        return self.out

    def sentence(self, full: str, start: int, end: int) -> None:
        text = full[:end]
        toks = [t for t in _tokens(text) if t.start >= start]
        phrases = _phrases(text, toks, self.names)
        for p in phrases:
            if not p.known and not p.room:
                self.out.unknown.append((text[p.start:p.end], full[start:end].strip(" ,")))
            if p.known and not p.back:
                if p.count:
                    self.out.counts[p.key] = max(p.count, self.out.counts.get(p.key, 1))
                self.out.named.append(p.key)
        elements = _elements(text, toks, phrases, _cues(text, phrases))
        clauses, loose = _clauses(text, elements)
        first = next((p for p in phrases if p.known and not p.back), None)
        if self.topic is None and not self.out.said and first is not None and any(p is first for p in loose):
            self.topic = first.key  # "a workbench, a toolbox on it": what the scene is about
        for p in loose:
            if p.known and not p.back:
                self.recent.append(p.key)
                if self.out.counts.get(p.key, 1) > 1:
                    self.groups.append((p.key,))
        for clause in clauses:
            try:
                self.clause(text, clause)
            except SceneReadingError:
                if not self.out.unknown:  # a phrase naming no upload is the error to report
                    raise

    def clause(self, text: str, clause: _Clause) -> None:
        before = _SAID_BEFORE.search(text[:clause.start])  # "the", "two", "a pair of" ... before the first figure
        said = text[before.start() if before else clause.start:clause.end].strip(" ,")
        if clause.figures and clause.figures[0].key == "one":
            if re.search(r"\b(?:each|either|both)\b", said):
                return  # "two plants flank the bench, one on each side": the clause before, distributed
            self.out.notes.append(f"'{said}': one more of a kind said this way is not read: say each place with "
                                  "its own count")
            return
        figures = [f for f in clause.figures if f.known and not f.back]
        if clause.figures and not figures:
            back = clause.figures[0]
            figures = [replace(back, key=k) for k in self._resolve(back, [], clause, said, None)]
        if not figures:
            raise SceneReadingError(f"'{said}' names no object to place")
        keys = [f.key for f in figures]
        if len(figures) > 1:
            self.groups.append(tuple(keys))
        # "the lamp and the trophy on the chest, and the stool left of it": "it" is not one of the two
        self.joined, self.joined_next = self.joined_next, set(keys) if len(figures) > 1 else set()
        for f in figures:
            if self.out.counts.get(f.key, 1) > 1:
                self.groups.append((f.key,))
        self.recent.extend(keys)
        if clause.relations and all(g.room for g in clause.relations[0].grounds) and clause.relations[0].grounds:
            # "with its back to the wall in front of the desk": the figure's place is the object's relation
            clause.relations = [*clause.relations[1:], clause.relations[0]]
        first_support: list[str] | None = None
        primary: _Ground | None = None
        # a reference is not to a ground the clause names ("the cups next to it on the tray": not the tray)
        named = [g.key for r in clause.relations for g in r.grounds if g.known and not g.back and not g.room]
        for rel in clause.relations:
            try:
                # a second place is not the first one's ground ("on the desk to its right": not the desk's right);
                # a way to face may be ("in front of the desk, facing it")
                turn = records.RELATIONS[rel.cue.relation].kind == Kind.ORIENTATION
                ground = self._grounds(rel, keys, clause, said, [] if turn else [
                    *named, *(primary.keys if primary is not None else [])])
            except SceneReadingError:
                if len(clause.relations) == 1:
                    raise
                continue  # a reference with nothing to refer to, beside a relation that places the figure
            if primary is None:
                primary = ground
                first_support = ground.keys if is_support(rel.cue.relation) else None
                self.out.said.extend(ground.said(rel, f.key, said, _det(f)) for f in figures)
            elif (is_support(rel.cue.relation) and (first_support or primary.group) and ground.keys
                  and all(_fits(g, ground.keys[0]) for g in first_support or primary.keys)):
                # "the teapot on the tray in the middle of the table": the tray on the table; "between the teapot
                # and the bag on the table": each on the table
                below = first_support or primary.keys
                self.out.said.extend(replace(ground.said(rel, g, said, "the"), derived=True) for g in below
                                     if g not in ground.keys)
                first_support = ground.keys
            else:
                self.out.said.extend(replace(ground.said(rel, f.key, said, _det(f)), primary=False) for f in figures)

    def _grounds(self, rel: _Relation, keys: list[str], clause: _Clause, said: str, used: list[str]) -> _Ground:
        """A relation's grounds, references resolved: "them" a group, "each" its copies, a part its possessor."""
        out = _Ground()
        for g in rel.grounds:
            if g.room:
                out.room = g.key
            elif g.known and g.back:
                out.keys.extend(self._resolve(g, keys, clause, said, rel, used=[*used, *out.keys]))
                out.each = out.each or g.key == "each"
                out.group = out.group or g.key in ("them", "both") and rel.wants == 1
            elif g.known:
                out.keys.append(g.key)
                out.each = out.each or g.each
            out.part = out.part or g.part
        if not out.keys and not rel.floor and not out.room and not rel.grounds:
            out.keys = self._left_out(keys, used) or self._resolve(
                _Phrase(rel.cue.start, rel.cue.end, "it"), keys, clause, said, rel, used=used)
        if len(out.keys) > 1 and rel.wants == 1:
            out.group = True  # "next to the sofa and the armchair"
            self.groups.append(tuple(out.keys))
        if set(out.keys) & set(keys):
            raise SceneReadingError(f"'{said}' places the {keys[0]} relative to itself")
        self.recent.extend(g for g in out.keys if g not in self.recent[-1:])
        out.floor = rel.floor and not out.keys
        out.group = out.group or rel.cue.relation == RelationName.BETWEEN and len(out.keys) > 1
        return out

    def _left_out(self, figures: list[str], used: Sequence[str]) -> list[str]:
        """The ground of a cue said without one ("a stool in front", "a metronome on top"): the scene's topic, else
        the object most often a ground so far (the one the others are arranged around)."""
        if self.topic is not None and self.topic not in figures:
            return [self.topic]
        tally: dict[str, int] = {}
        for said in self.out.said:
            for g in said.grounds:
                if g not in figures and g not in used and self.out.counts.get(g, 1) == 1:
                    tally[g] = tally.get(g, 0) + 1
        recency = {k: i for i, k in enumerate(self.recent)}
        return [max(tally, key=lambda g: (tally[g], recency.get(g, -1)))] if tally else []

    def _resolve(self, ref: _Phrase, figures: list[str], clause: _Clause, said: str, rel: _Relation | None,
                 used: Sequence[str] = ()) -> list[str]:
        """The objects a reference stands for (see the module's docstring)."""
        if ref.key in ("them", "both", "each"):
            return self._group(figures, clause, said, ref.key, rel)
        relation = rel.cue.relation if rel is not None else None
        candidates = [clause.host, self.topic, *reversed(self.recent)]
        fitting = [k for k in dict.fromkeys(c for c in candidates if c) if k not in figures and k not in used
                   and self.out.counts.get(k, 1) == 1 and k not in self.joined]
        if not fitting:
            fitting = [k for k in dict.fromkeys(c for c in candidates if c) if k not in figures]
        if not fitting:
            raise SceneReadingError(f"'{said}': nothing named before it to place the {figures[0] if figures else 'it'}"
                                    " against")
        if relation == RelationName.IN:  # "in it": a container, where one is in reach
            holder = next((k for k in fitting[:3] if (m := lexicon.lookup(k)) is not None and m.has("container")),
                          None)
            if holder is not None:
                return [holder]
        chosen = fitting[0]
        if (relation is not None and records.RELATIONS[relation].kind in (Kind.SIDE, Kind.DISTANCE) and figures
                and chosen not in (clause.host, self.topic) and not _alike(figures[0], chosen)):
            # "the laptop on the desk and the phone beside it": beside the laptop, a thing of its size
            chosen = next((k for k in fitting[:3] if _alike(figures[0], k)), chosen)
        return [chosen]

    def _group(self, figures: list[str], clause: _Clause, said: str, word: str, rel: _Relation | None
               ) -> list[str]:
        """What "them", "both" or "each" stands for: the group named last that is not the figure's, else the clause's
        subject and its ground, else the last clause's figure and its ground, else the last two objects named."""
        for group in reversed(self.groups):
            if not set(group) & set(figures):
                return list(group)
        if clause.host is not None and clause.host not in figures:
            host_ground = next((s.grounds for s in reversed(self.out.said) if s.figure == clause.host and s.grounds),
                               ())
            if host_ground:
                return [clause.host, *host_ground][:MAX_GROUNDS]
        previous = next((s for s in reversed(self.out.said) if s.figure not in figures and len(s.grounds) == 1
                         and s.grounds[0] not in figures and not s.derived), None)
        if previous is not None:  # "put the teapot next to the bag and the bowl in front of them"
            return [previous.figure, *previous.grounds]
        last = [k for k in dict.fromkeys(reversed(self.recent)) if k not in figures][:2]
        if len(last) < 2:
            raise SceneReadingError(f"'{said}': '{word}' needs two objects named before it")
        return last[::-1]  # in the order named


@dataclass
class _Ground:
    """A relation's grounds as read (keys) and what was said of them."""

    keys: list[str] = field(default_factory=list)
    part: str = ""
    group: bool = False
    each: bool = False
    floor: bool = False
    room: str = ""

    def said(self, rel: _Relation, figure: str, clause: str, det: str) -> Said:
        return Said(figure, rel.cue.relation, rel.cue.match.text, tuple(self.keys), clause, self.part,
                    self.group and rel.cue.relation != RelationName.BETWEEN, self.each, self.floor,
                    room=self.room, det=det)


_SAID_BEFORE = re.compile(r"(?:\b(?:" + "|".join(sorted(DETERMINERS | _QUANTITY | {"of"})) + r")\s+)+$")


ALIKE = 2.5  # sizes within this factor: things that stand side by side on the same surface


def _alike(a: str, b: str) -> bool:
    """Whether the lexicon knows both sizes and they are within ``ALIKE`` of each other."""
    x, y = lexicon.lookup(a), lexicon.lookup(b)
    return x is not None and y is not None and max(x.size_m, y.size_m) <= ALIKE * min(x.size_m, y.size_m)


def _fits(figure: str, ground: str) -> bool:
    """Whether ``figure`` can stand on ``ground`` as far as the lexicon's sizes say (no sofa on an armchair)."""
    a, b = lexicon.lookup(figure), lexicon.lookup(ground)
    return a is None or b is None or a.size_m <= b.size_m


def _det(p: _Phrase) -> str:
    return "a" if p.count > 1 or p.det in ("a", "an", "another", "some") or p.det in counts.NUMBER_WORDS else "the"


def read_scene(text: str, keys: Sequence[str]) -> SceneReading:
    """The relations a description says of the objects called ``keys`` (see the module's docstring). Raises
    ``SceneReadingError`` where a clause cannot be read."""
    return _Reader(keys).read(clean(text))


def is_place_said(part: str) -> bool:
    """Whether a part's words name a place the geometry reads ("top shelf", "edge")."""
    return bool(part) and read_place(f"on the {part} of it") is not None

