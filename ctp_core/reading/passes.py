"""The reading of a prompt: what the rules read of (target name, source name, prompt) before any number.

``read_prompt`` applies ``PASSES`` in order to a ``PromptReading``: the relation cue and a lean's side, each name
resolved in the prompt's context, the cue's relation and who its figure is, the ground (the middle of a container is
in it), the contents it holds, afloat, encased, draped, into an opening, and the reading (``RelationReading``: the
relation with a lean's side and an orientation). Each pass rewrites a part of the reading and says why in its notes.
The numbers (size, penetration, contact) are ``priors.rules``'s.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, field, replace

from ctp_core.reading import context, cues, lexicon, records
from ctp_core.reading.records import Kind, RelationName, Role
from ctp_core.reading.relation import RelationReading

# Cues of cutting that someone does with a tool in hand ("a chef cutting a cake"), not with their own body.
_AGENT_CUTS = re.compile(r"cut|slic|stab|pierc|skewer|spear|impal|carv")
# Cues of moving on water ("floating in", "a duck paddling on"), and of being at a water body's rim instead.
_AFLOAT = re.compile(r"float|swim|bob|paddl")
_AT_EDGE = re.compile(r"edge|rim|brink|lip")
_AMID = re.compile(r"(?:at|in) the (?:very )?(?:middle|center|centre) of")  # Holodeck's "center"
FASTENER_MAX_M = 0.1  # a pointed thing this short that holds or fastens a pierceable solid is a pin through it
# Said of water: under its surface, beneath the waves.
_WATER_SAID = re.compile(r"\b(?:submerged|underwater|(?:under|beneath|below) (?:the )?(?:water|waves|surface))\b")
# On the bottom of something full of contents: under them ("an ornament on the gravel of an aquarium of water").
_ON_BOTTOM = re.compile(r"\b(?:on|along|across) the (?:bottom|floor|gravel|bed|sand|pebbles) of\b")
# Hidden in a mass ("a bird nest hidden in a hedge"), growing in soil, buried in a container's contents.
_HIDDEN = re.compile(r"\b(?:hidden|hiding|hides|nestled|concealed|buried)\b")
_GROWS = re.compile(r"\b(?:growing|grows|grown|planted|rooted|sprouting)\b")
_BURIED = re.compile(r"\b(?:buried|burying|burrow(?:s|ed|ing)?)\b")
# Set solid around the figure: "frozen in a block of ice", "trapped in amber", "encased in resin".
_ENCASED = re.compile(r"\b(?:frozen|trapped|encased|entombed|preserved|fossili[sz]ed|cast)\s+(?:in|inside|within"
                      r"|into)\b")
# Put into a fold or a pocket ("a fortune tucked inside a cookie"), not embedded in the food's mass.
_TUCKED = re.compile(r"\b(?:tucked|tucks|tucking|slipped|slips|slipping)\b")
# Drinking from something: an animal's muzzle goes into the water it holds ("a horse drinking from a trough"),
# someone drinking from a cup holds it.
_DRINKS = re.compile(r"drink|sip|lap")
# Cues of biting or stinging (a mosquito biting an arm): its proboscis or sting goes into the skin.
_BITES = re.compile(r"bit|sting")


@dataclass
class PromptReading:
    """What the rules have read of one prompt (``read_prompt``); each of ``PASSES`` rewrites a part of it, in order.

    ``figure``: the source is the relation's figure (else the target is). ``ground``, ``ground_name`` and
    ``ground_at`` are the ground as ``_ground_named`` names it once the figure is settled (a later swap of the
    roles, ``_ground_under_figure``, leaves them). ``filled``: the contents the figure goes into, if any.
    ``notes``: the reasons for the relation, the roles and the ground, in their order; ``name_notes``: those for
    the name's side and orientation, which a prior's reason puts first after its size note.
    """

    prompt: str
    text: str  # ``cues.clean(prompt)``: lower case, offsets those of the prompt
    target_name: str
    source_name: str
    target: lexicon.Match | None
    source: lexicon.Match | None
    target_at: list[int]  # where the prompt mentions each (``_mentions``)
    source_at: list[int]
    cue: cues.CueMatch | None = None
    leant: RelationName | None = None  # the side of the ground a lean touches
    figure: bool = True
    relation: records.Relation | None = None
    why: str = ""  # the reason for ``relation``
    notes: list[str] = field(default_factory=list)
    drinks: bool = False  # an animal drinking from the ground
    bites: bool = False  # a biting or stinging creature's mouthparts in the ground
    ground_name: str = ""
    ground: lexicon.Match | None = None
    ground_at: list[int] = field(default_factory=list)
    figure_name: str = ""
    filled: str | None = None
    afloat: bool = False
    encased: bool = False
    reading: RelationReading | None = None  # the relation as a run uses it (with a lean's side, an orientation)
    name_notes: list[str] = field(default_factory=list)

    @classmethod
    def start(cls, target_name: str, source_name: str, prompt: str) -> PromptReading:
        """The lexicon's entries for both names and where the prompt mentions each."""
        target, source = lexicon.lookup(target_name), lexicon.lookup(source_name)
        return cls(prompt, cues.clean(prompt), target_name, source_name, target, source,
                   _mentions(prompt, target_name, target), _mentions(prompt, source_name, source))

    def aside(self, c: cues.CueMatch) -> bool:
        """A cue about something other than the two objects."""
        prompt, mentions = self.prompt, self.target_at + self.source_at
        # "... with only its eyes above the water": about a part
        return (c.cue.relation not in {"in", "penetrate"} and context.substance_object(prompt, c.end)
                and not context.names_next(prompt, c.end, mentions)
                or c.text in {"in", "inside"}  # "a candle in a bucket on the table": on the table
                and context.other_container(prompt, c.end, mentions)
                or c.relation.aside  # "... to the left of the plate"
                and context.about_another(prompt, c.end, mentions))

    def reground(self, ground: lexicon.Match) -> None:
        """The ground replaced (by itself with more tags), in its role's object too."""
        self.ground = ground
        self.target, self.source = (ground, self.source) if self.figure else (self.target, ground)


