"""Spatial relations read from a prompt: which cue, and who is the figure.

A relation has a *figure* (the thing placed: the hat, the cup, the arrow) and a *ground* (the head,
the table, the target). Contact is a fraction of the **source** surface, so it depends on whether the
source is the figure ("a cup on a table": its base, 0.15) or the ground (the table under the cup:
almost none). The names say which mesh is the source; the prompt's word order around the cue says
which role it plays ("Pinocchio wearing a hat" and "a hat on Pinocchio" both make the hat the figure).

Cues are matched as whole words (``in`` never matches inside "pinocchio" or "dining"), the most
specific cue wins (``CUES`` is in priority order: "holding a carrot in his hand" is holding, not in),
and ties go to the earliest cue.

A reading may say two things ("in front of the sofa, facing it"; "against the back of the sofa"): a position and an
orientation, or a lean and the side it leans on, named together as ``front+facing``, ``lean+behind`` (``JOIN``;
``parts`` splits them) and judged both. ``side_of`` gives the side of the ground a reading puts the figure on (the
target's own frame: ``predicates``); ``implied`` what a reading of an orientation alone means.
"""

from __future__ import annotations

import functools
import re
from collections.abc import Sequence
from dataclasses import dataclass, field


@dataclass(frozen=True)
class Relation:
    """One relation of the vocabulary, all that is known of it without the geometry: its reading priors and the
    declarative facts the engine reads (its score, preference, proposals and scale bound are its spec's,
    ``registry.SPECS``, under the same name).

    ``figure_contact``, ``ground_contact``: the share of the figure's and of the ground's surface in contact.
    ``penetration``: "yes" (cut, pierce, embed ... unless the ground is a container: a key stuck in a
    lock goes into the keyhole), "if_pointed" ("in"/"through": an arrow in a target yes, a spoon in a
    cup no) or "no". ``figure_size``: the figure's size over the ground's when the lexicon does not
    know one of them; what sits on, in or hangs from something is usually the smaller of the two.
    ``kind``: ``contact`` (the figure touches or rests on its ground: the relations above), ``side`` (beside the
    ground on one of its sides, in its own frame: ``front``, ``behind``, ``left``, ``right``), ``vertical``
    (``above``, ``below``: a gap, no contact), ``distance`` (``near``, ``far``), ``orientation`` (which way the
    figure's front points: ``facing``, ``facing_away``, ``aligned``; said alone or after a position) or ``between``
    (two grounds: the figure in the gap between them).
    ``rests``: the figure rests on its ground from above (the resting family: its score includes stability).
    ``steady``: stability applies (``predicates.stable``): what stands on something, the ground or the floor, rather
    than hangs, is fixed or goes into it.
    ``figure_regions``, ``ground_regions``: the search's region weights (``proposals.REGIONS``) when the source is
    the figure and when it is the ground; regions not named weigh 1 (weights shift proposals toward where the
    relation puts the figure, never away from everywhere else).
    """

    name: str
    figure_contact: float
    ground_contact: float
    figure_size: float
    penetration: str = "no"
    kind: str = "contact"
    rests: bool = False
    steady: bool = False
    figure_regions: dict[str, float] = field(default_factory=dict)
    ground_regions: dict[str, float] = field(default_factory=dict)


_AROUND = {"gap": 4.0, "side": 2.0, "floor": 3.0}  # the floor around the ground: beside it, on a side, near, far


def _apart(name: str, kind: str, size: float = 1.0, steady: bool = True) -> Relation:
    """A relation without contact; every one but ``above`` and ``below`` stands on the floor around the ground."""
    around = _AROUND if kind in ("side", "distance", "orientation") else {}
    return Relation(name, 0.0, 0.0, size, kind=kind, steady=steady, figure_regions=around, ground_regions=around)


