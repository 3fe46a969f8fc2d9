"""The deterministic scene-prior provider: the lexicon for sizes, the prompt's cue for the relation.

No network, no model, the same answer every time; the default provider and the fallback of the
language-model one. Every value says where it came from in ``reason``, and anything guessed for lack
of knowledge says "fallback".
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, field, replace

from ctp_core.priors.prior import ScenePrior, clamp_contact, clamp_size
from ctp_core.reading import context, lexicon
from ctp_core.reading.context import PERSON_M  # an unknown name that holds, wears or rides is someone this tall
from ctp_core.relations import vocabulary

STICKS_OUT = 2.5  # ... and a long thing or a plant that sticks out of it is at most this size of it
# An unknown figure on or in a known ground is an object someone handles: its size is the relation's typical share
# of the ground's, but at most this ("an acorn buried in the lawn" is no 4 m acorn).
UNKNOWN_FIGURE_MAX_M = 1.0
FITS_INSIDE = 0.9  # what is inside a container (not a long thing or a plant sticking out) is at most this size of it
# Relations where a ball touches at a point, a sheet lies on a face, a soft thing settles.
_SUPPORT = {"on", "stand", "sit", "lie", "lean", "hang", "attach"}
# Cues of a blade or a bit that passes through a wall, even a container's (a knife slicing a cardboard box).
_CUTS = re.compile(r"(?:cut|slic|saw|carv|chop|stab|pierc|drill|bor|punctur)\w*(?:ing|s)\b")  # no "carved"
# Cues of cutting that someone does with a tool in hand ("a chef cutting a cake"), not with their own body.
_AGENT_CUTS = re.compile(r"cut|slic|stab|pierc|skewer|spear|impal|carv")
# Cues of moving on water ("floating in", "a duck paddling on"), and of being at a water body's rim instead.
_AFLOAT = re.compile(r"float|swim|bob|paddl")
_AT_EDGE = re.compile(r"edge|rim|brink|lip")
# Short fasteners driven in (a nail, a screw, a tent peg) are mostly inside what holds them.
_DRIVEN = re.compile(r"hammer|driv|screw|nail|tapp|pound")
DRIVEN_MAX_M = 0.25
DRIVEN_CONTACT = 0.6
FASTENER_MAX_M = 0.1  # a pointed thing this short that holds or fastens a pierceable solid is a pin through it
# Someone standing in contents or in a place touches them with the feet (a horse in its stable, a heron wading).
_ON_FEET = re.compile(r"\b(?:standing|stands|wading|wades|walking|walks|grazing)\b")
ON_FEET_CONTACT = 0.02  # on a floor
WADING_CONTACT = 0.1  # in contents: the legs
# Immersion: words that put the whole figure below the contents' surface, and words that put only part of it
# there; without either, a figure at most SUNK_MAX the size of its ground that is no agent, plant, soft or
# pointed thing and does not float sinks whole into a liquid (pickles in brine, a coin in a fountain), not into a
# paste, a foam or a soil (strawberries in whipped cream).
_WHOLLY_UNDER = re.compile(r"\b(?:submerged|underwater|under (?:the )?water|at the bottom|sunk|buried"
                           r"|on the (?:bottom|floor|gravel|bed) of"
                           r"|sinking|sank|dropped)\b")
_WATER_SAID = re.compile(r"\b(?:submerged|underwater|(?:under|beneath|below) (?:the )?(?:water|waves|surface))\b")
# On the bottom of something full of contents: under them ("an ornament on the gravel of an aquarium of water").
_ON_BOTTOM = re.compile(r"\b(?:on|along|across) the (?:bottom|floor|gravel|bed|sand|pebbles) of\b")
# Screwed into something no point goes into (an engine, a lamp): into its threaded hole.
_SCREWED = re.compile(r"screw|bolt")
_HIDDEN = re.compile(r"\b(?:hidden|hiding|hides|nestled|concealed|buried)\b")
_GROWS = re.compile(r"\b(?:growing|grows|grown|planted|rooted|sprouting)\b")
_BURIED = re.compile(r"\b(?:buried|burying|burrow(?:s|ed|ing)?)\b")
# Set solid around the figure: "frozen in a block of ice", "trapped in amber", "encased in resin".
_ENCASED = re.compile(r"\b(?:frozen|trapped|encased|entombed|preserved|fossili[sz]ed|cast)\s+(?:in|inside|within"
                      r"|into)\b")
# Put onto a pointed thing through its body: bait on a hook, beads on a needle.
_THREADED = re.compile(r"\b(?:thread(?:s|ed|ing)?|impaled|hooked)\b")
# On the sharp parts of something ("on the spines of a hedgehog", "on the prongs of a fork"): impaled on them.
_ON_POINTS = re.compile(r"\b(?:on|onto|upon) (?:the |its |his |her |their |a )?(?:[a-z]+ )?(spines?|spikes?|thorns?"
                        r"|prongs?|tines?|quills?|barbs?|needles?)\b")
# Put into a fold or a pocket ("a fortune tucked inside a cookie"), not embedded in the food's mass.
_TUCKED = re.compile(r"\b(?:tucked|tucks|tucking|slipped|slips|slipping)\b")
# Drinking from something: an animal's muzzle goes into the water it holds ("a horse drinking from a trough"),
# someone drinking from a cup holds it.
# Standing up in a container: what stands in it sticks out of it, like a long thing ("scissors standing in a cup").
_UPRIGHT = re.compile(r"\b(?:standing|stands|stood|stand)(?: up| upright)? $")
_DRINKS = re.compile(r"drink|sip|lap")
DRINKING_CONTACT = 0.02  # also what a biting or stinging insect touches its victim with
_BITES = re.compile(r"bit|sting")
_PARTLY_UNDER = re.compile(r"\b(?:dip|dipped|dipping|dunk|dunked|dunking|half|partly|partially)\b")
SUNK_MAX = 0.5
IMMERSED_CONTACT = {"whole": 0.9, "part": 0.4, "pointed": 0.3}  # "pointed" also for anything stuck in them
# What a figure or a doll carries or wears, whatever the prompt's relation ("with a katana strapped to his back").
_GEAR = {"clothing and accessories", "tools, weapons and equipment"}
# Relations whose ground must be an agent (the wearer, the holder, the rider).
_AGENT_GROUND = {"wear", "hold"}


class RulesProvider:
    """Lexicon sizes + prompt relation cues; see ``lexicon`` and ``relations`` for the tables."""

    name = "rules"

    def estimate(self, target_name: str, source_name: str, prompt: str) -> ScenePrior:
        """The prior of a prompt: the reading of ``_Reading.start``, rewritten by each of ``_PASSES`` in order."""
        reading = _Reading.start(target_name, source_name, prompt)
        for rewrite in _PASSES:
            rewrite(reading)
        return ScenePrior(size_ratio=clamp_size(reading.size), penetration=reading.penetration,
                          contact_ratio=clamp_contact(reading.contact), provider=self.name,
                          reason="; ".join(n for n in reading.notes if n), relation=reading.name,
                          source_is_figure=reading.figure)


@dataclass
class _Reading:
    """What the rules have read of one prompt so far; each of ``_PASSES`` rewrites a part of it, in order.

    ``figure``: the source is the relation's figure (else the target is). ``ground``, ``ground_name`` and
    ``ground_at`` are the ground as ``_ground_named`` names it once the figure is settled (a later swap of the
    roles, ``_ground_under_figure``, leaves them). ``filled``: the contents the figure goes into, if any.
    ``notes``: the reasons the prior reports, in their order.
    """

    prompt: str
    text: str  # ``vocabulary.clean(prompt)``: lower case, offsets those of the prompt
    target_name: str
    source_name: str
    target: lexicon.Match | None
    source: lexicon.Match | None
    target_at: list[int]  # where the prompt mentions each (``_mentions``)
    source_at: list[int]
    cue: vocabulary.CueMatch | None = None
    leant: str | None = None  # the side of the ground a lean touches
    figure: bool = True
    relation: vocabulary.Relation | None = None
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
    size: float = 1.0
    penetration: bool = False
    contact: float = 0.0
    name: str = ""  # the reading's relation name (with a lean's side, an orientation)

    @classmethod
    def start(cls, target_name: str, source_name: str, prompt: str) -> _Reading:
        """The lexicon's entries for both names and where the prompt mentions each."""
        target, source = lexicon.lookup(target_name), lexicon.lookup(source_name)
        return cls(prompt, vocabulary.clean(prompt), target_name, source_name, target, source,
                   _mentions(prompt, target_name, target), _mentions(prompt, source_name, source))

    def aside(self, c: vocabulary.CueMatch) -> bool:
        """A cue about something other than the two objects."""
        prompt, mentions = self.prompt, self.target_at + self.source_at
        # "... with only its eyes above the water": about a part
        return (c.cue.relation not in {"in", "penetrate"} and context.substance_object(prompt, c.end)
                and not context.names_next(prompt, c.end, mentions)
                or c.text in {"in", "inside"}  # "a candle in a bucket on the table": on the table
                and context.other_container(prompt, c.end, mentions)
                or vocabulary.RELATIONS[c.cue.relation].kind != "contact"  # "... to the left of the plate"
                and context.about_another(prompt, c.end, mentions))

    def reground(self, ground: lexicon.Match) -> None:
        """The ground replaced (by itself with more tags), in its role's object too."""
        self.ground = ground
        self.target, self.source = (ground, self.source) if self.figure else (self.target, ground)


