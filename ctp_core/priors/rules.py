"""The deterministic scene-prior provider: the numbers of a prompt's reading (``reading.passes.read_prompt``).

The reading gives the relation, who its figure is, the ground and the contents it holds; this module sizes the
figure from the lexicon (``_size_ratio``), says whether it goes into the ground (``_penetration``) and how much of
it touches (``_contact``). No network, no model, the same answer every time; the default provider and the fallback
of the language-model one. Every value says where it came from in ``reason``, and anything guessed for lack of
knowledge says "fallback".
"""

from __future__ import annotations

import re

from ctp_core.priors.prior import ScenePrior, clamp_contact, clamp_size
from ctp_core.reading import context, lexicon, records
from ctp_core.reading.context import PERSON_M  # an unknown name that holds, wears or rides is someone this tall
from ctp_core.reading.passes import FASTENER_MAX_M, PromptReading, pierceable, read_prompt
from ctp_core.reading.records import RelationName, Role

STICKS_OUT = 2.5  # ... and a long thing or a plant that sticks out of it is at most this size of it
# An unknown figure on or in a known ground is an object someone handles: its size is the relation's typical share
# of the ground's, but at most this ("an acorn buried in the lawn" is no 4 m acorn).
UNKNOWN_FIGURE_MAX_M = 1.0
FITS_INSIDE = 0.9  # what is inside a container (not a long thing or a plant sticking out) is at most this size of it
# Cues of a blade or a bit that passes through a wall, even a container's (a knife slicing a cardboard box).
_CUTS = re.compile(r"(?:cut|slic|saw|carv|chop|stab|pierc|drill|bor|punctur)\w*(?:ing|s)\b")  # no "carved"
# Short fasteners driven in (a nail, a screw, a tent peg) are mostly inside what holds them.
_DRIVEN = re.compile(r"hammer|driv|screw|nail|tapp|pound")
DRIVEN_MAX_M = 0.25
DRIVEN_CONTACT = 0.6
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
# Screwed into something no point goes into (an engine, a lamp): into its threaded hole.
_SCREWED = re.compile(r"screw|bolt")
# Put onto a pointed thing through its body: bait on a hook, beads on a needle.
_THREADED = re.compile(r"\b(?:thread(?:s|ed|ing)?|impaled|hooked)\b")
# On the sharp parts of something ("on the spines of a hedgehog", "on the prongs of a fork"): impaled on them.
_ON_POINTS = re.compile(r"\b(?:on|onto|upon) (?:the |its |his |her |their |a )?(?:[a-z]+ )?(spines?|spikes?|thorns?"
                        r"|prongs?|tines?|quills?|barbs?|needles?)\b")
# Standing up in a container: what stands in it sticks out of it, like a long thing ("scissors standing in a cup").
_UPRIGHT = re.compile(r"\b(?:standing|stands|stood|stand)(?: up| upright)? $")
DRINKING_CONTACT = 0.02  # what a drinking animal's muzzle, a biting or stinging insect's mouthparts touch
_PARTLY_UNDER = re.compile(r"\b(?:dip|dipped|dipping|dunk|dunked|dunking|half|partly|partially)\b")
SUNK_MAX = 0.5
IMMERSED_CONTACT = {"whole": 0.9, "part": 0.4, "pointed": 0.3}  # "pointed" also for anything stuck in them
# What a figure or a doll carries or wears, whatever the prompt's relation ("with a katana strapped to his back").
_GEAR = {"clothing and accessories", "tools, weapons and equipment"}
# Relations whose ground must be an agent (the wearer, the holder, the rider).


class RulesProvider:
    """Lexicon sizes + prompt relation cues; see ``lexicon``, ``reading.passes`` and ``relations`` for the tables."""

    name = "rules"

    def estimate(self, target_name: str, source_name: str, prompt: str) -> ScenePrior:
        """The prior of a prompt: its reading (``read``), then its size ratio, penetration and contact."""
        reading = read_prompt(target_name, source_name, prompt)
        size, size_why = _sized(reading)
        penetration, pen_why = _penetrates(reading)
        contact = _touches(reading, size, penetration)
        notes = [size_why, *reading.name_notes, *reading.notes, pen_why]
        return ScenePrior(size_ratio=clamp_size(size), penetration=penetration,
                          contact_ratio=clamp_contact(contact), provider=self.name,
                          reason="; ".join(n for n in notes if n), reading=reading.reading)


def _sized(r: PromptReading) -> tuple[float, str]:
    """The size ratio and its note (``_size_ratio``); a drinker is sized at the rim, as on it, not in it; what
    stands upright in a container may stick out of it."""
    upright = r.cue is not None and _UPRIGHT.search(r.text[:r.cue.start]) is not None
    return _size_ratio(r.target_name, r.source_name, r.target, r.source,  # a drinker is at the rim
                       records.RELATIONS[RelationName.ON] if r.drinks else r.relation, r.figure, upright)