RELATIONS: dict[str, Relation] = {r.name: r for r in (
    # the buried part of a blade, arrow or nail
    Relation("penetrate", 0.25, 0.1, 0.8, "yes", figure_regions={"top": 1.5, "side": 1.5, "drop": 1.5}),
    # a hat's inner band; garments that wrap get more (rules)
    Relation("wear", 0.35, 0.1, 0.2, steady=True, figure_regions={"top": 4.0, "drop": 4.0},
             ground_regions={"bottom": 3.0}),
    Relation("hold", 0.1, 0.05, 0.3, figure_regions={"side": 2.0}),  # a hand closes around a handle
    # a rider or sitter: seat, legs, hands
    Relation("sit", 0.2, 0.2, 0.6, rests=True, steady=True, figure_regions={"top": 3.0, "drop": 3.0},
             ground_regions={"bottom": 3.0}),
    # lying or draped: one side
    Relation("lie", 0.35, 0.05, 0.3, rests=True, steady=True, figure_regions={"top": 3.0, "drop": 3.0},
             ground_regions={"bottom": 3.0}),
    # feet or a foot only
    Relation("stand", 0.05, 0.02, 0.3, rests=True, steady=True, figure_regions={"top": 4.0, "drop": 3.0},
             ground_regions={"bottom": 4.0}),
    Relation("wrap", 0.6, 0.2, 0.3, figure_regions={"side": 2.0}),  # coiled or tied around
    # an end or an edge
    Relation("lean", 0.05, 0.02, 0.8, steady=True, figure_regions={"side": 3.0, "floor": 2.0}),
    Relation("hang", 0.05, 0.02, 0.2, figure_regions={"side": 2.0, "bottom": 2.0}),  # a loop on a hook
    # glued, taped, mounted: a face or a foot
    Relation("attach", 0.3, 0.05, 0.2, figure_regions={"side": 2.0, "drop": 2.0}),
    # "a ball under the table" does not touch it
    Relation("under", 0.0, 0.05, 0.5, steady=True, figure_regions={"bottom": 3.0, "gap": 2.0, "floor": 4.0},
             ground_regions={"top": 4.0, "drop": 3.0}),
    # next to, behind, in front of: no contact
    Relation("beside", 0.0, 0.0, 1.0, steady=True, figure_regions=_AROUND, ground_regions=_AROUND),
    # contained: the bottom and some of the walls
    Relation("in", 0.25, 0.15, 0.5, "if_pointed", steady=True, figure_regions={"inside": 4.0, "top": 1.5, "drop": 2.0}),
    # resting on: its base
    Relation("on", 0.15, 0.05, 0.3, rests=True, steady=True, figure_regions={"top": 4.0, "drop": 4.0},
             ground_regions={"bottom": 4.0}),
    # where, without contact: beside the ground on one of its sides, above or below it, near or far from it
    *(_apart(side, "side") for side in ("front", "behind", "left", "right")),
    _apart("above", "vertical", 0.5, steady=False),  # a painting above a sofa, a lamp over a table: hung or fixed
    _apart("below", "vertical", 0.5, steady=False),
    _apart("near", "distance"),
    _apart("far", "distance"),
    # which way the figure's front points, relative to the ground
    *(_apart(name, "orientation") for name in ("facing", "facing_away", "aligned")),
    # two grounds: on the floor in the gap between them, clear of both
    Relation("between", 0.0, 0.0, 0.5, kind="between", steady=True, figure_regions={"floor": 4.0, "gap": 2.0}),
)}
PLACING = {"contact", "side", "vertical", "distance", "between"}  # the kinds that say where the figure is
JOIN = "+"  # a reading of two: a position and an orientation ("front+facing"), a lean and its side ("lean+behind")
# where an orientation said alone puts the figure: "a chair facing the desk" stands near the desk, not across the room
ORIENTED_NEAR = "near"


def parts(name: str | None) -> tuple[str, ...]:
    """The relations a reading names (``front+facing``: both); () for None."""
    return tuple(name.split(JOIN)) if name else ()


