"""The deterministic scene-prior provider: the lexicon for sizes, the prompt's cue for the relation.

No network, no model, the same answer every time; the default provider and the fallback of the
language-model one. Every value says where it came from in ``reason``, and anything guessed for lack
of knowledge says "fallback".
"""

from __future__ import annotations

import re
from dataclasses import replace

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
        target, source = lexicon.lookup(target_name), lexicon.lookup(source_name)
        target_at, source_at = _mentions(prompt, target_name, target), _mentions(prompt, source_name, source)
        def aside(c: vocabulary.CueMatch) -> bool:  # "... with only its eyes above the water": about a part
            return (c.cue.relation not in {"in", "penetrate"} and context.substance_object(prompt, c.end)
                    and not context.names_next(prompt, c.end, target_at + source_at)
                    or c.text in {"in", "inside"}  # "a candle in a bucket on the table": on the table
                    and context.other_container(prompt, c.end, target_at + source_at)
                    or vocabulary.RELATIONS[c.cue.relation].kind != "contact"  # "... to the left of the plate"
                    and context.about_another(prompt, c.end, target_at + source_at))

        # a position first ("in front of the sofa, facing it": front), an orientation alone ("facing the sofa")
        cue = vocabulary.find_cue(prompt, aside, vocabulary.PLACING) or vocabulary.find_cue(prompt, aside)
        # "against the back of the sofa", "behind the sofa, against it": a lean, on that side
        cue, leant = _leaning(prompt, cue, aside, target_at + source_at)
        figure = None
        if cue is not None:
            figure = vocabulary.source_is_figure(cue, source_at, target_at)
        notes: list[str] = []
        if figure is None:
            figure = True  # the source is what gets placed: by default it is the figure
        agent_role = {"wear": "ground", "hold": "ground", "sit": "figure"}.get(cue.cue.relation if cue else "")
        target, source = (
            context.resolve(target_name, prompt, target_at, source, agent_role == ("ground" if figure else "figure"),
                            source_name),
            context.resolve(source_name, prompt, source_at, target, agent_role == ("figure" if figure else "ground"),
                            target_name))
        relation, why = _relation(cue, target, source, source if figure else target)
        if leant is not None and relation.name != "lean":  # "behind the sofa, against it"
            relation, why = vocabulary.RELATIONS["lean"], f"'{cue.text}', leaning -> lean"
        drinks = cue is not None and relation.name == "in" and _DRINKS.match(cue.text) is not None
        drinker = source if figure else target
        if drinks and not (drinker is not None and drinker.entry.domain == "animals"):
            figure, drinks = not figure, False  # "a man drinking from a cup": he holds it
            relation, why = vocabulary.RELATIONS["hold"], f"'{cue.text}' said of someone: holding it"
        holder, held = (target, source) if figure else (source, target)
        if (relation.name == "hold" and holder is not None and holder.has("pointed") and not holder.has("agent")
                and (holder.size_m <= FASTENER_MAX_M or holder.has("staked")) and _pierceable(held)):
            # "pins holding a pattern on the fabric", "a skewer holding a burger together"
            figure = not figure
            relation = vocabulary.RELATIONS["penetrate"]
            why = f"'{cue.text}' said of a pointed {holder.phrase}: a fastener in the {held.phrase}"
        bites = (relation.name == "hold" and cue is not None and _BITES.match(cue.text) is not None
                 and holder is not None and holder.has("bites") and (held is None or held.has("agent")
                                                                     or _pierceable(held)))
        if bites:  # "a mosquito biting a man's arm": its proboscis in the skin
            figure = not figure
            relation = vocabulary.RELATIONS["penetrate"]
            why = f"'{cue.text}' said of a {holder.phrase}: its bite or sting pierces the skin"
        if not figure:
            notes.append("the source is the ground of the relation")
        ground_name, ground, ground_at = (target_name, target, target_at) if figure else (
            source_name, source, source_at)
        figure_name = source_name if figure else target_name
        text = vocabulary.clean(prompt)
        if (relation.name == "in" and ground is not None and ground.entry.domain == "food and drink"
                and not ground.has("container") and _TUCKED.search(text)):
            ground = replace(ground, tags=ground.tags | {"container"})  # "a fortune tucked inside a fortune cookie"
            target, source = (ground, source) if figure else (target, ground)
            notes.append(f"tucked into the {ground_name}: into a fold of it")
        filled = context.contents(prompt, ground_at, ground, figure_name)
        if filled is None and cue is not None and relation.name in {"in", "penetrate"}:
            filled = context.contents_after(prompt, cue.end, figure_name,
                                            ground is not None and ground.has("container"))
        if filled is None and relation.name == "in" and ground is not None and ground.has("container"):
            filled = context.contents_named(prompt, target_at + source_at, figure_name)  # "scooping salsa from"
        if filled is None and (relation.name == "penetrate" and ground is not None and ground.has("container")
                               or relation.name in {"in", "penetrate"} and ground is None):
            filled = context.contents_in_name(ground_name, figure_name)  # "stuck in the compost bin", "a snowbank"
        if (filled is not None and relation.name in _SUPPORT | {"under"} and ground is not None
                and (_ON_BOTTOM.search(text) or relation.name == "under" and _WATER_SAID.search(text))):
            relation, why = vocabulary.RELATIONS["in"], why + f"; under the {filled} it holds"
        if drinks and filled is None and ground is not None and not ground.has("agent"):
            filled = context.contents_in_name(ground_name, figure_name) or "water"  # a trough, a bowl: its water
        afloat = cue is not None and _AFLOAT.match(cue.text) is not None
        if filled is None and ground is not None and ground.has("container") and _WATER_SAID.search(text):
            filled = "water"  # "a toy submarine underwater in the bathtub"
            if relation.name == "under":  # "a submarine beneath the waves of the sea"
                relation, why = vocabulary.RELATIONS["in"], why + "; under the water it holds"
        if (filled is None and ground is not None and ground.has("container") and relation.name == "penetrate"
                and _BURIED.search(text)):
            filled = "its contents"  # "a plastic dinosaur half buried in the sandpit": in its sand
        if (filled is None and ground is not None and relation.name == "in" and not ground.has("container")
                and _HIDDEN.search(text)):
            filled = f"the {ground.phrase}"  # "a bird nest hidden in a hedge": inside its mass
        encased = (filled is None and relation.name == "in" and _ENCASED.search(text) is not None
                   and _solid(ground))
        if encased:
            filled = f"the {ground.phrase}"  # "a fish frozen inside a block of ice": wholly in the solid
        if filled is None and ground is not None and _GROWS.search(text) and (
                relation.name == "in" or relation.name == "penetrate" and ground.has("container")):
            filled = "soil"  # "daffodils growing in a flower pot", "a cactus planted in a pot": rooted in its soil
        if (not afloat and filled is not None and relation.name in _SUPPORT and ground is not None
                and ground.entry.domain == "buildings and places"  # "a swan gliding on the lake", not "a frog
                and cue is not None and context.names_next(prompt, cue.end, ground_at)  # on a lily pad in a pond"
                and not _AT_EDGE.search(cue.text)):  # at the edge of a fountain: on its rim
            afloat = True
            why += "; on a body of water: afloat in it"
        if afloat and filled is None and relation.name == "in" and ground is not None and ground.has("container"):
            filled = "water"  # "a bath thermometer floating in the baby bath": nothing floats in an empty one
            why += "; afloat in a container: in the water it holds"
        if afloat and filled is None:
            relation, why = vocabulary.RELATIONS["beside"], f"'{cue.text}' in air or open water: no contact"
        floating = afloat and filled is not None
        fig_match = source if figure else target
        if (relation.name == "above" and cue is not None and cue.text == "over" and fig_match is not None
                and (fig_match.has("soft") or fig_match.has("wrap"))):
            relation, why = vocabulary.RELATIONS["lie"], "'over' said of a cloth or a cover: draped over"
        opening = context.opening_after(prompt, cue.end) if cue is not None else None
        if opening is not None and ground is not None and not ground.has("container"):
            ground = replace(ground, tags=ground.tags | {"container"})  # "in the slot of a toaster"
            target, source = (ground, source) if figure else (target, ground)
            notes.append(f"into the {opening} of the {ground_name}")
        notes.insert(0, why)
        if relation.name == "under" and not figure:  # "a table under a cup": the cup is on the table
            relation, figure = vocabulary.RELATIONS["on"], True
            notes.append("read as the target resting on the source")
        upright = cue is not None and _UPRIGHT.search(text[:cue.start]) is not None
        size, size_why = _size_ratio(target_name, source_name, target, source,  # a drinker is at the rim, not in
                                     vocabulary.RELATIONS["on"] if drinks else relation, figure, upright)
        notes.insert(0, size_why)
        penetration, pen_why = _penetration(relation, figure, target, source, filled, floating,
                                            cue.text if cue is not None else "", text, ground_name)
        notes.append(pen_why)
        immersed = ground.phrase if filled == "its contents" and ground is not None else filled
        immersed = immersed if penetration else None
        driven = (penetration and relation.name == "penetrate" and cue is not None and _DRIVEN.match(cue.text)
                  and source is not None and source.has("pointed") and source.size_m <= DRIVEN_MAX_M)
        in_place = ground is not None and size <= SUNK_MAX and (
            ground.entry.domain == "buildings and places" or _ON_FEET.search(text) is not None)
        contact = DRIVEN_CONTACT if driven and figure else _contact(relation, figure, source, immersed, afloat, text,
                                                                    size, in_place, encased)
        if drinks and penetration or bites:
            contact = DRINKING_CONTACT  # its muzzle, its proboscis or sting
        name = relation.name if leant is None else vocabulary.JOIN.join((relation.name, leant))
        turn = _orientation(prompt, cue, relation, aside, ground_at)
        if turn is not None:  # "in front of the sofa, facing it": both judged
            name += vocabulary.JOIN + turn.cue.relation
            notes.insert(1, f"'{turn.text}' -> {turn.cue.relation} too")
        side = vocabulary.side_of(name)
        if side is not None:
            notes.insert(1, f"on the {ground_name}'s {side} side (its own front, else the viewer's)")
        return ScenePrior(size_ratio=clamp_size(size), penetration=penetration, contact_ratio=clamp_contact(contact),
                          provider=self.name, reason="; ".join(n for n in notes if n),
                          relation=name, source_is_figure=figure)


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