def _find_cue(r: _Reading) -> None:
    """The relation cue, a lean's side, and who the figure is from where each object is mentioned around the cue
    (the source, where the mentions do not say)."""
    # a position first ("in front of the sofa, facing it": front), an orientation alone ("facing the sofa")
    cue = vocabulary.find_cue(r.prompt, r.aside, vocabulary.PLACING) or vocabulary.find_cue(r.prompt, r.aside)
    # "against the back of the sofa", "behind the sofa, against it": a lean, on that side
    r.cue, r.leant = _leaning(r.prompt, cue, r.aside, r.target_at + r.source_at)
    figure = None
    if r.cue is not None:
        figure = vocabulary.source_is_figure(r.cue, r.source_at, r.target_at)
    if figure is None:
        figure = True  # the source is what gets placed: by default it is the figure
    r.figure = figure


def _resolve_objects(r: _Reading) -> None:
    """Each name resolved in the prompt's context (``context.resolve``); an unknown wearer, holder or sitter is an
    agent."""
    agent_role = {"wear": "ground", "hold": "ground", "sit": "figure"}.get(r.cue.cue.relation if r.cue else "")
    r.target, r.source = (
        context.resolve(r.target_name, r.prompt, r.target_at, r.source,
                        agent_role == ("ground" if r.figure else "figure"), r.source_name),
        context.resolve(r.source_name, r.prompt, r.source_at, r.target,
                        agent_role == ("figure" if r.figure else "ground"), r.target_name))