def implied(name: str) -> str:
    """The reading a name stands for: an orientation said alone ("a chair facing the desk", "a statue facing away
    from the house", "a bench aligned with the wall") places its figure ``ORIENTED_NEAR`` its ground too
    (``near+facing``): which way a front points says nothing of where, and a user who names the ground by it means
    the figure to stand by it. Every other name is itself."""
    named = parts(name)
    if named and all(p in RELATIONS and RELATIONS[p].kind == "orientation" for p in named):
        return JOIN.join((ORIENTED_NEAR, *named))
    return name


def side_of(name: str | None) -> str | None:
    """The side of the ground the reading puts the figure on (``front``, ``behind``, ``left``, ``right``), if any."""
    return next((p for p in parts(name) if p in RELATIONS and RELATIONS[p].kind == "side"), None)


@dataclass(frozen=True)
class RelationReading:
    """The relation a run uses: the reading's name (one relation, or a position and an orientation joined:
    ``front+facing``) and whether the source is its figure (the thing placed) or its ground. Built once from the
    priors (``ScenePrior.reading``) or from a report's verdict (``from_verdict``) and passed as one value; a run
    without a relation has None. An orientation said alone reads with the distance it implies (``implied``)."""

    name: str
    source_is_figure: bool = True
    place: str | None = None  # where on or beside the ground the prompt names (``reading.places``); None: the usual

    def __post_init__(self) -> None:
        object.__setattr__(self, "name", implied(self.name))  # what a name means is judged: "facing" is near+facing

    @classmethod
    def from_verdict(cls, verdict: dict | None) -> RelationReading | None:
        """The reading a report's ``relation`` (``predicates.RelationVerdict.to_dict``) was judged with; None
        without one."""
        if not verdict or verdict.get("name") is None:
            return None
        return cls(verdict["name"], verdict.get("role") != "ground", verdict.get("place"))

    @property
    def parts(self) -> tuple[str, ...]:
        """The relations it names, the position first (``front+facing``: front, facing)."""
        return parts(self.name)

    @property
    def known(self) -> bool:
        """Whether every relation it names is one of the vocabulary's (``RELATIONS``)."""
        return bool(self.parts) and all(p in RELATIONS for p in self.parts)

    @property
    def records(self) -> tuple[Relation, ...]:
        """The vocabulary's record of each relation it names (only the known ones)."""
        return tuple(RELATIONS[p] for p in self.parts if p in RELATIONS)

    @property
    def position(self) -> str:
        """The first relation it names: where the figure is (``front+facing``: front), or an orientation said
        alone."""
        return self.parts[0]

    @property
    def side(self) -> str | None:
        """The side of the ground it puts the figure on, if it names one (``side_of``)."""
        return side_of(self.name)

    @property
    def orientation(self) -> str | None:
        """The orientation it names (``facing``, ``facing_away``, ``aligned``), if any."""
        return next((r.name for r in self.records if r.kind == "orientation"), None)

    @property
    def role(self) -> str:
        """The source's role, as reports write it: "figure" or "ground"."""
        return "figure" if self.source_is_figure else "ground"

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
        return any(r.kind in ("side", "orientation") for r in self.records)

    @property
    def regions(self) -> dict[str, float]:
        """The search's region weights of its position, for the source's role (unnamed regions weigh 1)."""
        record = RELATIONS.get(self.position)
        if record is None:
            return {}
        return record.figure_regions if self.source_is_figure else record.ground_regions


@dataclass(frozen=True)
class Cue:
    pattern: str
    relation: str
    figure_after: bool = False  # the figure is named after the cue ("wearing a hat", "holding a cup")


_HEAD = r"(?:the |his |her |its |their |a |an )?(?:[a-z]+\s+){0,2}heads?"
_BODY = r"(?:hands?|paws?|mouths?|arms?|grip|beak|claws?|fingers?|teeth)"
_POSS = r"(?:his|her|its|their|the|a|one)"