def _find_cue(r: PromptReading) -> None:
    """The relation cue, a lean's side, and who the figure is from where each object is mentioned around the cue
    (the source, where the mentions do not say)."""
    # a position first ("in front of the sofa, facing it": front), an orientation alone ("facing the sofa")
    cue = cues.find_cue(r.prompt, r.aside, records.PLACING) or cues.find_cue(r.prompt, r.aside)
    # "against the back of the sofa", "behind the sofa, against it": a lean, on that side
    r.cue, r.leant = _leaning(r.prompt, cue, r.aside, r.target_at + r.source_at)
    figure = None
    if r.cue is not None:
        figure = cues.source_is_figure(r.cue, r.source_at, r.target_at)
    if figure is None:
        figure = True  # the source is what gets placed: by default it is the figure
    r.figure = figure


def _resolve_objects(r: PromptReading) -> None:
    """Each name resolved in the prompt's context (``context.resolve``); an unknown wearer, holder or sitter is an
    agent."""
    agent_role = r.cue.relation.agent if r.cue else None
    r.target, r.source = (
        context.resolve(r.target_name, r.prompt, r.target_at, r.source,
                        agent_role == (Role.GROUND if r.figure else Role.FIGURE), r.source_name),
        context.resolve(r.source_name, r.prompt, r.source_at, r.target,
                        agent_role == (Role.FIGURE if r.figure else Role.GROUND), r.target_name))


def _relation_of_cue(r: PromptReading) -> None:
    """The cue's relation (``_relation``); a side said with a lean ("behind the sofa, against it") is a lean."""
    r.relation, r.why = _relation(r.cue, r.target, r.source, r.source if r.figure else r.target)
    if r.leant is not None and r.relation.name != "lean":  # "behind the sofa, against it"
        r.relation, r.why = records.RELATIONS[RelationName.LEAN], f"'{r.cue.text}', leaning -> lean"