def _penetrates(r: PromptReading) -> tuple[bool, str]:
    """Whether the figure goes into the ground, and why (``_penetration``)."""
    floating = r.afloat and r.filled is not None
    return _penetration(r.relation, r.figure, r.target, r.source, r.filled, floating,
                        r.cue.text if r.cue is not None else "", r.text, r.ground_name)


def _touches(r: PromptReading, size: float, penetration: bool) -> float:
    """The contact ratio (``_contact``) of a reading whose figure has this ``size`` ratio and ``penetration``: a
    short fastener driven in is mostly inside what holds it; a drinking animal's muzzle or a biting insect's
    mouthparts touch little; a creature or a vehicle standing in a place touches its floor with feet or tyres."""
    ground, source = r.ground, r.source
    immersed = ground.phrase if r.filled == "its contents" and ground is not None else r.filled
    immersed = immersed if penetration else None
    driven = (penetration and r.relation.name == "penetrate" and r.cue is not None and _DRIVEN.match(r.cue.text)
              and source is not None and source.has("pointed") and source.size_m <= DRIVEN_MAX_M)
    in_place = ground is not None and size <= SUNK_MAX and (
        ground.entry.domain == "buildings and places" or _ON_FEET.search(r.text) is not None)
    if r.drinks and penetration or r.bites:
        return DRINKING_CONTACT  # its muzzle, its proboscis or sting
    if driven and r.figure:
        return DRIVEN_CONTACT
    return _contact(r.relation, r.figure, source, immersed, r.afloat, r.text, size, in_place, r.encased)


def _size_ratio(target_name, source_name, target, source, relation, figure: bool,
                upright: bool = False) -> tuple[float, str]:
    """Lexicon sizes; an unknown wearer/holder/rider is a person; otherwise an unknown size falls back
    to the relation's typical figure/ground ratio.

    A name that is only a detachable part ("lid", "cap"), or a part named after the other object ("soldering_stand"
    next to a "soldering_iron"), belongs to the other object: a teapot's lid is sized from the teapot, a pen's cap
    from the pen.
    """
    part = _part_ratio(target_name, source_name, target, source)
    if part is not None:
        return part
    sizes, whys = _sizes(target_name, source_name, target, source, relation, figure)
    fig_i = 1 if figure else 0
    if None in sizes:
        ratio = relation.figure_size if figure else 1.0 / relation.figure_size
        return ratio, (f"size ratio {clamp_size(ratio):.3g} (fallback: {', '.join(whys)}; "
                       f"the typical ratio for '{relation.name}')")
    fig_match, ground_match = (source, target) if figure else (target, source)
    if _to_scale(fig_match, ground_match, relation):
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


def _part_ratio(target_name, source_name, target, source) -> tuple[float, str] | None:
    """The size ratio of a name that is a part of the other object (``_size_ratio``); None where neither is."""
    for part_name, other_name, other, own, part_is_source in ((source_name, target_name, target, source, True),
                                                              (target_name, source_name, source, target, False)):
        part = lexicon.bare_part(part_name, other_name if own is None else "")  # unknown: "soldering_stand"
        if part is not None and other is not None and not other.has("agent"):  # a man has no lid
            fraction = lexicon.PART_SIZES[part]
            ratio = fraction if part_is_source else 1.0 / fraction
            return ratio, (f"size ratio {clamp_size(ratio):.3g} ({part_name}: the {part} of the {other_name}, "
                           f"{fraction:g} of its size)")
    return None


def _sizes(target_name, source_name, target, source, relation, figure: bool
           ) -> tuple[list[float | None], list[str]]:
    """The target's and the source's sizes in metres (None: unknown) and where each came from: the lexicon, a
    person for an unknown wearer, holder or sitter, at most ``UNKNOWN_FIGURE_MAX_M`` for an unknown figure on a big
    ground."""
    sizes, whys = [], []
    for name, match, is_ground in ((target_name, target, figure), (source_name, source, not figure)):
        if match is not None:
            sizes.append(match.size_m)
            whys.append(f"{name}: {match.how}")
        elif relation.agent == (Role.GROUND if is_ground else Role.FIGURE):
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
    return sizes, whys


def _to_scale(fig_match, ground_match, relation) -> bool:
    """A figure made to its ground's scale: a doll's or an action figure's gear, a small animal's clothes."""
    return (ground_match is not None and fig_match is not None and fig_match.size_m > 0.5 * ground_match.size_m
            and not fig_match.has("agent") and (
                relation.agent == Role.GROUND and ground_match.entry.domain == "toys and figures"
                or fig_match.entry.domain in _GEAR and ground_match.entry.name == "toy"
                or relation.name == "wear" and ground_match.entry.domain == "animals"
                and fig_match.entry.domain == "clothing and accessories" and ground_match.size_m < PERSON_M))


def _food(match) -> bool:
    """A food, or something made of one ("a corn dog", "a chocolate bunny")."""
    return match.entry.domain == "food and drink" or match.has("food")