def _side(words: str, before: str = "to|on|at|by", bare: str = "[ _]", of: str = "(?: of)?") -> str:
    """A side's wordings: "to the left of", "on its left", "at the left-hand end of", "left of", "left_of" (``bare``:
    what joins the side and "of" with no preposition before; ``of``: after a preposition). Not after a verb of
    fastening: "attached to the front of a bicycle", "strapped to the back of a scooter" are on it."""
    return (_FASTENED + r"(?:(?:" + before + r") (?:the |its |his |her |their )?" + words
            + r"(?:[- ]hand)?(?: side| end)?" + of + "|" + words + r"(?:[- ]hand)?(?: side)?" + bare + "of)")


_FASTENED = "".join(f"(?<!{verb} )" for verb in ("attached", "strapped", "hitched", "fixed", "mounted", "clipped",
                                                 "tied", "bolted", "fastened", "glued", "taped", "pinned", "stuck",
                                                 "chained", "secured", "nailed", "screwed"))


# How far or how firmly, between a verb and its preposition: "stuck halfway through", "pushed deep into".
_ADV = r"(?:(?:halfway|half way|partway|part way|deep|deeply|firmly|straight|right|upright|securely|all the way) )?"

# One list for every relation, in priority order (the most specific wording first): priority is a property of the
# whole list, how wordings of different relations overlap, not of one relation's record.
CUES: list[Cue] = [
    # penetration: the penetrating object is the figure
    Cue(r"(?:pierced|cut|stabbed|skewered|impaled|speared) (?:by|with)", "penetrate", True),
    Cue(r"pierc(?:e|es|ed|ing)|stab(?:s|bed|bing)?|impal(?:e|es|ed|ing)|skewer(?:ed|ing)|spear(?:ed|ing)"
        r"|cut(?:s|ting)?(?: through| into)?(?!\s+boards?)|slicing(?: through| into)?|embedded|lodged|penetrat[a-z]*"
        r"|stuck " + _ADV + r"(?:in|into|through)|stick(?:s|ing)? " + _ADV + r"(?:in|into|out of|through)"
        r"|buried " + _ADV + r"(?:in|into)"
        r"|pok(?:e|es|ed|ing) (?:out of|through|into)|peek(?:s|ing)? out of|protrud(?:e|es|ing) from"
        r"|(?:driven|hammered|nailed|pinned|planted|pushed|pressed|poked|thrust|plunged|sunk|jammed|screwed|shot|staked|dug)"
        r" " + _ADV
        + r"(?:in|into)"
        r"|(?:pushed|poked|thrust|jammed|shoved|driven|hammered) " + _ADV + r"through|set " + _ADV + r"into"
        r"|planted (?:on|atop)|carv(?:e|es|ed|ing)|(?:chop|split|crack)(?:s|ped|ping|ting|ing)? (?:into|through|open)"
        r"|saw(?:s|ed|ing)? (?:through|into)|(?:drill|bor)(?:e|es|ed|ing|s)? (?:a hole )?(?:in|into|through)",
        "penetrate"),
    # garments and headwear
    Cue(r"on (?:top of )?" + _HEAD + r"|around " + _POSS + r" (?:neck|waist|wrist|finger|arm)s?|worn by",
        "wear"),
    Cue(r"wear(?:s|ing)?|dressed in|put(?:s|ting)? on|has on|donning", "wear", True),
    # two grounds, named after the cue ("between the sofa and the armchair"): before "in" and the sides
    Cue(r"(?:in |midway |halfway |right )?between|in the (?:middle|center|centre) of(?= [a-z ]+ and )|flanked by",
        "between"),
    # held
    Cue(r"in " + _POSS + r" " + _BODY + r"|held (?:by|in)", "hold"),
    Cue(r"hold(?:s|ing)?|carr(?:y|ies|ying)|grasp(?:s|ing)?|grip(?:s|ping)?|clutch(?:es|ing)?|wield(?:s|ing)?"
        r"|brandish(?:es|ing)?|play(?:s|ing)|hug(?:s|ging)?|eat(?:s|ing)|bit(?:e|es|ing)|sting(?:s|ing)?",
        "hold", True),
    # where, in the ground's own frame, before the contact words they contain ("on the left side of" is left, not
    # on; "sitting in front of" is front); the wordings of SpatialSense, Sr3D, Holodeck and LayoutVLM
    Cue(_side("left"), "left"),
    Cue(_side("right"), "right"),
    # "on the front of", "on the back of a horse": on it
    # "by the front door", "at the front of the desk" (its front edge), "strapped to his back": no side
    Cue(r"in front(?: of)?|opposite|across from|" + _side("front", "to|by", "_", " of"), "front"),
    Cue(r"behind|in back of|" + _side("(?:back|rear)", "to|at|by", "_", " of"), "behind"),
    Cue(r"fac(?:e|es|ing) away(?: from)?|turned away from|look(?:s|ing)? away from|point(?:s|ing)? away from"
        r"|with (?:its|his|her|their) backs? (?:to|toward|towards)", "facing_away"),
    Cue(r"facing(?:[ _](?:to|toward|towards))?|fac(?:e|es)[ _](?:to|toward|towards)"  # "a rock face": no facing
        r"|faces(?= (?!(?:of|on|in|at|with|and|are|were)(?![a-z]))[a-z])|turned (?:to|toward|towards)"
        r"|look(?:s|ing)? (?:at|toward|towards)|point(?:s|ing)?[ _](?:at|to|toward|towards)"
        r"|oriented (?:to|toward|towards)", "facing"),
    Cue(r"align(?:s|ed)?[ _](?:with|to)|parallel (?:to|with)|in line with|lined up with|(?:in|with) the same"
        r" direction as", "aligned"),
    Cue(r"not far from|near(?:by|er|est)?(?: to)?|close(?:r|st)? to|close by|in the vicinity of|a short distance from"
        r"|within reach of|outside(?: of)?", "near"),
    Cue(r"far(?: away| off)? from|farthest from|furthest from|a long way from|distant from|at a distance from"
        r"|(?<!facing )(?<!faces )(?<!face )(?<!turned )(?<!looking )(?<!looks )(?<!pointing )(?<!points )"
        r"(?:away|apart) from", "far"),
    # supported postures
    Cue(r"rid(?:e|es|ing)|astride|straddl[a-z]+|driv(?:e|es|ing)|(?:sit|sits|sitting|seated|sat)"
        r" (?:on|in|at|astride|inside)", "sit"),
    Cue(r"(?:lying|lies|laid|lay|sleeping|sleeps|napping|curled up|draped|spread) (?:on|over|across|upon)"
        r"|cover(?:s|ing)(?= (?:the|a|an|its|his|her|their) )", "lie"),  # a cover lies over what it covers
    Cue(r"covered (?:by|with)", "lie", True),
    Cue(r"(?:standing|stands|stood|perched|perching|balanced|balancing|landed|hopping) (?:on|upon|atop)",
        "stand"),
    Cue(r"(?:wrapped|coiled|wound|tied|looped|wrapping|coiling) (?:around|round)|around|surround(?:s|ing)"
        r"|encircl(?:es|ing)", "wrap"),
    Cue(r"lean(?:s|ing|ed)? (?:against|on|in)|propped (?:against|up|on)|rest(?:s|ing)? against|against"
        r"|touch(?:es|ing)", "lean"),  # touching its side: Rel3D's "touching"
    # moving over a support: feet, wheels or a belly on it
    Cue(r"(?:walk|run|crawl|stroll|march|hik|climb|roll|skat|ski|slid|trott|gallop|wander)(?:s|ing|ed|e|es)?"
        r" (?:over|across|along|up|down|on)", "stand"),
    # hung or fixed above something, not on it: "a lamp hanging above the table", "a shelf mounted above the desk"
    Cue(r"(?:hang(?:s|ing)?|hung|dangl(?:e|es|ing)|suspended|mounted|fixed|attached|placed|set|put|installed)"
        r" (?:high |right |just |directly |up )?above", "above"),
    Cue(r"hang(?:s|ing)?|hung|dangl(?:e|es|ing)|suspended", "hang"),
    Cue(r"attached|glued|taped|stuck (?:on|to)|fixed (?:on|to)|fasten(?:s|ed|ing)?|mounted|stapled|clipped"
        r"|pinned (?:to|on)",
        "attach"),
    Cue(r"under(?:neath)?|beneath", "under"),
    Cue(r"below", "below"),
    # in water when the ground holds some (rules), else free in air or water
    Cue(r"(?:float(?:s|ing)?|swim(?:s|ming)?|bob(?:s|bing)?|paddl(?:e|es|ing)) (?:in|inside|within)", "in"),
    Cue(r"(?:float(?:s|ing)?|swim(?:s|ming)?|bob(?:s|bing)?|paddl(?:e|es|ing)) (?:on|upon|atop)", "on"),
    Cue(r"(?:leap|jump|hop|spring|climb|fly|flie|get|com)(?:s|ing|ed)? out of|emerg(?:e|es|ing) from", "beside"),
    Cue(r"above|over(?:head of)?", "above"),  # "over" said of a cloth drapes (rules)
    Cue(r"swim(?:s|ming)?|float(?:s|ing)?|hover(?:s|ing)?|fl(?:y|ies|ying) (?:around|past)", "beside"),  # free in
    # the air or water: no contact
    Cue(r"beside|next[ _]to|alongside|(?:at|by|to) (?:the|its|his|her|their) side(?: of)?|side[ _]of|side by side"
        r"|adjacent to|paired with", "beside"),
    Cue(r"(?:at|on) the (?:edge|rim|brink|lip) of", "on"),  # "a pigeon drinking at the edge of a fountain"
    # Holodeck's "center": "a vase in the middle of the table" is on it (in a container: in it, ``passes``)
    Cue(r"(?:at|in) the (?:very )?(?:middle|center|centre) of", "on"),
    Cue(r"through", "in"),  # penetrates only when a pointed thing goes through a solid
    Cue(r"filled with|full of|contain(?:s|ing)?|holding inside", "in", True),
    Cue(r"stir(?:s|red|ring)?", "in"),  # "a candy cane stirring a mug of hot chocolate": its end in it
    # "a horse drinking from a trough": an animal's muzzle in the water (rules; someone drinking holds the cup)
    Cue(r"(?:drink|sip|lapp?)(?:s|ing|ped|ping)?(?: (?:up )?water)? (?:from|out of)", "in"),
    Cue(r"inside|into|within|in", "in"),
    Cue(r"supporting", "on", True),  # "a table supporting a lamp"
    Cue(r"on[ _]top[ _]of|on top|atop|onto|upon|supported[ _]by|on", "on"),
]