def _relation_of_cue(r: _Reading) -> None:
    """The cue's relation (``_relation``); a side said with a lean ("behind the sofa, against it") is a lean."""
    r.relation, r.why = _relation(r.cue, r.target, r.source, r.source if r.figure else r.target)
    if r.leant is not None and r.relation.name != "lean":  # "behind the sofa, against it"
        r.relation, r.why = vocabulary.RELATIONS["lean"], f"'{r.cue.text}', leaning -> lean"


def _drinker_holds(r: _Reading) -> None:
    """Drinking from something: an animal's muzzle goes in it; someone drinking from it holds it."""
    r.drinks = r.cue is not None and r.relation.name == "in" and _DRINKS.match(r.cue.text) is not None
    drinker = r.source if r.figure else r.target
    if r.drinks and not (drinker is not None and drinker.entry.domain == "animals"):
        r.figure, r.drinks = not r.figure, False  # "a man drinking from a cup": he holds it
        r.relation, r.why = vocabulary.RELATIONS["hold"], f"'{r.cue.text}' said of someone: holding it"


def _fastener_pierces(r: _Reading) -> None:
    """A short or staked pointed thing that holds a pierceable solid goes through it ("pins holding a pattern on
    the fabric", "a skewer holding a burger together")."""
    holder, held = (r.target, r.source) if r.figure else (r.source, r.target)
    if (r.relation.name == "hold" and holder is not None and holder.has("pointed") and not holder.has("agent")
            and (holder.size_m <= FASTENER_MAX_M or holder.has("staked")) and _pierceable(held)):
        r.figure = not r.figure
        r.relation = vocabulary.RELATIONS["penetrate"]
        r.why = f"'{r.cue.text}' said of a pointed {holder.phrase}: a fastener in the {held.phrase}"


def _bite_pierces(r: _Reading) -> None:
    """A biting or stinging creature holding someone or something pierceable: its proboscis or sting in the skin
    ("a mosquito biting a man's arm")."""
    holder, held = (r.target, r.source) if r.figure else (r.source, r.target)
    r.bites = (r.relation.name == "hold" and r.cue is not None and _BITES.match(r.cue.text) is not None
               and holder is not None and holder.has("bites") and (held is None or held.has("agent")
                                                                  or _pierceable(held)))
    if r.bites:
        r.figure = not r.figure
        r.relation = vocabulary.RELATIONS["penetrate"]
        r.why = f"'{r.cue.text}' said of a {holder.phrase}: its bite or sting pierces the skin"


def _ground_named(r: _Reading) -> None:
    """The figure settled: which object is the ground, by name, match and mentions."""
    if not r.figure:
        r.notes.append("the source is the ground of the relation")
    r.ground_name, r.ground, r.ground_at = (r.target_name, r.target, r.target_at) if r.figure else (
        r.source_name, r.source, r.source_at)
    r.figure_name = r.source_name if r.figure else r.target_name


def _tucked_into_fold(r: _Reading) -> None:
    """Tucked or slipped into a food: into a fold of it, as into a container ("a fortune tucked inside a fortune
    cookie")."""
    ground = r.ground
    if (r.relation.name == "in" and ground is not None and ground.entry.domain == "food and drink"
            and not ground.has("container") and _TUCKED.search(r.text)):
        r.reground(replace(ground, tags=ground.tags | {"container"}))
        r.notes.append(f"tucked into the {r.ground_name}: into a fold of it")


def _contents_held(r: _Reading) -> None:
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


def _under_contents(r: _Reading) -> None:
    """On the bottom of a ground full of contents, or under the water it holds: in them ("an ornament on the gravel
    of an aquarium of water")."""
    if (r.filled is not None and r.relation.name in _SUPPORT | {"under"} and r.ground is not None
            and (_ON_BOTTOM.search(r.text) or r.relation.name == "under" and _WATER_SAID.search(r.text))):
        r.relation, r.why = vocabulary.RELATIONS["in"], r.why + f"; under the {r.filled} it holds"


def _drinking_water(r: _Reading) -> None:
    """An animal drinking from something that is no creature: from the water it holds (a trough, a bowl)."""
    if r.drinks and r.filled is None and r.ground is not None and not r.ground.has("agent"):
        r.filled = context.contents_in_name(r.ground_name, r.figure_name) or "water"  # a trough, a bowl: its water


def _water_said(r: _Reading) -> None:
    """Underwater in a container: in the water it holds ("a toy submarine underwater in the bathtub"); beneath the
    water is in it ("a submarine beneath the waves of the sea")."""
    if r.filled is None and r.ground is not None and r.ground.has("container") and _WATER_SAID.search(r.text):
        r.filled = "water"  # "a toy submarine underwater in the bathtub"
        if r.relation.name == "under":  # "a submarine beneath the waves of the sea"
            r.relation, r.why = vocabulary.RELATIONS["in"], r.why + "; under the water it holds"


def _buried_in_contents(r: _Reading) -> None:
    """Buried in a container: in its contents ("a plastic dinosaur half buried in the sandpit": in its sand)."""
    if (r.filled is None and r.ground is not None and r.ground.has("container") and r.relation.name == "penetrate"
            and _BURIED.search(r.text)):
        r.filled = "its contents"  # "a plastic dinosaur half buried in the sandpit": in its sand


def _hidden_in_mass(r: _Reading) -> None:
    """Hidden in something that is no container: inside its mass ("a bird nest hidden in a hedge")."""
    if (r.filled is None and r.ground is not None and r.relation.name == "in" and not r.ground.has("container")
            and _HIDDEN.search(r.text)):
        r.filled = f"the {r.ground.phrase}"  # "a bird nest hidden in a hedge": inside its mass


