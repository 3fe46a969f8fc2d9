"""Which relation a prompt names, and who is its figure: the cues (a relation's wordings) and how they are matched.

Cues are matched as whole words (``in`` never matches inside "pinocchio" or "dining"), the most specific cue wins
(``CUES`` is in priority order: "holding a carrot in his hand" is holding, not in), and ties go to the earliest cue.
The names say which mesh is the source; the prompt's word order around the cue says which role it plays ("Pinocchio
wearing a hat" and "a hat on Pinocchio" both make the hat the figure). Torch-free.
"""

from __future__ import annotations

import functools
import re
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass

from ctp_core.reading.records import RELATIONS, Kind, Relation, RelationName

R = RelationName


@dataclass(frozen=True)
class Cue:
    """One wording of a relation: a regular expression over the lower-cased prompt."""

    pattern: str
    relation: RelationName
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
    Cue(r"(?:pierced|cut|stabbed|skewered|impaled|speared) (?:by|with)", R.PENETRATE, True),
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
        R.PENETRATE),
    # garments and headwear
    Cue(r"on (?:top of )?" + _HEAD + r"|around " + _POSS + r" (?:neck|waist|wrist|finger|arm)s?|worn by",
        R.WEAR),
    Cue(r"wear(?:s|ing)?|dressed in|put(?:s|ting)? on|has on|donning", R.WEAR, True),
    # two grounds, named after the cue ("between the sofa and the armchair"): before "in" and the sides
    Cue(r"(?:in |midway |halfway |right )?between|in the (?:middle|center|centre) of(?= [a-z ]+ and )|flanked by",
        R.BETWEEN),
    # held
    Cue(r"in " + _POSS + r" " + _BODY + r"|held (?:by|in)", R.HOLD),
    Cue(r"hold(?:s|ing)?|carr(?:y|ies|ying)|grasp(?:s|ing)?|grip(?:s|ping)?|clutch(?:es|ing)?|wield(?:s|ing)?"
        r"|brandish(?:es|ing)?|play(?:s|ing)|hug(?:s|ging)?|eat(?:s|ing)|bit(?:e|es|ing)|sting(?:s|ing)?",
        R.HOLD, True),
    # where, in the ground's own frame, before the contact words they contain ("on the left side of" is left, not
    # on; "sitting in front of" is front); the wordings of SpatialSense, Sr3D, Holodeck and LayoutVLM
    Cue(_side("left"), R.LEFT),
    Cue(_side("right"), R.RIGHT),
    # "on the front of", "on the back of a horse": on it
    # "by the front door", "at the front of the desk" (its front edge), "strapped to his back": no side
    Cue(r"in front(?: of)?|opposite|across from|ahead of|" + _side("front", "to|by", "_", " of"), R.FRONT),
    Cue(r"behind|in back of|" + _side("(?:back|rear)", "to|at|by", "_", " of"), R.BEHIND),
    Cue(r"fac(?:e|es|ing) away(?: from)?|turned away from|look(?:s|ing)? away from|point(?:s|ing)? away from"
        r"|with (?:its|his|her|their) backs? (?:to|toward|towards)", R.FACING_AWAY),
    Cue(r"facing(?:[ _](?:to|toward|towards))?|fac(?:e|es)[ _](?:to|toward|towards)"  # "a rock face": no facing
        r"|faces(?= (?!(?:of|on|in|at|with|and|are|were)(?![a-z]))[a-z])|turned (?:to|toward|towards)"
        r"|look(?:s|ing)? (?:at|toward|towards)|point(?:s|ing)?[ _](?:at|to|toward|towards)"
        r"|oriented (?:to|toward|towards)", R.FACING),
    Cue(r"align(?:s|ed)?[ _](?:with|to)|parallel (?:to|with)|in line with|lined up with|(?:in|with) the same"
        r" direction as", R.ALIGNED),
    Cue(r"not far from|near(?:by|er|est)?(?: to)?|close(?:r|st)? to|close by|in the vicinity of|a short distance from"
        r"|within reach of|outside(?: of)?", R.NEAR),
    Cue(r"far(?: away| off)? from|farthest from|furthest from|a long way from|distant from|at a distance from"
        r"|(?<!facing )(?<!faces )(?<!face )(?<!turned )(?<!looking )(?<!looks )(?<!pointing )(?<!points )"
        r"(?:away|apart) from", R.FAR),
    # supported postures
    Cue(r"rid(?:e|es|ing)|astride|straddl[a-z]+|driv(?:e|es|ing)|(?:sit|sits|sitting|seated|sat)"
        r" (?:on|in|at|astride|inside)", R.SIT),
    Cue(r"(?:lying|lies|laid|lay|sleeping|sleeps|napping|curled up|draped|spread) (?:on|over|across|upon)"
        r"|cover(?:s|ing)(?= (?:the|a|an|its|his|her|their) )", R.LIE),  # a cover lies over what it covers
    Cue(r"covered (?:by|with)", R.LIE, True),
    Cue(r"(?:standing|stands|stood|perched|perching|balanced|balancing|landed|hopping) (?:on|upon|atop)",
        R.STAND),
    Cue(r"(?:wrapped|coiled|wound|tied|looped|wrapping|coiling) (?:around|round)|around|surround(?:s|ing)"
        r"|encircl(?:es|ing)", R.WRAP),
    Cue(r"lean(?:s|ing|ed)? (?:against|on|in)|propped (?:against|up|on)|rest(?:s|ing)? against|against"
        r"|touch(?:es|ing)", R.LEAN),  # touching its side: Rel3D's "touching"
    # moving over a support: feet, wheels or a belly on it
    Cue(r"(?:walk|run|crawl|stroll|march|hik|climb|roll|skat|ski|slid|trott|gallop|wander)(?:s|ing|ed|e|es)?"
        r" (?:over|across|along|up|down|on)", R.STAND),
    # hung or fixed above something, not on it: "a lamp hanging above the table", "a shelf mounted above the desk"
    Cue(r"(?:hang(?:s|ing)?|hung|dangl(?:e|es|ing)|suspended|mounted|fixed|attached|placed|set|put|installed)"
        r" (?:high |right |just |directly |up )?above", R.ABOVE),
    Cue(r"hang(?:s|ing)?|hung|dangl(?:e|es|ing)|suspended", R.HANG),
    Cue(r"attached|glued|taped|stuck (?:on|to)|fixed (?:on|to)|fasten(?:s|ed|ing)?|mounted|stapled|clipped"
        r"|pinned (?:to|on)|connected (?:to|with)|joined to",
        R.ATTACH),
    Cue(r"under(?:neath)?|beneath", R.UNDER),
    Cue(r"below", R.BELOW),
    # in water when the ground holds some (rules), else free in air or water
    Cue(r"(?:float(?:s|ing)?|swim(?:s|ming)?|bob(?:s|bing)?|paddl(?:e|es|ing)) (?:in|inside|within)", R.IN),
    Cue(r"(?:float(?:s|ing)?|swim(?:s|ming)?|bob(?:s|bing)?|paddl(?:e|es|ing)) (?:on|upon|atop)", R.ON),
    Cue(r"(?:leap|jump|hop|spring|climb|fly|flie|get|com)(?:s|ing|ed)? out of|emerg(?:e|es|ing) from", R.BESIDE),
    Cue(r"above|over(?:head of)?", R.ABOVE),  # "over" said of a cloth drapes (rules)
    Cue(r"swim(?:s|ming)?|float(?:s|ing)?|hover(?:s|ing)?|fl(?:y|ies|ying) (?:around|past)", R.BESIDE),  # free in
    # the air or water: no contact
    Cue(r"beside|next[ _]to|alongside|(?:at|by|to) (?:the|its|his|her|their) side(?: of)?|side[ _]of|side by side"
        r"|adjacent to|paired with|along|among(?:st)?|detached from|flank(?:s|ing)?"
        r"|on (?:each|either|both|opposite|the other|its other|their other) sides?(?: of)?", R.BESIDE),
    Cue(r"(?:at|on) the (?:edge|rim|brink|lip) of", R.ON),  # "a pigeon drinking at the edge of a fountain"
    # Holodeck's "center": "a vase in the middle of the table" is on it (in a container: in it, ``passes``)
    Cue(r"(?:at|in) the (?:very )?(?:middle|center|centre) of", R.ON),
    Cue(r"through", R.IN),  # penetrates only when a pointed thing goes through a solid
    Cue(r"filled with|full of|contain(?:s|ing)?|holding inside", R.IN, True),
    Cue(r"stir(?:s|red|ring)?", R.IN),  # "a candy cane stirring a mug of hot chocolate": its end in it
    # "a horse drinking from a trough": an animal's muzzle in the water (rules; someone drinking holds the cup)
    Cue(r"(?:drink|sip|lapp?)(?:s|ing|ped|ping)?(?: (?:up )?water)? (?:from|out of)", R.IN),
    Cue(r"enclosed (?:by|in|within)|inside|into|within|in", R.IN),
    Cue(r"supporting", R.ON, True),  # "a table supporting a lamp"
    Cue(r"on[ _]top[ _]of|on top|atop|onto|upon|supported[ _]by|on", R.ON),
    # VSR's "by" ("a bike by the door"), after every wording with "by" of its own ("held by", "covered by")
    Cue(r"(?:right |just |close )?by", R.BESIDE),
]
del R


@functools.cache
def _compiled(cue: Cue) -> re.Pattern:
    """A cue's pattern as whole words (compiled once per cue; ``CUES`` may grow, a new relation's wordings)."""
    return re.compile(r"(?<![a-z])(?:" + cue.pattern + r")(?![a-z])")


@dataclass(frozen=True)
class CueMatch:
    """Where one cue was found in a prompt."""

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


def find_cue(prompt: str, aside: Callable[[CueMatch], bool] | None = None, kinds: Collection[Kind] | None = None
             ) -> CueMatch | None:
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
    cue = find_cue(prompt, kinds={Kind.BETWEEN})
    if cue is None or cue.relation.grounds < 2:
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