@functools.cache
def _compiled(cue: Cue) -> re.Pattern:
    """A cue's pattern as whole words (compiled once per cue; ``CUES`` may grow, a new relation's wordings)."""
    return re.compile(r"(?<![a-z])(?:" + cue.pattern + r")(?![a-z])")


@dataclass(frozen=True)
class CueMatch:
    cue: Cue
    start: int  # character offsets in the prompt
    end: int
    text: str

    @property
    def relation(self) -> Relation:
        return RELATIONS[self.cue.relation]


def clean(prompt: str) -> str:
    """Lower-case prompt with possessives blanked in place, so offsets stay those of the prompt."""
    return re.sub(r"['\u2019]s(?![a-z])", "  ", prompt.lower())


def find_cue(prompt: str, aside=None, kinds: set[str] | None = None) -> CueMatch | None:
    """The relation cue of a prompt: the first-priority cue found, the earliest if it occurs twice; a cue that
    ``aside(cue)`` says is about something else ("with only its eyes above the water") yields to the next one
    found, and is the answer only when there is no other; so do the cues within it (the "in" of "in front of the
    fireplace"). ``kinds``: only cues of relations of these kinds."""
    text = clean(prompt)
    first = None
    set_aside: list[tuple[int, int]] = []
    for cue in CUES:
        regex = _compiled(cue)
        if kinds is not None and RELATIONS[cue.relation].kind not in kinds:
            continue
        for m in regex.finditer(text):
            found = CueMatch(cue, m.start(), m.end(), m.group(0))
            if any(start <= found.start and found.end <= end for start, end in set_aside):
                continue
            about_other = aside is not None and aside(found)
            if not _adjective(text, found) and not about_other:
                return found
            if about_other:
                set_aside.append((found.start, found.end))
            first = first or found
    return first