def _encased_in_solid(r: _Reading) -> None:
    """Frozen, trapped or encased in a solid: wholly in it ("a fish frozen inside a block of ice")."""
    r.encased = (r.filled is None and r.relation.name == "in" and _ENCASED.search(r.text) is not None
                 and _solid(r.ground))
    if r.encased:
        r.filled = f"the {r.ground.phrase}"  # "a fish frozen inside a block of ice": wholly in the solid


def _rooted_in_soil(r: _Reading) -> None:
    """Growing or planted in something: rooted in its soil ("daffodils growing in a flower pot", "a cactus planted
    in a pot")."""
    if r.filled is None and r.ground is not None and _GROWS.search(r.text) and (
            r.relation.name == "in" or r.relation.name == "penetrate" and r.ground.has("container")):
        r.filled = "soil"  # "daffodils growing in a flower pot", "a cactus planted in a pot": rooted in its soil


def _afloat_on_water(r: _Reading) -> None:
    """Afloat: a cue of floating ("floating in", "a duck paddling on"), or resting on a body of water the cue names
    next ("a swan gliding on the lake"; not "a frog on a lily pad in a pond", nor at the edge of a fountain: on its
    rim)."""
    r.afloat = r.cue is not None and _AFLOAT.match(r.cue.text) is not None
    if (not r.afloat and r.filled is not None and r.relation.name in _SUPPORT and r.ground is not None
            and r.ground.entry.domain == "buildings and places"  # "a swan gliding on the lake", not "a frog
            and r.cue is not None and context.names_next(r.prompt, r.cue.end, r.ground_at)  # on a lily pad in a pond"
            and not _AT_EDGE.search(r.cue.text)):  # at the edge of a fountain: on its rim
        r.afloat = True
        r.why += "; on a body of water: afloat in it"


def _afloat_in_container(r: _Reading) -> None:
    """Afloat in a container: in the water it holds ("a bath thermometer floating in the baby bath": nothing floats
    in an empty one)."""
    if r.afloat and r.filled is None and r.relation.name == "in" and r.ground is not None and r.ground.has("container"):
        r.filled = "water"  # "a bath thermometer floating in the baby bath": nothing floats in an empty one
        r.why += "; afloat in a container: in the water it holds"


def _afloat_in_air(r: _Reading) -> None:
    """Afloat in nothing that holds water (in air, in open water): beside it, no contact."""
    if r.afloat and r.filled is None:
        r.relation, r.why = vocabulary.RELATIONS["beside"], f"'{r.cue.text}' in air or open water: no contact"


def _draped_over(r: _Reading) -> None:
    """A cloth or a cover "over" the ground: draped over it, lying on it."""
    fig_match = r.source if r.figure else r.target
    if (r.relation.name == "above" and r.cue is not None and r.cue.text == "over" and fig_match is not None
            and (fig_match.has("soft") or fig_match.has("wrap"))):
        r.relation, r.why = vocabulary.RELATIONS["lie"], "'over' said of a cloth or a cover: draped over"


def _into_opening(r: _Reading) -> None:
    """Into an opening the prompt names after the cue ("in the slot of a toaster"): the ground holds things."""
    opening = context.opening_after(r.prompt, r.cue.end) if r.cue is not None else None
    if opening is not None and r.ground is not None and not r.ground.has("container"):
        r.reground(replace(r.ground, tags=r.ground.tags | {"container"}))  # "in the slot of a toaster"
        r.notes.append(f"into the {opening} of the {r.ground_name}")


def _relation_noted(r: _Reading) -> None:
    """The relation read, and why, leads the notes."""
    r.notes.insert(0, r.why)


def _ground_under_figure(r: _Reading) -> None:
    """The target under the source: the target rests on the source ("a table under a cup": the cup is on the
    table)."""
    if r.relation.name == "under" and not r.figure:  # "a table under a cup": the cup is on the table
        r.relation, r.figure = vocabulary.RELATIONS["on"], True
        r.notes.append("read as the target resting on the source")


def _sized(r: _Reading) -> None:
    """The size ratio (``_size_ratio``); a drinker is sized at the rim, as on it, not in it; what stands upright in
    a container may stick out of it."""
    upright = r.cue is not None and _UPRIGHT.search(r.text[:r.cue.start]) is not None
    r.size, size_why = _size_ratio(r.target_name, r.source_name, r.target, r.source,  # a drinker is at the rim
                                   vocabulary.RELATIONS["on"] if r.drinks else r.relation, r.figure, upright)
    r.notes.insert(0, size_why)


def _penetrates(r: _Reading) -> None:
    """Whether the figure goes into the ground (``_penetration``)."""
    floating = r.afloat and r.filled is not None
    r.penetration, pen_why = _penetration(r.relation, r.figure, r.target, r.source, r.filled, floating,
                                          r.cue.text if r.cue is not None else "", r.text, r.ground_name)
    r.notes.append(pen_why)