def _drinker_holds(r: PromptReading) -> None:
    """Drinking from something: an animal's muzzle goes in it; someone drinking from it holds it."""
    r.drinks = r.cue is not None and r.relation.name == "in" and _DRINKS.match(r.cue.text) is not None
    drinker = r.source if r.figure else r.target
    if r.drinks and not (drinker is not None and drinker.entry.domain == "animals"):
        r.figure, r.drinks = not r.figure, False  # "a man drinking from a cup": he holds it
        r.relation, r.why = records.RELATIONS[RelationName.HOLD], f"'{r.cue.text}' said of someone: holding it"


def _fastener_pierces(r: PromptReading) -> None:
    """A short or staked pointed thing that holds a pierceable solid goes through it ("pins holding a pattern on
    the fabric", "a skewer holding a burger together")."""
    holder, held = (r.target, r.source) if r.figure else (r.source, r.target)
    if (r.relation.name == "hold" and holder is not None and holder.has("pointed") and not holder.has("agent")
            and (holder.size_m <= FASTENER_MAX_M or holder.has("staked")) and pierceable(held)):
        r.figure = not r.figure
        r.relation = records.RELATIONS[RelationName.PENETRATE]
        r.why = f"'{r.cue.text}' said of a pointed {holder.phrase}: a fastener in the {held.phrase}"


def _bite_pierces(r: PromptReading) -> None:
    """A biting or stinging creature holding someone or something pierceable: its proboscis or sting in the skin
    ("a mosquito biting a man's arm")."""
    holder, held = (r.target, r.source) if r.figure else (r.source, r.target)
    r.bites = (r.relation.name == "hold" and r.cue is not None and _BITES.match(r.cue.text) is not None
               and holder is not None and holder.has("bites") and (held is None or held.has("agent")
                                                                  or pierceable(held)))
    if r.bites:
        r.figure = not r.figure
        r.relation = records.RELATIONS[RelationName.PENETRATE]
        r.why = f"'{r.cue.text}' said of a {holder.phrase}: its bite or sting pierces the skin"


def _ground_named(r: PromptReading) -> None:
    """The figure settled: which object is the ground, by name, match and mentions."""
    if not r.figure:
        r.notes.append("the source is the ground of the relation")
    r.ground_name, r.ground, r.ground_at = (r.target_name, r.target, r.target_at) if r.figure else (
        r.source_name, r.source, r.source_at)
    r.figure_name = r.source_name if r.figure else r.target_name


def _amid_container(r: PromptReading) -> None:
    """In the middle of a container: in it ("a toy in the middle of the box"; of a table, a rug or a plate: on it)."""
    if (r.relation.name == "on" and r.cue is not None and _AMID.fullmatch(r.cue.text) and r.ground is not None
            and r.ground.has("container") and not r.ground.has("flat")):
        r.relation, r.why = records.RELATIONS[RelationName.IN], f"'{r.cue.text}' a container: in it"


def _tucked_into_fold(r: PromptReading) -> None:
    """Tucked or slipped into a food: into a fold of it, as into a container ("a fortune tucked inside a fortune
    cookie")."""
    ground = r.ground
    if (r.relation.name == "in" and ground is not None and ground.entry.domain == "food and drink"
            and not ground.has("container") and _TUCKED.search(r.text)):
        r.reground(replace(ground, tags=ground.tags | {"container"}))
        r.notes.append(f"tucked into the {r.ground_name}: into a fold of it")