_PARTICIPLE = re.compile(r"[a-z]+ing")
_AFTER_ARTICLE = re.compile(r"(?:^|\s)(?:a|an|the)\s+$")
_BEFORE_WORD = re.compile(r"\s+[a-z]")


def _adjective(text: str, cue: CueMatch) -> bool:
    """A bare participle between an article and a noun describes the noun ("a meat hook through a hanging
    ham"), it does not relate the two objects."""
    return (_PARTICIPLE.fullmatch(cue.text) is not None and _AFTER_ARTICLE.search(text[:cue.start]) is not None
            and _BEFORE_WORD.match(text[cue.end:]) is not None)


def source_is_figure(cue: CueMatch, source_at: list[int], target_at: list[int]) -> bool | None:
    """Whether the source plays the figure, from where each object is mentioned around the cue.

    The figure is the mention nearest the cue on its figure side ("a cup on the table": before;
    "wearing a hat": after; "a tree with a star on top": the star, nearer). None when the prompt does
    not tell (a name not mentioned, or one word naming both, like "blender" in "blender jar ... base").
    """
    if cue.cue.figure_after:
        side = sorted([(p, "s") for p in source_at if p >= cue.end] + [(p, "t") for p in target_at if p >= cue.end])
        nearest = side[:1]
    else:
        side = sorted([(p, "s") for p in source_at if p < cue.start] + [(p, "t") for p in target_at if p < cue.start])
        nearest = side[-1:]
    if not nearest:
        return None
    pos = nearest[0][0]
    if pos in source_at and pos in target_at:
        return None
    return nearest[0][1] == "s"