def _touches(r: _Reading) -> None:
    """The contact ratio (``_contact``): a short fastener driven in is mostly inside what holds it; a drinking
    animal's muzzle or a biting insect's mouthparts touch little; a creature or a vehicle standing in a place
    touches its floor with feet or tyres."""
    ground, source = r.ground, r.source
    immersed = ground.phrase if r.filled == "its contents" and ground is not None else r.filled
    immersed = immersed if r.penetration else None
    driven = (r.penetration and r.relation.name == "penetrate" and r.cue is not None and _DRIVEN.match(r.cue.text)
              and source is not None and source.has("pointed") and source.size_m <= DRIVEN_MAX_M)
    in_place = ground is not None and r.size <= SUNK_MAX and (
        ground.entry.domain == "buildings and places" or _ON_FEET.search(r.text) is not None)
    r.contact = DRIVEN_CONTACT if driven and r.figure else _contact(r.relation, r.figure, source, immersed, r.afloat,
                                                                    r.text, r.size, in_place, r.encased)
    if r.drinks and r.penetration or r.bites:
        r.contact = DRINKING_CONTACT  # its muzzle, its proboscis or sting


def _named(r: _Reading) -> None:
    """The reading's name: the relation, joined with a lean's side and with an orientation said about the same
    ground ("in front of the sofa, facing it": both judged)."""
    r.name = r.relation.name if r.leant is None else vocabulary.JOIN.join((r.relation.name, r.leant))
    turn = _orientation(r.prompt, r.cue, r.relation, r.aside, r.ground_at)
    if turn is not None:  # "in front of the sofa, facing it": both judged
        r.name += vocabulary.JOIN + turn.cue.relation
        r.notes.insert(1, f"'{turn.text}' -> {turn.cue.relation} too")


def _side_noted(r: _Reading) -> None:
    """The side of the ground the name puts the figure on, in the notes."""
    side = vocabulary.side_of(r.name)
    if side is not None:
        r.notes.insert(1, f"on the {r.ground_name}'s {side} side (its own front, else the viewer's)")


# The rewrites of a reading, in the order ``RulesProvider.estimate`` applies them: each reads what those before it
# settled (the cue, then the relation and who the figure is, then the ground and its contents, then the numbers).
_PASSES: tuple[Callable[[_Reading], None], ...] = (
    _find_cue, _resolve_objects, _relation_of_cue, _drinker_holds, _fastener_pierces, _bite_pierces, _ground_named,
    _tucked_into_fold, _contents_held, _under_contents, _drinking_water, _water_said, _buried_in_contents,
    _hidden_in_mass, _encased_in_solid, _rooted_in_soil, _afloat_on_water, _afloat_in_container, _afloat_in_air,
    _draped_over, _into_opening, _relation_noted, _ground_under_figure, _sized, _penetrates, _touches, _named,
    _side_noted,
)


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


def _orientation(prompt: str, cue: vocabulary.CueMatch | None, relation: vocabulary.Relation, aside,
                 ground_at: list[int]) -> vocabulary.CueMatch | None:
    """An orientation said after a position about the same ground ("in front of the desk, facing it", "next to the
    sofa, facing the sofa"); None where there is none, or it is about something else ("facing the window")."""
    if cue is None or relation.kind == "orientation":
        return None
    turn = vocabulary.find_cue(prompt, aside, {"orientation"})
    if turn is None or turn.start < cue.end and cue.start < turn.end:
        return None
    return turn if not context.about_another(prompt, turn.end, ground_at) else None


# the side a lean's ground is touched on, named after the lean: "against the back of", "on the left-hand end of"
_LEANT_ON = re.compile(r"\s+(?:the |its |his |her |their )?(front|back|rear|left|right)(?:[- ]hand)?(?: side| end)?"
                       r" of(?![a-z])")
_SIDE_WORD = {"front": "front", "back": "behind", "rear": "behind", "left": "left", "right": "right"}


def _leaning(prompt: str, cue: vocabulary.CueMatch | None, aside, mention_at: list[int]
             ) -> tuple[vocabulary.CueMatch | None, str | None]:
    """The cue to read and the side of the ground a lean touches, where the prompt names one: after the lean
    ("against the back of the sofa", "leaning on the front of the car": ``front``, ``behind``, ``left``, ``right``;
    "the side of" names none), or as a side with a lean about the same ground ("behind the sofa, against it",
    "leaning against the left side of the amp"; the earlier of the two cues says who the figure is). ``(cue,
    None)`` otherwise."""
    if cue is None or cue.cue.relation == "lean":
        said = cue and _LEANT_ON.match(vocabulary.clean(prompt), cue.end)
        return cue, _SIDE_WORD[said.group(1)] if said else None
    if cue.relation.kind != "side":
        return cue, None
    lean = vocabulary.find_cue(prompt, aside, {"contact"})
    if lean is None or lean.cue.relation != "lean" or lean.start < cue.end and cue.start < lean.end:
        return cue, None
    said_of_side = lean.end <= cue.start and _BEFORE_SIDE.fullmatch(vocabulary.clean(prompt)[lean.end:cue.start])
    if not said_of_side and context.about_another(prompt, lean.end, mention_at):  # "... leaning on the wall"
        return cue, None
    return min(cue, lean, key=lambda c: c.start), cue.cue.relation


_BEFORE_SIDE = re.compile(r"\s*(?:the |its |his |her |their )?")  # "against the [left side of]": one phrase