def _contents_held(r: PromptReading) -> None:
    """The contents the ground holds, where the prompt or a name says: by the ground's mention
    (``context.contents``), after an "in" cue, named elsewhere in the prompt ("scooping salsa from"), or in the
    ground's name ("stuck in the compost bin", "a snowbank")."""
    ground, relation = r.ground, r.relation
    filled = context.contents(r.prompt, r.ground_at, ground, r.figure_name)
    if filled is None and r.cue is not None and relation.name in {"in", "penetrate"}:
        filled = context.contents_after(r.prompt, r.cue.end, r.figure_name,
                                        ground is not None and ground.has("container"))
    if filled is None and relation.name == "in" and ground is not None and ground.has("container"):
        filled = context.contents_named(r.prompt, r.target_at + r.source_at, r.figure_name)  # "scooping salsa from"
    if filled is None and (relation.name == "penetrate" and ground is not None and ground.has("container")
                           or relation.name in {"in", "penetrate"} and ground is None):
        filled = context.contents_in_name(r.ground_name, r.figure_name)  # "stuck in the compost bin", "a snowbank"
    r.filled = filled


def _under_contents(r: PromptReading) -> None:
    """On the bottom of a ground full of contents, or under the water it holds: in them ("an ornament on the gravel
    of an aquarium of water")."""
    if (r.filled is not None and (r.relation.supports or r.relation.name == RelationName.UNDER) and r.ground is not None
            and (_ON_BOTTOM.search(r.text) or r.relation.name == "under" and _WATER_SAID.search(r.text))):
        r.relation, r.why = records.RELATIONS[RelationName.IN], r.why + f"; under the {r.filled} it holds"


def _drinking_water(r: PromptReading) -> None:
    """An animal drinking from something that is no creature: from the water it holds (a trough, a bowl)."""
    if r.drinks and r.filled is None and r.ground is not None and not r.ground.has("agent"):
        r.filled = context.contents_in_name(r.ground_name, r.figure_name) or "water"  # a trough, a bowl: its water


def _water_said(r: PromptReading) -> None:
    """Underwater in a container: in the water it holds ("a toy submarine underwater in the bathtub"); beneath the
    water is in it ("a submarine beneath the waves of the sea")."""
    if r.filled is None and r.ground is not None and r.ground.has("container") and _WATER_SAID.search(r.text):
        r.filled = "water"  # "a toy submarine underwater in the bathtub"
        if r.relation.name == "under":  # "a submarine beneath the waves of the sea"
            r.relation, r.why = records.RELATIONS[RelationName.IN], r.why + "; under the water it holds"


def _buried_in_contents(r: PromptReading) -> None:
    """Buried in a container: in its contents ("a plastic dinosaur half buried in the sandpit": in its sand)."""
    if (r.filled is None and r.ground is not None and r.ground.has("container") and r.relation.name == "penetrate"
            and _BURIED.search(r.text)):
        r.filled = "its contents"  # "a plastic dinosaur half buried in the sandpit": in its sand


def _hidden_in_mass(r: PromptReading) -> None:
    """Hidden in something that is no container: inside its mass ("a bird nest hidden in a hedge")."""
    if (r.filled is None and r.ground is not None and r.relation.name == "in" and not r.ground.has("container")
            and _HIDDEN.search(r.text)):
        r.filled = f"the {r.ground.phrase}"  # "a bird nest hidden in a hedge": inside its mass


def _encased_in_solid(r: PromptReading) -> None:
    """Frozen, trapped or encased in a solid: wholly in it ("a fish frozen inside a block of ice")."""
    r.encased = (r.filled is None and r.relation.name == "in" and _ENCASED.search(r.text) is not None
                 and _solid(r.ground))
    if r.encased:
        r.filled = f"the {r.ground.phrase}"  # "a fish frozen inside a block of ice": wholly in the solid


def _rooted_in_soil(r: PromptReading) -> None:
    """Growing or planted in something: rooted in its soil ("daffodils growing in a flower pot", "a cactus planted
    in a pot")."""
    if r.filled is None and r.ground is not None and _GROWS.search(r.text) and (
            r.relation.name == "in" or r.relation.name == "penetrate" and r.ground.has("container")):
        r.filled = "soil"  # "daffodils growing in a flower pot", "a cactus planted in a pot": rooted in its soil