_ARTICLE = re.compile(r"^(?:the|a|an|his|her|its|their|two|both|each)\s+")
_PHRASE_END = re.compile(r"[,.;:!?]|\s(?:with|while|where|so|facing|near|on|in|under|beside|next)\s")


def ground_phrases(prompt: str, cue: CueMatch) -> list[str]:
    """The grounds a cue of two names after it ("between the sofa and the armchair": ["sofa", "armchair"]), the
    articles dropped; one phrase when the prompt names them together ("flanked by two chairs": ["chairs"])."""
    text = clean(prompt)[cue.end:]
    end = _PHRASE_END.search(text)
    phrase = (text[:end.start()] if end else text).strip()
    names = [_ARTICLE.sub("", part.strip()).strip() for part in re.split(r"\s+and\s+|\s*&\s*", phrase)]
    return [name for name in names if name]


def named_grounds(prompt: str, placed: list[str]) -> list[str]:
    """The placed objects a two-ground cue names ("a lamp between the sofa and the armchair", with "sofa" and
    "armchair" placed: both), in the prompt's order: a phrase names the object whose name it is, holds or ends
    with; [] without such a cue, or where a phrase names none of them."""
    cue = find_cue(prompt, kinds={"between"})
    if cue is None or cue.relation.name != "between":
        return []
    found = []
    for phrase in ground_phrases(prompt, cue):
        match = next((name for name in placed if name.lower() == phrase), None) or next(
            (name for name in placed if name.lower() in phrase or phrase.endswith(name.lower().split()[-1])), None)
        if match is None:
            return []
        found.append(match)
    return found if len(set(found)) == len(found) else []


def grounds(prompt: str | None, given: Sequence[str], placed: list[str]) -> list[str]:
    """The placed objects a source relates to: ``given`` where it names two or more; else the two a "between"
    prompt names among ``placed`` (``named_grounds``); else ``given`` (empty: the caller's default)."""
    if len(given) >= 2 or not prompt:
        return list(given)
    named = named_grounds(prompt, placed)
    return named if len(named) >= 2 else list(given)