def _relation(cue, target, source, figure) -> tuple[vocabulary.Relation, str]:
    """The cue's relation; only agents ride or sit ("a ball riding down a slide" rests on it), and
    agents cut with tools, not themselves ("a chef cutting a cake" handles it; "a worm poking out of an apple"
    is in it)."""
    if cue is not None:
        rel = vocabulary.RELATIONS[cue.cue.relation]
        if rel.name == "sit" and figure is not None and not figure.has("agent"):
            return vocabulary.RELATIONS["on"], f"'{cue.text}' said of an object: resting on"
        if (rel.name == "penetrate" and figure is not None and figure.has("agent")
                and _AGENT_CUTS.match(cue.text)):  # "a chef cutting a cake"
            return vocabulary.RELATIONS["hold"], f"'{cue.text}' said of someone: handling it, with a tool"
        if rel.name == "wear" and figure is not None and figure.has("agent"):  # "a bird on a giraffe's head"
            return vocabulary.RELATIONS["stand"], f"'{cue.text}' said of a creature: standing on it"
        return rel, f"'{cue.text}' -> {rel.name}"
    if source is not None and lexicon.bare_part(source.phrase) is not None:
        return vocabulary.RELATIONS["on"], "no relation cue; a detachable part: assumed seated on its owner"
    if target is not None and target.has("container") and (source is None or source.size_m <= target.size_m):
        return vocabulary.RELATIONS["in"], "no relation cue; the target holds things: assumed inside"
    return vocabulary.RELATIONS["on"], "no relation cue: assumed resting on"


def _size_ratio(target_name, source_name, target, source, relation, figure: bool,
                upright: bool = False) -> tuple[float, str]:
    """Lexicon sizes; an unknown wearer/holder/rider is a person; otherwise an unknown size falls back
    to the relation's typical figure/ground ratio.

    A name that is only a detachable part ("lid", "cap"), or a part named after the other object ("soldering_stand"
    next to a "soldering_iron"), belongs to the other object: a teapot's lid is sized from the teapot, a pen's cap
    from the pen.
    """
    for part_name, other_name, other, own, part_is_source in ((source_name, target_name, target, source, True),
                                                              (target_name, source_name, source, target, False)):
        part = lexicon.bare_part(part_name, other_name if own is None else "")  # unknown: "soldering_stand"
        if part is not None and other is not None and not other.has("agent"):  # a man has no lid
            fraction = lexicon.PARTS[part]
            ratio = fraction if part_is_source else 1.0 / fraction
            return ratio, (f"size ratio {clamp_size(ratio):.3g} ({part_name}: the {part} of the {other_name}, "
                           f"{fraction:g} of its size)")
    sizes, whys = [], []
    for name, match, is_ground in ((target_name, target, figure), (source_name, source, not figure)):
        if match is not None:
            sizes.append(match.size_m)
            whys.append(f"{name}: {match.how}")
        elif is_ground and relation.name in _AGENT_GROUND or not is_ground and relation.name == "sit":
            sizes.append(PERSON_M)
            whys.append(f"{name!r}: unknown, taken as a person ({PERSON_M:g} m) because it {relation.name}s")
        else:
            sizes.append(None)
            whys.append(f"{name!r}: not in the lexicon")
    fig_i, ground_i = (1, 0) if figure else (0, 1)
    if (sizes[fig_i] is None and sizes[ground_i] is not None
            and sizes[ground_i] * relation.figure_size > UNKNOWN_FIGURE_MAX_M):  # "an acorn buried in the lawn"
        sizes[fig_i] = UNKNOWN_FIGURE_MAX_M
        whys[fig_i] += f", so at most {UNKNOWN_FIGURE_MAX_M:g} m on a ground this big (fallback)"
    if None in sizes:
        ratio = relation.figure_size if figure else 1.0 / relation.figure_size
        return ratio, (f"size ratio {clamp_size(ratio):.3g} (fallback: {', '.join(whys)}; "
                       f"the typical ratio for '{relation.name}')")
    fig_match, ground_match = (source, target) if figure else (target, source)
    if (ground_match is not None and fig_match is not None and fig_match.size_m > 0.5 * ground_match.size_m
            and not fig_match.has("agent") and (
                relation.name in _AGENT_GROUND and ground_match.entry.domain == "toys and figures"
                or fig_match.entry.domain in _GEAR and ground_match.entry.name == "toy"
                or relation.name == "wear" and ground_match.entry.domain == "animals"
                and fig_match.entry.domain == "clothing and accessories" and ground_match.size_m < PERSON_M)):
        # a doll's hat, an action figure's sword (held, worn or strapped on), a dog's raincoat: made to its scale
        scale = ground_match.size_m / PERSON_M
        sizes[fig_i] *= scale
        whys[fig_i] += f" x {scale:.2g} (made to its wearer's scale)"
    ratio = sizes[1] / sizes[0]
    fits = FITS_INSIDE if figure else 1.0 / FITS_INSIDE
    if (relation.name == "in" and ground_match is not None and ground_match.has("container") and fig_match is not None
            and not fig_match.has("pointed") and fig_match.entry.domain != "plants"  # stems stick out of a vase
            and not upright  # "scissors standing in a pencil cup" stick out of it
            and (ratio > fits if figure else ratio < fits)):
        return fits, (f"size ratio {fits:.3g} ({whys[1]} / {whys[0]}: the {fig_match.phrase} must fit inside, "
                      f"so no bigger than {FITS_INSIDE:g} of the {ground_match.phrase})")
    sticks_out = STICKS_OUT if figure else 1.0 / STICKS_OUT
    if (relation.name in {"in", "penetrate"} and ground_match is not None and ground_match.has("container")
            and fig_match is not None and (ratio > sticks_out if figure else ratio < sticks_out)):  # a shoe tree
        return sticks_out, (f"size ratio {sticks_out:.3g} ({whys[1]} / {whys[0]}: a {fig_match.phrase} in a "
                            f"{ground_match.phrase} sticks out of it, by no more than {STICKS_OUT:g} times its size)")
    clamped = clamp_size(ratio)
    note = "" if clamped == ratio else f", clamped from {ratio:.3g}"
    return ratio, f"size ratio {clamped:.3g} ({whys[1]} / {whys[0]}{note})"


