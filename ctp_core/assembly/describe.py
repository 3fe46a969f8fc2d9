"""A scene from one sentence: a description of several objects read into an assembly plan.

"a piano with its stool in front of it and a metronome on top", "put the stool in front of the piano; stand the
metronome on it", "stool, front of, piano; metronome, on, piano". ``read_description(description, names)`` splits the
description into clauses (commas, "and", ";", a constraint triple per sentence), finds in each the objects it
names (the uploads' ``names``, plurals too; "it", "its", "them", "each" and a clause without a ground refer back
to the object named last that is not the clause's figure), and reads each clause's relation and figure with the
pair reader (``passes.read_prompt``): one reader serves a pair and a plan, so a clause means here what the same words
mean to ``ctp align``. A count makes copies ("two paint tins": ``paint tin_1``, ``paint tin_2``; "a lamp on each"
one per copy of the ground). The plan places every ground before its figures, the first object named as a
ground (that no clause places) staying put; an object the description never places goes on the floor beside it,
and the plan says so. An object named that matches no upload is an error, never a guess. Torch-free: the API
reads a description before anything is queued.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field

from ctp_core.assembly.plan import MAX_GROUNDS
from ctp_core.errors import ConfigError
from ctp_core.reading import counts, cues, lexicon, passes, records
from ctp_core.reading.places import PLACE_WORDS

__all__ = ["DescriptionError", "Placement", "ScenePlan", "read_description"]

DESCRIPTION_MAX = 2000  # characters of a description
# A clause begins with an imperative or a filler that says nothing of the arrangement.
_LEAD = re.compile(r"^(?:(?:please|then|also|and|with|there (?:is|are))\s+)*(?:(?:put|place|set|stand|lay|hang|"
                   r"add|move|position|rest|sit|mount|centre|center)\s+)?")
_PIECES = re.compile(r"\s*,\s*|\s+(?:and|then)\s+")
_SENTENCES = re.compile(r"\s*(?:[;\n]|\.(?:\s|$))\s*")
# A constraint triple's relation as layout tools write it ("front of") -> the words the reader reads.
_TRIPLE_WORDS = {"front of": "in front of", "in front": "in front of", "front": "in front of",
                 "side of": "beside", "on top": "on top of", "top of": "on top of", "face": "facing",
                 "faces": "facing", "next": "next to", "back of": "behind"}
_DETERMINERS = frozenset({"a", "an", "the", "another", "some", "both", "every", "his", "her", "its", "their", "my",
                          "your", "our", "this", "that", "these", "those", *counts.NUMBER_WORDS})
# Words that end an object's phrase: prepositions, conjunctions, verbs of placing.
_PHRASE_ENDS = frozenset({
    "and", "with", "of", "to", "on", "in", "at", "by", "under", "beside", "behind", "near", "next", "between", "above",
    "below", "over", "inside", "atop", "facing", "against", "into", "onto", "from", "around", "for", "while", "that",
    "which", "is", "are", "stands", "sits", "rests", "lies", "hangs", "leans", "it", "them", "each", "beneath",
    "underneath", "opposite", "across"})
_FLOOR = frozenset({"floor", "ground", "room"})  # "a rug on the floor": on the floor beside the first object


class DescriptionError(ConfigError):
    """A description that cannot be read into a plan (an object matching no upload, a clause with no object to
    place, a cycle): the CLI prints it, the API answers 422 with its code."""

    code = "invalid_description"


@dataclass(frozen=True)
class Placement:
    """One step of the plan: the node it places (``name``; copies ``<name>_k``), its upload, the prompt its run is
    read and guided by, the nodes it relates to (``on``), the relation the reader reads and the clause it comes
    from (``said``; empty where the description never places the object: ``floor``)."""

    name: str
    upload: int
    prompt: str
    on: tuple[str, ...]
    relation: str
    said: str = ""
    floor: bool = False


@dataclass
class ScenePlan:
    """The plan a description reads into: the base (stays put), the steps in placing order, what was assumed."""

    description: str
    base: str
    base_upload: int
    steps: list[Placement]
    warnings: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"description": self.description, "base": self.base, "base_upload": self.base_upload,
                "steps": [{**asdict(s), "on": list(s.on)} for s in self.steps], "warnings": list(self.warnings)}

    def assembly_plan(self, files: Sequence[str]) -> dict:
        """The plan as ``ctp assemble --plan`` and ``POST /assemble`` take it (``files``: one per upload)."""
        return {"base": files[self.base_upload], "name": self.base,
                "steps": [{"file": files[s.upload], "name": s.name, "prompt": s.prompt,
                           "on": s.on[0] if len(s.on) == 1 else list(s.on)} for s in self.steps]}


@dataclass(frozen=True)
class _Mention:
    """An object phrase of a clause: an upload's name (``key``: the name), a phrase naming no upload (``key``: the
    phrase, ``known`` False) or a reference back (``key``: "it", "them", "each")."""

    start: int
    end: int
    key: str
    known: bool = True
    each: bool = False  # "each chair": every copy of it

    @property
    def back(self) -> bool:
        return self.key in ("it", "them", "each")


@dataclass
class _Said:
    """One clause read: its figure, its grounds (object keys; "each": one ground copy per figure copy), the clause
    and the step's prompt (the clause with its references back said by name), whether it puts the figure on the
    floor."""

    figure: str
    grounds: list[str]
    clause: str
    prompt: str
    each: bool = False
    floor: bool = False


def read_description(description: str, names: Sequence[str]) -> ScenePlan:
    """The plan of ``description`` over the uploads called ``names`` (given names, else the files' stems): see the
    module's docstring. Raises ``DescriptionError`` (``field`` ``prompt`` or ``names``)."""
    text = " ".join(description.split())
    if not text:
        raise DescriptionError("the description is empty", code="empty_description", field="prompt")
    if len(text) > DESCRIPTION_MAX:
        raise DescriptionError(f"the description is over {DESCRIPTION_MAX} characters", field="prompt")
    keys = [" ".join(w for w in lexicon.words(name) if w not in _DETERMINERS) for name in names]
    if len(keys) < 2:
        raise DescriptionError("a scene needs at least two objects", code="too_few_objects", field="names")
    reader = _Reader(keys)
    for clause in _clauses(text, reader):
        reader.clause(clause)
    phrases = list(dict.fromkeys(_singular(p) for p, _ in reader.unknown))
    if not reader.counts and len(phrases) == len(keys) and phrases != list(names):  # read by them once at most
        return _by_order(description, names, phrases)
    _check_keys(names, keys)
    if reader.unknown:
        phrase, clause = reader.unknown[0]
        raise DescriptionError(f"'{phrase}' (in '{clause}') names none of the objects ({', '.join(keys)}): name "
                               "the uploads as the description does", code="unknown_object", field="prompt")
    return _plan(description, [" ".join(n.split()) for n in names], keys, reader)


def _check_keys(names: Sequence[str], keys: list[str]) -> None:
    """Every upload's name a distinct word or words a description can say."""
    for i, key in enumerate(keys):
        if not key:
            raise DescriptionError(f"object {i + 1}'s name {names[i]!r} has no word to find in a description",
                                   field="names")
        if key in keys[:i]:
            raise DescriptionError(f"two objects are called {key!r}: give each its own name", field="names")


def _by_order(description: str, names: Sequence[str], phrases: list[str]) -> ScenePlan:
    """No upload's name said and one object phrase per upload: the uploads in the order the description names
    its objects (``phrases``), said so."""
    plan = read_description(description, phrases)
    plan.warnings.insert(0, "no object's name is said: matched in the order the description names them ("
                         + ", ".join(f"{n} as {p}" for n, p in zip(names, phrases, strict=True)) + ")")
    return plan


def _singular(phrase: str) -> str:
    """The phrase with its head word in the singular where the lexicon knows that form ("paint tins")."""
    words = phrase.split()
    head = next((w for w in lexicon.singulars(words[-1]) if w in lexicon.LEXICON), words[-1])
    return " ".join([*words[:-1], head])


def _clauses(text: str, reader: _Reader) -> list[str]:
    """The clauses of a description: one per sentence written as a constraint triple, else its pieces between
    commas, "and" and "then" (a "between X and Y" kept whole, a piece that names no object joined to the one
    before: "..., facing it")."""
    out: list[str] = []
    for sentence in filter(None, _SENTENCES.split(text.strip(" ."))):
        triple = _triple(sentence)
        if triple is not None:
            out.append(triple)
            continue
        pieces: list[str] = []
        for piece in filter(None, _PIECES.split(sentence)):
            if pieces and (_open_between(pieces[-1]) or not reader.names_object(piece)):
                joint = " and " if _open_between(pieces[-1]) else ", "
                pieces[-1] = f"{pieces[-1]}{joint}{piece}"
            else:
                pieces.append(piece)
        out.extend(pieces)
    return out


def _triple(sentence: str) -> str | None:
    """A constraint triple ("stool, front of, piano"; "lamp, between, sofa, armchair") as a clause ("the stool in
    front of the piano"); None where the sentence is no triple (its second part is not a relation said alone)."""
    parts = [p.strip() for p in sentence.split(",")]
    if not 3 <= len(parts) <= 2 + MAX_GROUNDS or not all(parts):
        return None
    relation = _TRIPLE_WORDS.get(parts[1].lower(), parts[1].lower())
    cue = cues.find_cue(relation)
    if cue is None or cue.start != 0 or cue.end != len(relation):
        return None
    if (len(parts) == 4) != (cue.relation.grounds == 2):
        return None
    grounds = " and ".join(_the(p) for p in parts[2:])
    return f"{_the(parts[0])} {relation} {grounds}"


def _the(phrase: str) -> str:
    return phrase if phrase.split()[0].lower() in _DETERMINERS else f"the {phrase}"


def _open_between(piece: str) -> bool:
    """A piece that ends inside "between X and Y" (its cue has fewer than two grounds yet; "between them" has)."""
    cue = cues.find_cue(piece, kinds={"between"})
    return cue is not None and cues.ground_phrases(piece, cue) not in (["them"], ["it"]) and len(
        cues.ground_phrases(piece, cue)) < 2


class _Reader:
    """The clauses read one after another: the objects and counts said, the references back, the relations."""

    def __init__(self, keys: list[str]) -> None:
        self.keys = keys
        self.counts: dict[str, int] = {}  # object -> copies, in the order first named
        self.recent: list[str] = []  # objects in the order named (references resolved)
        self.said: list[_Said] = []
        self.unknown: list[tuple[str, str]] = []  # (phrase, clause) naming no upload
        self.previous: list[str] = []  # the objects the clause before named

    def mentions(self, clause: str) -> list[_Mention]:
        """The object phrases of a clause, in order: uploads' names (whole, else a head word only one upload
        has), references back, and phrases after a determiner that name no upload."""
        tokens = [(m.start(), m.end(), m.group()) for m in re.finditer(r"[a-z]+", clause.lower())]
        found: list[_Mention] = []
        i = 0
        while i < len(tokens):
            hit = self._name_at(tokens, i)
            if hit is not None:
                n, key = hit
                each = i > 0 and tokens[i - 1][2] == "each"
                found.append(_Mention(tokens[i][0], tokens[i + n - 1][1], key, each=each))
                i += n
                continue
            word = tokens[i][2]
            if word in ("it", "them"):
                found.append(_Mention(tokens[i][0], tokens[i][1], word))
            elif word == "each" and (i + 1 == len(tokens) or tokens[i + 1][2] in _PHRASE_ENDS | {"one"}):
                found.append(_Mention(tokens[i][0], tokens[i][1], "each"))
            elif word in _DETERMINERS and word != "each":
                phrase = self._phrase(tokens, i + 1)
                if phrase:
                    start, end = tokens[i + 1][0], tokens[i + len(phrase)][1]
                    found.append(_Mention(start, end, " ".join(phrase), known=False))
                    i += len(phrase)
            i += 1
        return found

    def _name_at(self, tokens: list[tuple[int, int, str]], i: int) -> tuple[int, str] | None:
        """(tokens, key) of an upload's name starting at token ``i``: the whole name (or its words as one: "tool
        box" is said "toolbox"), or its last word where no other upload's name ends with it."""
        for key in sorted(filter(None, self.keys), key=lambda k: -len(k.split())):
            words = key.split()
            said = [t[2] for t in tokens[i:i + len(words)]]
            if len(said) == len(words) and said[:-1] == words[:-1] and words[-1] in lexicon.singulars(said[-1]):
                return len(words), key
            if len(words) > 1 and "".join(words) in lexicon.singulars(tokens[i][2]):
                return 1, key
        heads = [k for k in self.keys if k and k.split()[-1] in lexicon.singulars(tokens[i][2])]
        return (1, heads[0]) if len(heads) == 1 else None

    def _phrase(self, tokens: list[tuple[int, int, str]], i: int) -> list[str]:
        """The words of an object's phrase from token ``i`` (up to three, to a word that ends a phrase); [] for a
        part or place of a ground ("the top", "its left") or where an upload's name starts."""
        words: list[str] = []
        while i < len(tokens) and len(words) < 3 and tokens[i][2] not in _PHRASE_ENDS | _DETERMINERS:
            if self._name_at(tokens, i) is not None:
                return []
            words.append(tokens[i][2])
            i += 1
        return [] if not words or words[-1] in PLACE_WORDS | _FLOOR else words

    def names_object(self, piece: str) -> bool:
        """Whether a piece names an object of its own (not only a reference back: "facing it")."""
        return any(not m.back for m in self.mentions(_LEAD.sub("", piece.lower())))

    def clause(self, clause: str) -> None:
        """Read one clause: its objects, their counts, and its relation where it says one."""
        clause = _LEAD.sub("", clause.strip().lower())
        mentions = self.mentions(clause)
        for m in mentions:
            if not m.known:
                self.unknown.append((clause[m.start:m.end], clause))
        named = [m for m in mentions if m.known and not m.back]
        for before, m in zip([None, *mentions], mentions, strict=False):
            if m in named:  # the number said just before its name ("two paint tins"), wherever it is named so
                said = counts.read_count(clause[before.end if before else 0:m.end], m.key).count or 1
                self.counts[m.key] = max(said, self.counts.get(m.key, 1))
        cue = _cue(clause, mentions) if len(named) > 2 else _cue(clause)
        if cue is None or self.unknown and self.unknown[-1][1] == clause:
            self.recent.extend(m.key for m in named)
            self.previous = [m.key for m in named]
            return
        figure_side = [m for m in mentions if (m.start >= cue.end) == cue.cue.figure_after]
        ground_side = [m for m in mentions if m not in figure_side]
        figures = [m for m in figure_side if not m.back]
        if not figures:
            raise DescriptionError(f"'{clause}' names no object to place", code="unclear_clause", field="prompt")
        figure = figures[0] if cue.cue.figure_after else figures[-1]
        self.recent.extend(m.key for m in figure_side if not m.back and m is not figure)
        grounds, each, used = self._grounds(ground_side, figure.key, cue, clause)
        floor = not grounds and bool(_FLOOR & set(clause[cue.end:].split()))
        if not grounds and not floor:
            grounds = [self._back(figure.key, clause)]
        said = clause[:used[-1].end] if len(named) > 2 and used else clause  # the words after are of another
        self.recent.extend([figure.key, *grounds])
        self.previous = [figure.key, *grounds]
        prompt = self._prompt(said, [m for m in ground_side if m.end <= len(said)], grounds) if grounds else clause
        self.said.append(_Said(figure.key, grounds, clause, prompt, each, floor))

    def _grounds(self, side: list[_Mention], figure: str, cue: cues.CueMatch, clause: str
                 ) -> tuple[list[str], bool, list[_Mention]]:
        """The clause's grounds (object keys), whether they are "each" of a group's copies, and the mentions they
        come from."""
        most = cue.relation.grounds
        grounds: list[str] = []
        each = False
        for m in side[:most]:
            if m.key == "them":
                grounds.extend(self._them(figure, clause))
            elif m.key in ("it", "each"):
                grounds.append(self._back(figure, clause))
                each = each or m.key == "each"
            else:
                grounds.append(m.key)
                each = each or m.each
        if figure in grounds:
            raise DescriptionError(f"'{clause}' places the {figure} relative to itself", code="unclear_clause",
                                   field="prompt")
        return grounds[:most], each, side[:most]

    def _back(self, figure: str, clause: str) -> str:
        """What "it" (or a clause without a ground) refers to: the object named last that is not the figure."""
        back = next((key for key in reversed(self.recent) if key != figure), None)
        if back is None:
            raise DescriptionError(f"'{clause}': nothing named before it to place the {figure} against",
                                   code="unclear_clause", field="prompt")
        return back

    def _them(self, figure: str, clause: str) -> list[str]:
        """What "them" refers to: an object with copies the clause before named, else the last two objects named."""
        group = next((key for key in self.previous if key != figure and self.counts.get(key, 1) > 1), None)
        if group is not None:
            return [group]
        last = self._back(figure, clause)
        before = [key for key in reversed(self.recent) if key not in (figure, last)]
        if not before:
            raise DescriptionError(f"'{clause}': 'them' needs two objects named before it", code="unclear_clause",
                                   field="prompt")
        return [before[0], last]

    def _prompt(self, clause: str, side: list[_Mention], grounds: list[str]) -> str:
        """The clause with its references back said by name ("a metronome on the piano")."""
        if not side and not {"its", "their"} & set(clause.split()):  # "a metronome on top": of what it refers to
            return f"{clause} {'of ' if clause.split()[-1] in PLACE_WORDS else ''}the {grounds[0]}"
        out, at = [], 0
        for m in (m for m in side if m.back):
            said = " and ".join(f"the {g}" for g in grounds) if m.key == "them" else f"the {grounds[0]}"
            out.append(clause[at:m.start] + said)
            at = m.end
        return "".join(out) + clause[at:]


def _cue(clause: str, mentions: Sequence[_Mention] = ()) -> cues.CueMatch | None:
    """The clause's relation cue as the pair reader finds it (a placing cue first). A clause naming three objects
    or more ("a lamp on the desk beside the monitor") relates the first two: the cue of the shortest start of the
    clause that names an object before its cue and one after it."""
    for mention in mentions[1:]:
        cue = _cue(clause[:mention.end])
        if cue is not None and cue.end <= mention.start and any(m.end <= cue.start for m in mentions):
            return cue
    return cues.find_cue(clause, kinds=records.PLACING) or cues.find_cue(clause)


def _plan(description: str, names: list[str], keys: list[str], reader: _Reader) -> ScenePlan:
    """The plan of what the reader read: nodes (named as the uploads, copies ``<name>_k``), every ground placed
    before its figures."""
    placed_by: dict[str, _Said] = {}
    for said in reader.said:
        if said.figure in placed_by:
            raise DescriptionError(f"the {said.figure} is placed twice ('{placed_by[said.figure].clause}', "
                                   f"'{said.clause}'): say one place for it", code="placed_twice", field="prompt")
        placed_by[said.figure] = said
    count = {key: reader.counts.get(key, 1) for key in keys}
    for said in reader.said:
        if said.each and len(said.grounds) == 1:
            count[said.figure] = count[said.grounds[0]]
    # what stays on the floor: objects said to, and grounds no clause places
    roots = list(dict.fromkeys(key for s in reader.said for key in ([s.figure] if s.floor else s.grounds)
                               if s.floor or key not in placed_by))
    if not roots:
        raise DescriptionError("every object is placed on another: nothing stays put (the description goes in a "
                               "circle)" if reader.said else "the description places no object relative to another",
                               code="placement_cycle" if reader.said else "nothing_placed", field="prompt")
    nodes = {key: [name] if count[key] == 1 else [f"{name}_{k}" for k in range(1, count[key] + 1)]
             for key, name in zip(keys, names, strict=True)}
    base = nodes[roots[0]][0]
    unnamed = [key for key in keys if key not in placed_by and key not in roots]  # never named, or never placed
    warnings = [f"the {key} is not {'placed by' if key in reader.counts else 'named in'} the description: on the "
                f"floor beside the {roots[0]}" for key in [*(k for k in roots[1:] if k not in placed_by), *unnamed]]
    steps: list[Placement] = []
    for key in [*roots, *unnamed]:
        said = placed_by.get(key)
        steps.extend(_floor(key, [n for n in nodes[key] if n != base], keys.index(key), (base, roots[0]),
                            said.clause if said else ""))
    done = {*roots, *unnamed}
    pending = [s for s in reader.said if not s.floor]
    while pending:
        ready = next((s for s in pending if all(g in done for g in s.grounds)), None)
        if ready is None:
            raise DescriptionError("the description goes in a circle: " + "; ".join(f"'{s.clause}'" for s in pending),
                                   code="placement_cycle", field="prompt")
        pending.remove(ready)
        steps.extend(_steps(ready, nodes, keys))
        done.add(ready.figure)
    return ScenePlan(description, base, keys.index(roots[0]), steps, warnings)


def _floor(key: str, names: list[str], upload: int, base: tuple[str, str], said: str) -> list[Placement]:
    """Steps that put copies on the floor beside the base (``base``: its node and what the description calls it),
    where the description says so or does not place them."""
    base, called = base
    ground = f"other {key}" if key == called else called  # a copy of the base: "a table beside the other table"
    prompt = f"{'an' if key[0] in 'aeiou' else 'a'} {key} beside the {ground}"
    return [Placement(name, upload, prompt, (base,), _relation(base, name, prompt, said or prompt), said, floor=True)
            for name in names]


def _steps(said: _Said, nodes: dict[str, list[str]], keys: list[str]) -> list[Placement]:
    """A clause's steps: one per copy of its figure, each on its grounds (with "each", on its own ground copy)."""
    upload = keys.index(said.figure)
    figures = nodes[said.figure]
    prompt = said.prompt if len(figures) == 1 else counts.one_copy(said.prompt, "scatter")
    if said.each:  # "a cushion on each chair": each copy on the chair it is given
        prompt = re.sub(r"\beach (?!other)", "the ", prompt)
    out = []
    for k, name in enumerate(figures):
        if said.each:
            on = tuple(nodes[g][k] for g in said.grounds)
        elif len(said.grounds) == 1 and len(nodes[said.grounds[0]]) > 1 and cues.find_cue(prompt,
                                                                                             kinds={"between"}):
            on = tuple(nodes[said.grounds[0]][:MAX_GROUNDS])  # "a brush between them": two copies
        else:
            on = tuple(nodes[g][0] for g in said.grounds)
        out.append(Placement(name, upload, prompt, on, _relation(on[0], name, prompt, said.clause), said.clause))
    return out


def _relation(ground: str, figure: str, prompt: str, clause: str) -> str:
    """The relation the pair reader reads of a step's prompt; an error where it takes the figure for the ground."""
    reading = passes.read_prompt(ground, figure, prompt)
    if not reading.figure:
        raise DescriptionError(f"'{clause}': the reader takes the {figure} as the ground here; say it as 'the "
                               f"{figure} <where> the {ground}'", code="unclear_clause", field="prompt")
    return reading.reading.name