def _afloat_on_water(r: PromptReading) -> None:
    """Afloat: a cue of floating ("floating in", "a duck paddling on"), or resting on a body of water the cue names
    next ("a swan gliding on the lake"; not "a frog on a lily pad in a pond", nor at the edge of a fountain: on its
    rim)."""
    r.afloat = r.cue is not None and _AFLOAT.match(r.cue.text) is not None
    if (not r.afloat and r.filled is not None and r.relation.supports and r.ground is not None
            and r.ground.entry.domain == "buildings and places"  # "a swan gliding on the lake", not "a frog
            and r.cue is not None and context.names_next(r.prompt, r.cue.end, r.ground_at)  # on a lily pad in a pond"
            and not _AT_EDGE.search(r.cue.text)):  # at the edge of a fountain: on its rim
        r.afloat = True
        r.why += "; on a body of water: afloat in it"


def _afloat_in_container(r: PromptReading) -> None:
    """Afloat in a container: in the water it holds ("a bath thermometer floating in the baby bath": nothing floats
    in an empty one)."""
    if r.afloat and r.filled is None and r.relation.name == "in" and r.ground is not None and r.ground.has("container"):
        r.filled = "water"  # "a bath thermometer floating in the baby bath": nothing floats in an empty one
        r.why += "; afloat in a container: in the water it holds"


def _afloat_in_air(r: PromptReading) -> None:
    """Afloat in nothing that holds water (in air, in open water): beside it, no contact."""
    if r.afloat and r.filled is None:
        r.relation, r.why = records.RELATIONS[RelationName.BESIDE], f"'{r.cue.text}' in air or open water: no contact"


def _draped_over(r: PromptReading) -> None:
    """A cloth or a cover "over" the ground: draped over it, lying on it."""
    fig_match = r.source if r.figure else r.target
    if (r.relation.name == "above" and r.cue is not None and r.cue.text == "over" and fig_match is not None
            and (fig_match.has("soft") or fig_match.has("wrap"))):
        r.relation, r.why = records.RELATIONS[RelationName.LIE], "'over' said of a cloth or a cover: draped over"


def _into_opening(r: PromptReading) -> None:
    """Into an opening the prompt names after the cue ("in the slot of a toaster"): the ground holds things."""
    opening = context.opening_after(r.prompt, r.cue.end) if r.cue is not None else None
    if opening is not None and r.ground is not None and not r.ground.has("container"):
        r.reground(replace(r.ground, tags=r.ground.tags | {"container"}))  # "in the slot of a toaster"
        r.notes.append(f"into the {opening} of the {r.ground_name}")


def _relation_noted(r: PromptReading) -> None:
    """The relation read, and why, leads the notes."""
    r.notes.insert(0, r.why)


def _ground_under_figure(r: PromptReading) -> None:
    """The target under the source: the target rests on the source ("a table under a cup": the cup is on the
    table)."""
    if r.relation.name == "under" and not r.figure:  # "a table under a cup": the cup is on the table
        r.relation, r.figure = records.RELATIONS[RelationName.ON], True
        r.notes.append("read as the target resting on the source")


def _named(r: PromptReading) -> None:
    """The reading: the relation, with a lean's side and with an orientation said about the same ground ("in front
    of the sofa, facing it": both judged)."""
    turn = _orientation(r.prompt, r.cue, r.relation, r.aside, r.ground_at, r.source_at if r.figure else r.target_at)
    if turn is not None:  # "in front of the sofa, facing it": both judged
        r.name_notes.append(f"'{turn.text}' -> {turn.cue.relation} too")
    more = [r for r in (r.leant, turn.cue.relation if turn else None) if r is not None]
    r.reading = RelationReading.of(r.relation.name, *more, role=Role.FIGURE if r.figure else Role.GROUND)