def _solid(ground) -> bool:
    """A mass a thing can be set in (ice, amber, rock, a cake): no container, creature, sheet, cloth or net, tree or
    bush."""
    return ground is not None and not ground.tags & {"container", "agent", "flat", "soft"} and (
        ground.entry.domain != "plants" or ground.has("pierceable"))


def _food(match) -> bool:
    """A food, or something made of one ("a corn dog", "a chocolate bunny")."""
    return match.entry.domain == "food and drink" or match.has("food")


def _pierceable(ground) -> bool:
    """Solids a pointed thing goes into: tagged ``pierceable`` (wood, soil, foam, a dartboard), solid food,
    plants and soft things; never a container (it has an opening), a person or an animal."""
    return ground is not None and not ground.has("container") and not ground.has("agent") and (
        ground.has("pierceable") or ground.has("soft") or ground.entry.domain in {"food and drink", "plants"})


def _holds_own(ground_name: str, fig) -> bool:
    """A holder named for what it holds ("knife_block" for a knife): it has a slot for it."""
    return bool(set(lexicon.singulars(fig.phrase.split()[-1])) & lexicon.forms(lexicon.words(ground_name)))


def _penetration(relation, figure: bool, target, source, filled: str | None, floating: bool,
                 cue_text: str = "", text: str = "", ground_name: str = "") -> tuple[bool, str]:
    """From the relation word and from what the ground is.

    Categories: a ground full of contents that close it off (``context.contents``: a drink, a soup, soil, a
    pond) is entered below their surface by whatever goes in, is stuck in or floats in it (flat things float on
    top); a container otherwise is entered through its opening; a pointed figure goes into a pierceable solid
    (``_pierceable``), also when "stuck on" it (a candle on a cake), and a food or soft thing "on" a pointed
    stick is skewered by it; anything inside a solid food that is no container (a coin in a cake) is embedded,
    unless it is tucked into a fold of it (a fortune cookie's paper). Found in ``estimate``: contents the prompt
    names outside the objects ("scooping salsa from a bowl"), the contents of a container something is buried in
    (a sandpit's sand) or that is named for its contents (a compost bin), a solid something is frozen, trapped or
    encased in (ice, amber); what rests on the bottom of filled contents or is beneath their surface is under them; a
    short or staked pointed thing that fastens or holds a pierceable solid (a safety pin, a skewer through a burger)
    goes through it. Something screwed into what no point goes into (an engine, a lamp) is in a threaded hole, and an
    accessory pinned to a person goes through their clothes. What is threaded, impaled or hooked onto a pointed
    thing (bait on a fishing hook) is pierced by it, and hooks made to pierce (fishing, meat hooks) are pointed.
    Defaults for what the rules do not know: a pointed thing "in" any solid that is no container, and no holder
    named for it, is stuck in it (a dart in a door, not a knife in a knife block); any verb "into" a pierceable mass
    that is no sheet goes in (a pebble sinking into mud); what is on the spines, thorns or prongs of something is
    impaled on them. Found in ``estimate``: what is planted in a container is in its soil, an animal drinking from
    something has its muzzle in the water it holds, and a biting or stinging insect (``bites``) pierces the skin.
    """
    ground, fig = (target, source) if figure else (source, target)
    fig_name = fig.phrase if fig is not None else "source" if figure else "target"
    if filled is not None and (relation.name in {"in", "penetrate"} or floating):
        if floating and fig is not None and fig.has("flat"):
            return False, f"a flat {fig_name} floats on top of {filled}: no penetration"
        return True, f"the ground holds {filled}: the {fig_name} goes below their surface: penetration"
    if relation.penetration == "yes":
        if ground is not None and ground.has("container") and not _CUTS.match(cue_text):
            return False, "goes into an opening of the ground: no penetration"
        if ground is not None and _SCREWED.match(cue_text) and not _pierceable(ground):
            return False, f"screwed into a threaded hole of the {ground.phrase}: no penetration"
        return True, "the relation cuts or pierces: penetration"
    return _pierces(relation, fig, ground, fig_name, cue_text, text, ground_name)


