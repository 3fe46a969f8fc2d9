"""A scene from one sentence: a description of several objects read into an assembly plan.

"a piano with its stool in front of it and a metronome on top", "put the stool in front of the piano; stand the
metronome on it", "stool, front of, piano; metronome, on, piano". ``read_description(description, names)`` reads the
description by its sentence structure (``ctp_core.reading.scene``: clauses and their modifiers, coordinated figures
and grounds, nested places, groups, references back, counts, ellipsis) into the relations it says of each object,
then plans them: one step per object (copies ``<name>_k``), its prompt the figure, its cue and its ground by name,
read by the pair reader (``passes.read_prompt``: one reader serves a pair and a plan, so a step means what the same
words mean to ``ctp align``), every ground placed before its figures.

The base (what stays put) is what supports others and is supported by none: among the objects no clause places,
the one holding up the most (furniture before the things on it, a desk before a tray before a cup), then the
largest, then the first named, whatever the order of mention. Each step says what its object stands on
(``support``: the ground of an on/in relation; beside, between, in front of an object on a table: that table; else
the floor), the relations said of it besides its own (``also``: "the lamp on the desk to its right": on the desk,
right of the monitor) and its warnings. An object the description never places goes on the floor beside the base,
with a warning on its step; an object named that matches no upload is an error, never a guess. Torch-free: the API
reads a description before anything is queued.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace

from ctp_core.assembly.plan import MAX_GROUNDS, Also
from ctp_core.errors import ConfigError
from ctp_core.reading import counts, cues, lexicon, passes, scene
from ctp_core.reading.records import ALONGSIDE, RELATIONS, Kind, RelationName
from ctp_core.reading.scene import DETERMINERS, Said, SceneReading, SceneReadingError

__all__ = ["DescriptionError", "Placement", "ScenePlan", "keys_of", "plan_relations", "read_description"]

DESCRIPTION_MAX = 2000  # characters of a description
FLOOR = "floor"  # what a step stands on when no object holds it up
_SENTENCES = re.compile(r"\s*(?:[;\n]|\.(?:\s|$))\s*")
# A constraint triple's relation as layout tools write it ("front of") -> the words the reader reads.
_TRIPLE_WORDS = {"front of": "in front of", "in front": "in front of", "front": "in front of",
                 "side of": "beside", "on top": "on top of", "top of": "on top of", "face": "facing",
                 "faces": "facing", "next": "next to", "back of": "behind"}
_DETERMINERS = DETERMINERS


class DescriptionError(ConfigError):
    """A description that cannot be read into a plan (an object matching no upload, a clause with no object to
    place, a cycle): the CLI prints it, the API answers 422 with its code."""

    code = "invalid_description"


@dataclass(frozen=True)
class Placement:
    """One step of the plan: the node it places (``name``; copies ``<name>_k``), its upload, the prompt its run is
    read and guided by, the nodes it relates to (``on``), the relation the reader reads and the clause it comes
    from (``said``; empty where the description never places the object: ``floor``), what it stands on
    (``support``: a node, or "floor"), the relations said of it besides (``also``) and its warnings."""

    name: str
    upload: int
    prompt: str
    on: tuple[str, ...]
    relation: str
    said: str = ""
    floor: bool = False
    support: str = FLOOR
    also: tuple[Also, ...] = ()
    warnings: tuple[str, ...] = ()

    def to_dict(self) -> dict:
        out = asdict(self)
        return {**out, "on": list(self.on), "warnings": list(self.warnings),
                "also": [a.to_dict() for a in self.also]}


@dataclass
class ScenePlan:
    """The plan a description reads into: the base (stays put), the steps in placing order, what was assumed
    (``warnings``: every step's, and the plan's own), and who read it (``reader``)."""

    description: str
    base: str
    base_upload: int
    steps: list[Placement]
    warnings: list[str] = field(default_factory=list)
    reader: str = "rules"

    def to_dict(self) -> dict:
        return {"description": self.description, "base": self.base, "base_upload": self.base_upload,
                "base_support": FLOOR, "steps": [s.to_dict() for s in self.steps], "warnings": list(self.warnings),
                "reader": self.reader}

    def assembly_plan(self, files: Sequence[str]) -> dict:
        """The plan as ``ctp assemble --plan`` and ``POST /assemble`` take it (``files``: one per upload)."""
        return {"base": files[self.base_upload], "name": self.base,
                "steps": [{"file": files[s.upload], "name": s.name, "prompt": s.prompt,
                           "on": s.on[0] if len(s.on) == 1 else list(s.on),
                           **({"also": [a.to_dict() for a in s.also]} if s.also else {})} for s in self.steps]}


def read_description(description: str, names: Sequence[str]) -> ScenePlan:
    """The plan of ``description`` over the uploads called ``names`` (given names, else the files' stems): see the
    module's docstring. Raises ``DescriptionError`` (``field`` ``prompt`` or ``names``)."""
    text = " ".join(description.split())
    if not text:
        raise DescriptionError("the description is empty", code="empty_description", field="prompt")
    if len(text) > DESCRIPTION_MAX:
        raise DescriptionError(f"the description is over {DESCRIPTION_MAX} characters", field="prompt")
    keys = keys_of(names)
    if len(keys) < 2:
        raise DescriptionError("a scene needs at least two objects", code="too_few_objects", field="names")
    said = "; ".join(_triple(s) or s for s in filter(None, _SENTENCES.split(text.strip(" .")))) + "."
    try:
        reading = scene.read_scene(said, keys)
    except SceneReadingError as exc:
        unknown = _unknown(said, keys)
        if not unknown:
            raise DescriptionError(exc.message, code=exc.code, field="prompt") from None
        reading = SceneReading(unknown=unknown)
    phrases = list(dict.fromkeys(_singular(p) for p, _ in reading.unknown))
    if not reading.counts and len(phrases) == len(keys) and phrases != list(names):  # read by them once at most
        return _by_order(description, names, phrases)
    _check_keys(names, keys)
    if reading.unknown:
        phrase, clause = reading.unknown[0]
        raise DescriptionError(f"'{phrase}' (in '{clause}') names none of the objects ({', '.join(keys)}): name "
                               "the uploads as the description does", code="unknown_object", field="prompt")
    return plan_relations(description, [" ".join(n.split()) for n in names], keys, reading)


def keys_of(names: Sequence[str]) -> list[str]:
    """What a description calls each upload: its name's words, determiners dropped ("The Sofa" -> "sofa")."""
    return [" ".join(w for w in lexicon.words(name) if w not in _DETERMINERS) for name in names]


def _unknown(text: str, keys: list[str]) -> list[tuple[str, str]]:
    """The phrases naming no upload, for a description whose clauses could not be read (names said otherwise)."""
    try:
        return scene.read_scene(text.replace(";", ".").replace(",", "."), keys).unknown
    except SceneReadingError:
        return []


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


# -- the plan -----------------------------------------------------------------------------------------------------

def plan_relations(description: str, names: list[str], keys: list[str], reading: SceneReading) -> ScenePlan:
    """The plan of what a reader read (the rules, or a language model's answer: ``readers``): nodes (named as the
    uploads, copies ``<name>_k``), the base, every ground placed before its figures."""
    notes: dict[str, list[str]] = {}
    placed_by, also = _relations(reading, notes)
    count = {key: reading.counts.get(key, 1) for key in keys}
    for said in placed_by.values():
        if said.each and len(said.grounds) == 1:
            count[said.figure] = count[said.grounds[0]]
    roots = list(dict.fromkeys(
        [*(k for k, s in placed_by.items() if s.floor),
         *(g for s in placed_by.values() for g in s.grounds if g not in placed_by)]))
    if not roots:
        if not placed_by:
            raise DescriptionError("the description places no object relative to another", code="nothing_placed",
                                   field="prompt")
        raise DescriptionError("every object is placed on another: nothing stays put (the description goes in a "
                               "circle)", code="placement_cycle", field="prompt")
    base_key = _base(roots, placed_by)
    nodes = {key: [name] if count[key] == 1 else [f"{name}_{k}" for k in range(1, count[key] + 1)]
             for key, name in zip(keys, names, strict=True)}
    base = nodes[base_key][0]
    unplaced = [k for k in roots if k != base_key and k not in placed_by]
    unnamed = [key for key in keys if key not in placed_by and key not in roots]  # never named, or never placed
    for key in [*unplaced, *unnamed]:
        how = "placed by" if key in reading.named else "named in"
        notes.setdefault(key, []).append(f"the {key} is not {how} the description: on the floor beside the "
                                         f"{base_key}")
    support: dict[str, str] = {base: FLOOR}
    steps: list[Placement] = []
    for key in [base_key, *(k for k in roots if k != base_key and k in placed_by), *unplaced, *unnamed]:
        said = placed_by.get(key)
        for node in nodes[key]:
            if node != base:
                warned = tuple(notes.get(key, ())) if key != base_key or node == nodes[key][1] else ()
                steps.append(_floor(key, node, keys.index(key), (base, base_key), said.clause if said else "",
                                    warned))
                support[node] = FLOOR
    done = {base_key, *roots, *unnamed}
    for said in _order([s for s in placed_by.values() if not s.floor and s.figure not in done], done, also):
        said, more = _on_the_same_top(said, also.get(said.figure, []), support, nodes)
        for step in _steps(said, nodes, keys, more, support, tuple(notes.get(said.figure, ()))):
            support[step.name] = step.support
            steps.append(step)
    warnings = list(dict.fromkeys([*(w for s in steps for w in s.warnings), *reading.notes]))
    return ScenePlan(description, base, keys.index(base_key), steps, warnings)


def _relations(reading: SceneReading, notes: dict[str, list[str]]) -> tuple[dict[str, Said], dict[str, list[Said]]]:
    """Each object's own relation (the one that places it) and the others said of it; what cannot be placed noted
    under its object."""
    placed_by: dict[str, Said] = {}
    for said in reading.said:
        if not said.primary or said.derived:
            continue
        if said.figure in placed_by:
            raise DescriptionError(f"the {said.figure} is placed twice ('{placed_by[said.figure].clause}', "
                                   f"'{said.clause}'): say one place for it", code="placed_twice", field="prompt")
        placed_by[said.figure] = said
    for said in reading.said:  # said of a ground by the relation after its figure's: where nothing else places it
        if said.derived and said.figure not in placed_by:
            placed_by[said.figure] = said
    for key, said in list(placed_by.items()):
        if said.room and not said.grounds:  # "a mirror on the wall": no object of the scene to place it against
            notes.setdefault(key, []).append(f"'{said.clause}': the {said.room} is no object of the scene")
            del placed_by[key]
    also: dict[str, list[Said]] = {}
    for said in reading.said:
        if not said.primary and said.grounds:
            also.setdefault(said.figure, []).append(said)
        elif not said.primary and said.room:
            notes.setdefault(said.figure, []).append(f"'{said.clause}': the {said.room} is no object of the scene: "
                                                     f"'{said.cue} the {said.room}' is not judged")
    _places_of_grounds(placed_by, also)
    return placed_by, also


def _places_of_grounds(placed_by: dict[str, Said], also: dict[str, list[Said]]) -> None:
    """A figure put on A and beside (in front of, ...) B, where nothing else places A or B, says where they stand:
    B smaller than A stands on A ("a lamp on the desk beside the monitor": the monitor on the desk, the lamp beside
    it there); A smaller than B stands by B as said ("a lamp on the nightstand by the bed": the nightstand by the
    bed). Where the lexicon knows neither size, nothing is assumed (B goes beside the base, with a warning)."""
    for figure, said in list(placed_by.items()):
        if not said.supports or len(said.grounds) != 1:
            continue
        (top,) = said.grounds
        for other in also.get(figure, []):
            if RELATIONS[other.relation].kind not in ALONGSIDE - {Kind.ORIENTATION} or len(other.grounds) != 1:
                continue
            (beside,) = other.grounds
            if beside in placed_by or beside == top:
                continue
            a, b = _size(top), _size(beside)
            if a is None or b is None:
                continue
            if b < a:  # the monitor on the desk
                placed_by[beside] = replace(said, figure=beside, det="the", derived=True, part="")
            elif top not in placed_by:  # the nightstand by the bed
                placed_by[top] = replace(other, figure=top, det="the", derived=True, primary=True)
                also[figure] = [a for a in also[figure] if a is not other]


def _size(key: str) -> float | None:
    match = lexicon.lookup(key)
    return match.size_m if match is not None else None


def _order(pending: list[Said], done: set[str], also: dict[str, list[Said]]) -> list[Said]:
    """The relations in placing order: every ground before its figures; a relation whose other objects are placed
    first ("right of the monitor": after the monitor) where the grounds leave a choice."""
    out: list[Said] = []
    while pending:
        ready = [s for s in pending if all(g in done for g in s.grounds)]
        if not ready:
            raise DescriptionError("the description goes in a circle: " + "; ".join(f"'{s.clause}'" for s in pending),
                                   code="placement_cycle", field="prompt")
        said = next((s for s in ready if all(g in done for a in also.get(s.figure, ()) for g in a.grounds)), ready[0])
        pending.remove(said)
        out.append(said)
        done.add(said.figure)
    return out


def _on_the_same_top(said: Said, also: list[Said], support: dict[str, str], nodes: dict[str, list[str]]
                     ) -> tuple[Said, list[Said]]:
    """An object put on something and beside, between or in front of objects standing on that same thing ("the lamp
    on the desk to the right of the monitor", the monitor on the desk): placed by that relation, standing on the
    same top (its step's ``support``), the relation of support said as well."""
    if not said.supports or said.each or len(said.grounds) != 1:
        return said, also
    top = nodes[said.grounds[0]][0]
    for other in also:
        if (RELATIONS[other.relation].kind in ALONGSIDE - {Kind.ORIENTATION} and other.grounds
                and all(support.get(nodes[g][0]) == top for g in other.grounds)):
            placed = replace(other, primary=True, clause=said.clause, det=said.det)
            return placed, [replace(said, primary=False), *(a for a in also if a is not other)]
    return said, also


def _base(roots: list[str], placed_by: dict[str, Said]) -> str:
    """What stays put: among the objects no clause places, the one that holds up the most objects (through what
    they hold up), then the largest the lexicon knows, then the first named."""
    def held(key: str, seen: frozenset[str] = frozenset()) -> int:
        above = [f for f, s in placed_by.items() if s.supports and key in s.grounds and f not in seen]
        return len(above) + sum(held(f, seen | {key}) for f in above)

    return max(roots, key=lambda k: (held(k), _size(k) or 0.0, -roots.index(k)))


def _floor(key: str, node: str, upload: int, base: tuple[str, str], said: str, warnings: tuple[str, ...]
           ) -> Placement:
    """A step that puts a copy on the floor beside the base (``base``: its node and what the description calls it),
    where the description says so or does not place it."""
    base, called = base
    ground = f"other {key}" if key == called else called  # a copy of the base: "a table beside the other table"
    prompt = f"{_a(key)} {key} beside the {ground}"
    return Placement(node, upload, prompt, (base,), _relation(base, node, prompt, said or prompt), said, floor=True,
                     support=FLOOR, warnings=warnings)


def _a(word: str) -> str:
    return "an" if word[:1] in "aeiou" else "a"


def _plural(key: str) -> str:
    return key + ("es" if key.endswith(("s", "x", "ch", "sh")) else "s")


def _ground_words(said: Said, grounds: list[str], copies: bool) -> str:
    """How a step's prompt names its grounds: "the desk", "the sofa and the armchair", "the storage boxes" (a group
    of copies), "the top shelf of the bookcase" (a part that names a place)."""
    if copies:
        return f"the {_plural(grounds[0])}"
    words = " and ".join(f"the {g}" for g in grounds)
    if said.part and scene.is_place_said(said.part):
        return f"the {said.part} of {words}"
    return words


def _cue_words(said: Said, ground: str) -> str:
    """The cue as the step says it: "to its right" -> "to the right of <ground>", "in front" -> "in front of
    <ground>"; else as said, followed by the ground."""
    cue = said.cue
    words = cue.split()
    if len(words) >= 2 and any(w in ("its", "their", "his", "her") for w in words[:-1]) and words[-1] in (
            scene.PLACE_WORDS | {"side", "end"}) and said.relation != "facing_away":
        return re.sub(r"\b(?:its|their|his|her)\b", "the", cue) + f" of {ground}"
    if words[-1] in scene.PLACE_WORDS:
        return f"{cue} of {ground}"
    return f"{cue} {ground}"


def _prompt(said: Said, figure: str, grounds: list[str], copies: bool) -> str:
    return f"{figure} {_cue_words(said, _ground_words(said, grounds, copies))}"


def _steps(said: Said, nodes: dict[str, list[str]], keys: list[str], also: list[Said], support: dict[str, str],
           warnings: tuple[str, ...]) -> list[Placement]:
    """A clause's steps: one per copy of its figure, each on its grounds (with "each", on its own ground copy; a
    group: on every one of its objects)."""
    upload = keys.index(said.figure)
    figures = nodes[said.figure]
    copies = len(said.grounds) == 1 and len(nodes[said.grounds[0]]) > 1 and (said.group or said.relation == "between")
    det = "a" if len(figures) > 1 else said.det
    if said.figure.split()[-1] in counts.ONE_PAIR:  # "a pair of glasses": one object said as a pair
        det = "the"
    figure = f"{_a(said.figure) if det == 'a' else det} {said.figure}"
    if len(figures) > 1 and counts.read_count(said.clause).arrangement == "around":
        said = replace(said, cue="beside")  # "four chairs around the table": each beside it, facing it
        also = [*also, replace(said, relation=RelationName.FACING, cue="facing", primary=False)]
    prompt = _prompt(said, figure, list(said.grounds), copies)
    held = [a for a in also if a.supports and not said.supports and len(a.grounds) == 1
            and a.grounds[0] not in said.grounds]
    for a in held[:1]:  # "to the right of the monitor, on the desk": where it stands said too
        prompt += f", {_cue_words(a, _ground_words(a, list(a.grounds), False))}"
    turns = [a for a in also if RELATIONS[a.relation].kind == Kind.ORIENTATION]
    for a in turns:  # "in front of the desk, facing it": one reading, both judged; facing another: said too
        prompt += f", {_cue_words(a, _ground_words(a, list(a.grounds), False))}"
    others = [a for a in also if a.grounds != said.grounds or a not in turns]
    notes = list(warnings)
    if said.part and not scene.is_place_said(said.part):
        notes.append(f"'{said.clause}': on the {said.grounds[0]}, its {said.part} not told apart")
    out = []
    for k, name in enumerate(figures):
        if said.each:
            on = tuple(nodes[g][k % len(nodes[g])] for g in said.grounds)
        elif copies:
            on = tuple(nodes[said.grounds[0]][:MAX_GROUNDS])  # "next to them", "a brush between them": the copies
        else:
            on = tuple(nodes[g][0] for g in said.grounds)[:MAX_GROUNDS]
        relation = _relation(on[0], name, prompt, said.clause)
        more = tuple(Also(p, tuple(nodes[g][0] for g in a.grounds)[:MAX_GROUNDS],
                          _relation(nodes[a.grounds[0]][0], name, p, a.clause)) for a in others
                     for p in [_prompt(a, f"the {said.figure}", list(a.grounds), False)])
        out.append(Placement(name, upload, prompt, on, relation, said.clause, support=_support(relation, on, support),
                             also=more, warnings=tuple(notes)))
    return out


def _support(relation: str, on: tuple[str, ...], support: dict[str, str]) -> str:
    """What a step's object stands on, by the relation the reader reads (``relation``): the ground of a relation of
    support; for one beside, between or in front of objects that stand on the same thing, that thing; else the
    floor."""
    position = RelationName(relation.split("+")[0])
    if scene.is_support(position):
        return on[0]
    if RELATIONS[position].kind in ALONGSIDE:
        below = {support.get(g, FLOOR) for g in on}
        if len(below) == 1:
            return below.pop()
    return FLOOR


def _relation(ground: str, figure: str, prompt: str, clause: str) -> str:
    """The relation the pair reader reads of a step's prompt; an error where it takes the figure for the ground."""
    reading = passes.read_prompt(ground, figure, prompt)
    if not reading.figure or reading.reading is None:
        raise DescriptionError(f"'{clause}': the reader takes the {figure} as the ground here; say it as 'the "
                               f"{figure} <where> the {ground}'", code="unclear_clause", field="prompt")
    return reading.reading.name