def _side_noted(r: PromptReading) -> None:
    """The side of the ground the reading puts the figure on, leading the name's notes."""
    side = r.reading.side if r.reading is not None else None
    if side is not None:
        r.name_notes.insert(0, f"on the {r.ground_name}'s {side} side (its own front, else the viewer's)")


# The rewrites of a reading, in the order ``read_prompt`` applies them: each reads what those before it settled (the
# cue, then the relation and who the figure is, then the ground and its contents, then the name).
PASSES: tuple[Callable[[PromptReading], None], ...] = (
    _find_cue, _resolve_objects, _relation_of_cue, _drinker_holds, _fastener_pierces, _bite_pierces, _ground_named,
    _amid_container, _tucked_into_fold, _contents_held, _under_contents, _drinking_water, _water_said,
    _buried_in_contents, _hidden_in_mass, _encased_in_solid, _rooted_in_soil, _afloat_on_water, _afloat_in_container,
    _afloat_in_air, _draped_over, _into_opening, _relation_noted, _ground_under_figure, _named, _side_noted,
)


def read_prompt(target_name: str, source_name: str, prompt: str) -> PromptReading:
    """The reading of a prompt about two named objects: ``PromptReading.start``, rewritten by each of ``PASSES``."""
    reading = PromptReading.start(target_name, source_name, prompt)
    for rewrite in PASSES:
        rewrite(reading)
    return reading


def _mentions(prompt: str, name: str, match: lexicon.Match | None) -> list[int]:
    """Character offsets in the prompt where the named object is mentioned.

    The name's head (its lexicon phrase, a synonym of it, or its part word) is preferred; any other
    word of the name ("blender" in "blender_tank") counts only when the head is not mentioned.
    """
    words = context.prompt_words(prompt)
    offsets, tokens = [start for start, _ in words], [word for _, word in words]
    name_words = [w for w in lexicon.words(name) if w not in lexicon.SIZE_WORDS]
    if not name_words:
        return []
    head_forms = set(lexicon.singulars(match.phrase.split()[-1] if match else name_words[-1]))
    heads = [offsets[i] for i, t in enumerate(tokens) if head_forms & set(lexicon.singulars(t))]
    if match is not None and lexicon.LEXICON.get(match.phrase) is match.entry:  # a synonym: "broomstick", "broom"
        heads += [offsets[s] for s, _, _, entry in lexicon.spans(tokens) if entry is match.entry]
    if heads:
        return sorted(set(heads))
    forms = lexicon.forms(name_words)
    return [offsets[i] for i, t in enumerate(tokens) if forms & set(lexicon.singulars(t))]


def _orientation(prompt: str, cue: cues.CueMatch | None, relation: records.Relation, aside,
                 ground_at: list[int], figure_at: list[int]) -> cues.CueMatch | None:
    """An orientation said after a position about the same ground ("in front of the desk, facing it", "next to the
    sofa, facing the sofa"); None where there is none, it is about something else ("facing the window"), or it is
    said before the figure is named: the viewer's (Sr3D's "facing the bed from the side you sit on it, choose the
    pillow on its left")."""
    if cue is None or relation.kind == Kind.ORIENTATION:
        return None
    turn = cues.find_cue(prompt, aside, {Kind.ORIENTATION})
    if turn is None or turn.start < cue.end and cue.start < turn.end:
        return None
    if figure_at and min(figure_at) > turn.start:  # the viewer's: "facing the bed ..., choose the pillow on its left"
        return None
    return turn if not context.about_another(prompt, turn.end, ground_at) else None


# the side a lean's ground is touched on, named after the lean: "against the back of", "on the left-hand end of"
_LEANT_ON = re.compile(r"\s+(?:the |its |his |her |their )?(front|back|rear|left|right)(?:[- ]hand)?(?: side| end)?"
                       r" of(?![a-z])")
_SIDE_WORD = {"front": RelationName.FRONT, "back": RelationName.BEHIND, "rear": RelationName.BEHIND,
              "left": RelationName.LEFT, "right": RelationName.RIGHT}