def _pierces(relation, fig, ground, fig_name: str, cue_text: str, text: str, ground_name: str) -> tuple[bool, str]:
    """``_penetration`` where no contents and no relation that cuts decide: by the shapes of the figure ``fig`` and
    of the ``ground`` (pointed, pierceable, flat, a food) and by the words said (pinned, stuck on, threaded, on the
    spines of, into)."""
    if relation.penetration == "if_pointed" and fig is not None and fig.has("pointed") and _pierceable(ground):
        return True, f"a pointed {fig.phrase} into a solid {ground.phrase}: penetration"
    if (cue_text.startswith("pinned") and fig is not None and ground is not None
            and (ground.has("soft") or ground.entry.domain == "people and characters (agents)")  # their clothes
            and fig.entry.domain == "clothing and accessories"):  # a brooch, a badge: its own pin
        return True, f"a {fig.phrase} pinned to a {ground.phrase}: its pin through the cloth, penetration"
    if (relation.name == "attach" and cue_text.startswith("stuck") and _pierceable(ground)
            and not (fig is not None and fig.has("flat"))):
        return True, f"stuck on a {ground.phrase}, which it pierces: penetration"
    if (relation.name == "attach" and fig is not None and fig.has("pointed") and fig.size_m <= FASTENER_MAX_M
            and _pierceable(ground)):  # "a safety pin fastening a cloth diaper", "a tack fixed to the board"
        return True, f"a {fig.phrase} fastens the {ground.phrase} through it: penetration"
    if (relation.name in {"on", "attach", "hang"} and _ON_POINTS.search(text) is not None
            and fig is not None and not fig.tags & {"agent", "flat"}):  # "an apple stuck on a hedgehog's spines"
        return True, f"on the {_ON_POINTS.search(text).group(1)} of the ground: pierced by them, penetration"
    if relation.name == "on" and fig is not None and fig.has("staked") and _pierceable(ground):
        return True, f"a {fig.phrase} stands stuck in the {ground.phrase}: penetration"
    if (relation.name == "on" and ground is not None and ground.has("pointed") and ground.size_m <= 1.0
            and (fig is not None and (_food(fig) or fig.has("soft")) and not fig.has("agent")
                 or _THREADED.search(text))):  # "a worm threaded onto a fishing hook"
        return True, f"a {fig_name} on a pointed {ground.phrase}: skewered, penetration"
    if (relation.name == "in" and fig is not None and fig.has("pointed") and ground is not None
            and not ground.tags & {"container", "agent"} and not _holds_own(ground_name, fig)):
        return True, f"a pointed {fig.phrase} in a solid {ground.phrase}: stuck in it, penetration"  # a knife in a door
    if (cue_text.endswith("into") and _pierceable(ground) and ground.has("pierceable") and not ground.has("flat")
            and not (fig is not None and fig.has("agent"))):  # "a pebble sinking into the mud", any verb
        return True, f"forced into a pierceable {ground.phrase}: penetration"
    if (relation.name == "in" and ground is not None and ground.entry.domain == "food and drink"
            and not ground.has("container") and not ground.has("agent")):
        return True, f"inside a solid {ground.phrase}: embedded, penetration"
    return False, ""


def _contact(relation, figure: bool, source, immersed_in: str | None = None, afloat: bool = False,
             prompt: str = "", size: float = 1.0, in_place: bool = False, encased: bool = False) -> float:
    """The relation's contact for the source's role, adjusted for the source's shape when it is the figure;
    a figure that goes into contents (``immersed_in``) touches them with its whole wetted part: all of it when
    it goes wholly under (``_immersion``) or is set in a solid (``encased``), a part otherwise; so does one
    that is no blade or stick and is buried or sunk in a solid."""
    if not figure:
        return relation.ground_contact
    contact = relation.figure_contact
    if immersed_in is not None:
        if source is not None and source.has("agent") and _ON_FEET.search(prompt) and not afloat:
            return WADING_CONTACT  # "a heron wading in the pond": its legs
        how = "whole" if encased else _immersion(source, immersed_in, afloat, prompt, size)
        return IMMERSED_CONTACT["pointed" if how == "part" and relation.name == "penetrate" else how]
    if (relation.name == "penetrate" and _WHOLLY_UNDER.search(prompt) and not _PARTLY_UNDER.search(prompt)
            and not (source is not None and source.has("pointed"))):
        return IMMERSED_CONTACT["whole"]  # "a dog bone buried in the garden"
    if source is None:
        return contact
    if relation.name == "in" and (source.has("agent") or source.entry.domain == "vehicles") and in_place:
        return ON_FEET_CONTACT  # "a horse in its stable", "a motorbike parked in the garage": feet or tyres
    if source.has("round") and relation.name in _SUPPORT | {"in"}:
        contact = min(contact, 0.05 if relation.name in _SUPPORT else 0.1)
    if source.has("flat") and relation.name in {"on", "lie", "attach"}:
        contact = max(contact, 0.45)
    if source.has("flat") and not source.has("soft") and relation.name == "hang":
        contact = max(contact, 0.3)  # a frame or a sign hangs flat against its wall
    if source.has("pointed") and relation.name == "in" and not source.has("round"):
        contact = min(contact, 0.1)  # a spoon, a straw, a pencil leans on the rim and the bottom
    if relation.name == "lie" and not (source.has("soft") or source.has("flat") or source.has("agent")):
        contact = min(contact, 0.1)  # a rigid tool or stick lying down touches at a few points
    if source.has("soft") and relation.name in {"on", "sit"}:
        contact = max(contact, 0.3)
    if source.has("wrap") and relation.name in {"wear", "on", "attach", "in", "lie"}:
        contact = max(contact, 0.6)
    return contact


def _immersion(source, contents: str, afloat: bool, text: str, size: float) -> str:
    """How much of a figure is below the contents' surface: "whole", "part" or "pointed" (a blade, a stick,
    a spoon: its end)."""
    if _WHOLLY_UNDER.search(text) and not _PARTLY_UNDER.search(text):  # "half submerged" is partly
        return "whole"
    if source is not None and source.has("pointed"):
        return "pointed"
    words = contents.split()
    liquid = words[-1] in context.LIQUIDS or context.is_drink(contents) and not set(words) & context.CONTENTS - \
        context.LIQUIDS  # a "pond" or a "cocktail" is liquid; a "honey jar" is not
    if source is not None and source.has("aquatic") and liquid and not _PARTLY_UNDER.search(text):
        return "whole"  # "a goldfish in a bag of water", "a trout swimming in the stream"
    if afloat or _PARTLY_UNDER.search(text) or size > SUNK_MAX or not liquid:
        return "part"
    if source is not None and (source.has("agent") or source.has("soft") or source.entry.domain == "vehicles" or (
            source.entry.domain == "plants" and not source.has("round"))):
        return "part"  # someone standing or sitting in it, a sponge or a boat afloat, stems and roots (a pebble sinks)
    return "whole"