def _holds_own(ground_name: str, fig) -> bool:
    """A holder named for what it holds ("knife_block" for a knife): it has a slot for it."""
    return bool(set(lexicon.singulars(fig.phrase.split()[-1])) & lexicon.forms(lexicon.words(ground_name)))


def _penetration(relation, figure: bool, target, source, filled: str | None, floating: bool,
                 cue_text: str = "", text: str = "", ground_name: str = "") -> tuple[bool, str]:
    """From the relation word and from what the ground is.

    Categories: a ground full of contents that close it off (``context.contents``: a drink, a soup, soil, a
    pond) is entered below their surface by whatever goes in, is stuck in or floats in it (flat things float on
    top); a container otherwise is entered through its opening; a pointed figure goes into a pierceable solid
    (``pierceable``), also when "stuck on" it (a candle on a cake), and a food or soft thing "on" a pointed
    stick is skewered by it; anything inside a solid food that is no container (a coin in a cake) is embedded,
    unless it is tucked into a fold of it (a fortune cookie's paper). Found in the reading: contents the prompt
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
    impaled on them. Found in the reading: what is planted in a container is in its soil, an animal drinking from
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
        if ground is not None and _SCREWED.match(cue_text) and not pierceable(ground):
            return False, f"screwed into a threaded hole of the {ground.phrase}: no penetration"
        return True, "the relation cuts or pierces: penetration"
    return _pierces(relation, fig, ground, fig_name, cue_text, text, ground_name)


def _pierces(relation, fig, ground, fig_name: str, cue_text: str, text: str, ground_name: str) -> tuple[bool, str]:
    """``_penetration`` where no contents and no relation that cuts decide: by the shapes of the figure ``fig`` and
    of the ``ground`` (pointed, pierceable, flat, a food) and by the words said (pinned, stuck on, threaded, on the
    spines of, into)."""
    if relation.penetration == "if_pointed" and fig is not None and fig.has("pointed") and pierceable(ground):
        return True, f"a pointed {fig.phrase} into a solid {ground.phrase}: penetration"
    if (cue_text.startswith("pinned") and fig is not None and ground is not None
            and (ground.has("soft") or ground.entry.domain == "people and characters (agents)")  # their clothes
            and fig.entry.domain == "clothing and accessories"):  # a brooch, a badge: its own pin
        return True, f"a {fig.phrase} pinned to a {ground.phrase}: its pin through the cloth, penetration"
    if (relation.name == "attach" and cue_text.startswith("stuck") and pierceable(ground)
            and not (fig is not None and fig.has("flat"))):
        return True, f"stuck on a {ground.phrase}, which it pierces: penetration"
    if (relation.name == "attach" and fig is not None and fig.has("pointed") and fig.size_m <= FASTENER_MAX_M
            and pierceable(ground)):  # "a safety pin fastening a cloth diaper", "a tack fixed to the board"
        return True, f"a {fig.phrase} fastens the {ground.phrase} through it: penetration"
    if (relation.name in {"on", "attach", "hang"} and _ON_POINTS.search(text) is not None
            and fig is not None and not fig.tags & {"agent", "flat"}):  # "an apple stuck on a hedgehog's spines"
        return True, f"on the {_ON_POINTS.search(text).group(1)} of the ground: pierced by them, penetration"
    return _stuck_in(relation, fig, ground, fig_name, cue_text, text, ground_name)


def _stuck_in(relation, fig, ground, fig_name: str, cue_text: str, text: str, ground_name: str) -> tuple[bool, str]:
    """``_pierces`` past the words that pin, stick or impale: a staked thing on a pierceable ground, a food on a
    pointed stick, a pointed thing in a solid, anything forced into a pierceable mass or inside a solid food."""
    if relation.name == "on" and fig is not None and fig.has("staked") and pierceable(ground):
        return True, f"a {fig.phrase} stands stuck in the {ground.phrase}: penetration"
    if (relation.name == "on" and ground is not None and ground.has("pointed") and ground.size_m <= 1.0
            and (fig is not None and (_food(fig) or fig.has("soft")) and not fig.has("agent")
                 or _THREADED.search(text))):  # "a worm threaded onto a fishing hook"
        return True, f"a {fig_name} on a pointed {ground.phrase}: skewered, penetration"
    if (relation.name == "in" and fig is not None and fig.has("pointed") and ground is not None
            and not ground.tags & {"container", "agent"} and not _holds_own(ground_name, fig)):
        return True, f"a pointed {fig.phrase} in a solid {ground.phrase}: stuck in it, penetration"  # a knife in a door
    if (cue_text.endswith("into") and pierceable(ground) and ground.has("pierceable") and not ground.has("flat")
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
    return _shaped(contact, relation, source)


def _shaped(contact: float, relation, source) -> float:
    """The figure's ``contact`` for its shape (``_contact``): a ball touches at a point, a sheet lies on a face, a
    soft thing settles, a wrap hugs."""
    if source.has("round") and (relation.supports or relation.name == RelationName.IN):
        contact = min(contact, 0.05 if relation.supports else 0.1)
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