def _leaning(prompt: str, cue: cues.CueMatch | None, aside, mention_at: list[int]
             ) -> tuple[cues.CueMatch | None, RelationName | None]:
    """The cue to read and the side of the ground a lean touches, where the prompt names one: after the lean
    ("against the back of the sofa", "leaning on the front of the car": ``front``, ``behind``, ``left``, ``right``;
    "the side of" names none), or as a side with a lean about the same ground ("behind the sofa, against it",
    "leaning against the left side of the amp"; the earlier of the two cues says who the figure is). ``(cue,
    None)`` otherwise."""
    if cue is None or cue.cue.relation == "lean":
        said = cue and _LEANT_ON.match(cues.clean(prompt), cue.end)
        return cue, _SIDE_WORD[said.group(1)] if said else None
    if cue.relation.kind != Kind.SIDE:
        return cue, None
    lean = cues.find_cue(prompt, aside, {Kind.CONTACT})
    if lean is None or lean.cue.relation != "lean" or lean.start < cue.end and cue.start < lean.end:
        return cue, None
    said_of_side = lean.end <= cue.start and _BEFORE_SIDE.fullmatch(cues.clean(prompt)[lean.end:cue.start])
    if not said_of_side and context.about_another(prompt, lean.end, mention_at):  # "... leaning on the wall"
        return cue, None
    return min(cue, lean, key=lambda c: c.start), cue.cue.relation


_BEFORE_SIDE = re.compile(r"\s*(?:the |its |his |her |their )?")  # "against the [left side of]": one phrase


def _relation(cue, target, source, figure) -> tuple[records.Relation, str]:
    """The cue's relation; only agents ride or sit ("a ball riding down a slide" rests on it), and
    agents cut with tools, not themselves ("a chef cutting a cake" handles it; "a worm poking out of an apple"
    is in it)."""
    if cue is not None:
        rel = records.RELATIONS[cue.cue.relation]
        if rel.name == "sit" and figure is not None and not figure.has("agent"):
            return records.RELATIONS[RelationName.ON], f"'{cue.text}' said of an object: resting on"
        if (rel.name == "penetrate" and figure is not None and figure.has("agent")
                and _AGENT_CUTS.match(cue.text)):  # "a chef cutting a cake"
            return records.RELATIONS[RelationName.HOLD], f"'{cue.text}' said of someone: handling it, with a tool"
        if rel.name == "wear" and figure is not None and figure.has("agent"):  # "a bird on a giraffe's head"
            return records.RELATIONS[RelationName.STAND], f"'{cue.text}' said of a creature: standing on it"
        return rel, f"'{cue.text}' -> {rel.name}"
    if source is not None and lexicon.bare_part(source.phrase) is not None:
        return records.RELATIONS[RelationName.ON], "no relation cue; a detachable part: assumed seated on its owner"
    if target is not None and target.has("container") and (source is None or source.size_m <= target.size_m):
        return records.RELATIONS[RelationName.IN], "no relation cue; the target holds things: assumed inside"
    return records.RELATIONS[RelationName.ON], "no relation cue: assumed resting on"


def _solid(ground) -> bool:
    """A mass a thing can be set in (ice, amber, rock, a cake): no container, creature, sheet, cloth or net, tree or
    bush."""
    return ground is not None and not ground.tags & {"container", "agent", "flat", "soft"} and (
        ground.entry.domain != "plants" or ground.has("pierceable"))


def pierceable(ground) -> bool:
    """Solids a pointed thing goes into: tagged ``pierceable`` (wood, soil, foam, a dartboard), solid food,
    plants and soft things; never a container (it has an opening), a person or an animal."""
    return ground is not None and not ground.has("container") and not ground.has("agent") and (
        ground.has("pierceable") or ground.has("soft") or ground.entry.domain in {"food and drink", "plants"})

