"""Object names read in the context of the prompt.

A file name says less than the prompt: the source may be called "duck" while the prompt says "a rubber
duck", "mouse" next to a laptop is a computer mouse, and "a mug of hot cocoa" is full. ``resolve`` reads the
noun phrase of the prompt that mentions a name (its modifiers) and the other object, ``contents`` what fills
a container. Categories of modifiers (documented here because they decide sizes):

- a longer lexicon phrase with the prompt's modifiers wins ("rubber duck", "coat hanger", "garden gnome");
- a word with several senses (``lexicon.SENSES``) takes the sense whose lexicon section fits the other object,
  the name's own modifiers and the prompt's other known words ("a flute of champagne", "drumsticks on a snare
  drum"), or the agent sense when the relation needs someone (a mouse eating cheese);
- ``TOY_WORDS`` ("toy robot", "miniature house") make an object hand-sized (``TOY_SIZE_M``) unless it is a toy
  already (a "toy box" is a lexicon phrase: a box for toys); ``CRAFT_WORDS`` ("paper crane", "origami boat") do
  the same for animals and vehicles, and ``TOY_MATERIALS`` ("a plastic dinosaur", "a tin soldier") for
  creatures, people and vehicles (a plastic chair stays a chair);
- a garment named after an animal or a small person ("dog coat", "baby shoes") is scaled to its wearer;
- ``HOLLOW_WORDS`` ("a carved pumpkin") make the object a container;
- ``YOUNG_WORDS`` ("baby elephant") make an animal or a food a young, small one (``YOUNG_SCALE``), and
  ``FOLDED_WORDS`` ("a folded towel") a cloth or a sheet a folded, smaller one (``FOLDED_SCALE``);
- a figure named after a food ("toast soldier", "chocolate bunny", "gingerbread man", "corn dog"), or a building or
  vehicle named after a sweet (``CONFECTIONS``: "a gingerbread house") is that food, shaped like it: food-sized
  (``FOOD_FIGURE_M``, a building or vehicle ``TOY_SIZE_M``), no agent or container, tagged ``food``.
"""

from __future__ import annotations

import re
from dataclasses import replace
from functools import lru_cache

from ctp_core.reading import cues, lexicon

# A size word in the prompt is relative to the kind ("a big knife" is no twice-as-long knife): the name's
# factor (``lexicon.SIZE_WORDS``) damped to this power.
PROMPT_SIZE_POWER = 0.5
PERSON_M = 1.75  # the wearer garments are sized for
TOY_SIZE_M = 0.3  # a toy or a model of something big fits in the hands
CRAFT_SIZE_M = 0.2  # a folded-paper animal or vehicle, and a paper version of anything big (a flag, an umbrella)
PAPER_LARGE_M = 1.0
FOOD_FIGURE_M = 0.12  # a sweet or a snack shaped like a person or an animal
YOUNG_WORDS = frozenset({"baby", "young", "newborn", "infant"})
YOUNG_SCALE = 0.35  # a calf is about a third of its mother's length
FOLDED_WORDS = frozenset({"folded", "rolled", "crumpled", "stacked"})
FOLDED_SCALE = 0.4
TOY_WORDS = frozenset({"toy", "miniature", "model", "plush", "stuffed", "figurine", "lego", "dollhouse"})
CRAFT_WORDS = frozenset({"paper", "origami", "folded"})
TOY_MATERIALS = frozenset({"plastic", "tin", "clockwork", "rubber"})
# Sweets things are built of ("a gingerbread house", "a chocolate car"); an "ice cream van" is a van.
CONFECTIONS = frozenset({"gingerbread", "chocolate", "candy", "sugar", "marzipan", "cake", "cookie", "biscuit"})
HOLLOW_WORDS = frozenset({"hollow", "hollowed", "carved", "empty"})
_CRAFT_DOMAINS = frozenset({"animals", "vehicles"})
_INDOOR = frozenset({"food and drink", "tableware and kitchen", "bathroom and cosmetics", "furniture and home"})
# Sections whose objects go together (a drink and its glass, a person and an animal).
_NEAR = (frozenset({"food and drink", "tableware and kitchen"}),
         frozenset({"furniture and home", "bathroom and cosmetics"}),
         frozenset({"people and characters (agents)", "animals", "toys and figures"}))
_STOP = lexicon.word_set("a an the of in on at with his her its their my your our this that these those and or to "
                         "from by for into onto is are two three four five some several pair one")
# Contents that close a container off: liquids, pastes, foams and soils. Discrete things (apples, cereal, coins)
# leave gaps and are not here: a spoon rests on cereal but sinks into soup.
CONTENTS = lexicon.word_set("""
brine water seawater saltwater coffee tea cocoa chocolate soup stew broth milk juice wine beer whiskey whisky soda
lemonade cola punch
milkshake smoothie yogurt yoghurt cream custard batter dough sauce gravy ketchup mustard honey jam syrup oil
paint ink glue wax foam bubbles soil dirt earth compost sand mud snow cement concrete jelly porridge oatmeal rice
salsa guacamole hummus fondue pesto mayonnaise blood sugar flour
""")
_WORD = re.compile(r"[a-z]+")
_FILL_WORDS = frozenset({"of", "with", "full", "filled", "containing"})
# Made into a paste, a liquid or a foam: "a pot of melted cheese", "a bowl of mashed potatoes".
_MELTED = frozenset({"melted", "molten", "liquid", "liquified", "whipped", "mashed", "pureed", "creamed", "blended"})
# Contents a small thing sinks into whole (the others, pastes, foams and soils, hold it half sunk).
LIQUIDS = lexicon.word_set("""
water seawater saltwater coffee tea cocoa soup stew broth milk juice wine beer whiskey whisky soda lemonade cola
punch brine oil blood
""")
# Heaps: what goes into a pile of anything (leaves, laundry, dirt) is buried in it, below its surface.
HEAPS = lexicon.word_set("pile heap mound")
# Places and receptacles named after the contents they hold, as the end of a one-word compound ("sandpit").
HOLDS_CONTENTS = lexicon.word_set("pit pits bank banks flat flats drift drifts dune dunes bed beds box bin pile heap "
                                  "mound field hole well pot can tub tank trap bag sack pan patch bath pool")
_CONTENTS_LONGEST_FIRST = sorted(CONTENTS, key=len, reverse=True)  # for ``_compound``, sorted once
# Mass nouns of loose pieces: they leave gaps, a spoon rests on them.
DISCRETE = lexicon.word_set("cereal popcorn candy fruit ice gold money change food salad confetti gravel hay straw")


def is_drink(phrase: str) -> bool:
    """A drink, a soup or another filled thing the lexicon knows ("champagne", "pina colada")."""
    known = lexicon.phrase_entry(phrase.split())
    return known is not None and "filled" in known[1].tags


def _is_contents(word: str, before: str | None) -> bool:
    """A contents word, a drink of the lexicon ("champagne"), anything melted or whipped, or a singular mass
    noun the lexicon knows as no object, or only as a food that is no round piece ("ramen", "peanut butter")."""
    if word in CONTENTS or before in _MELTED or is_drink(word):
        return True
    known = lexicon.phrase_entry([word])
    if word in DISCRETE or word in _STOP:
        return False
    food = known is not None and known[1].domain == "food and drink" and not known[1].tags & {"round", "agent"}
    if lexicon.singulars(word)[-1] != word:  # a plural: strands heap up ("noodles"), pieces leave gaps ("apples")
        return food and not known[1].tags & {"flat", "container"} and known[1].size_m >= 0.1
    return known is None or food


@lru_cache(maxsize=64)
def prompt_words(prompt: str) -> tuple[tuple[int, str], ...]:
    """The prompt's words with their offsets; every reader of one prompt shares a single tokenisation."""
    return tuple((m.start(), m.group(0)) for m in _WORD.finditer(cues.clean(prompt)))


def modifiers(prompt: str, mention_at: list[int]) -> list[str]:
    """Up to two words before the first mention of an object in the prompt, stopping at function words."""
    tokens = prompt_words(prompt)
    starts = [start for start, _ in tokens]
    if not mention_at or mention_at[0] not in starts:
        return []
    i = starts.index(mention_at[0])
    mods: list[str] = []
    for _, word in reversed(tokens[max(0, i - 2):i]):
        if word in _STOP:
            break
        mods.insert(0, word)
    return mods


def resolve(name: str, prompt: str, mention_at: list[int], other: lexicon.Match | None,
            needs_agent: bool, other_name: str = "") -> lexicon.Match | None:
    """The lexicon match of ``name`` as the prompt qualifies it (see the module docstring for the categories).

    A modifier the other object's name has is that object's ("a baby elephant next to its mother", names
    "baby_elephant" and "elephant": "baby" is not the mother's)."""
    match = lexicon.lookup(name)
    said = [w for start, w in prompt_words(prompt) if start in mention_at[:1]]
    plain = lexicon.lookup(said[0]) if said else None
    if (match is not None and plain is not None and plain.entry is match.entry and match.phrase not in lexicon.LEXICON
            and match.phrase not in lexicon.PART_SIZES):  # a "lipstick cover" is no lipstick
        # "quilt_patchwork_hi" that the prompt calls "a half-finished quilt": a quilt, with a quilt's shape
        match = replace(plain, how=plain.how + f" (the prompt calls {name!r} a {said[0]})")
    match = _head_first(name, prompt, mention_at, match, said, plain)
    if match is None or match.phrase not in lexicon.LEXICON and match.phrase not in lexicon.PART_SIZES:
        match = _held_in(name, prompt, mention_at) or match
    taken = set(lexicon.words(name)) | set(lexicon.words(other_name))
    mods = [w for w in modifiers(prompt, mention_at) if w not in taken]
    if mods:
        qualified = lexicon.lookup(" ".join([*mods, *lexicon.words(name)]))
        if qualified is not None and (match is None or (
                len(qualified.phrase.split()) > len(match.phrase.split())
                and qualified.phrase.split()[-1] == match.phrase.split()[-1])):
            match = replace(qualified, how=qualified.how + f" (the prompt says '{' '.join(mods)}')")
    if match is None:
        return None
    words = [*mods, *lexicon.words(name)]
    scene = [(2.0, other.entry)] if other is not None else []
    scene += [(2.0, e) for _, _, phrase, e in lexicon.spans(words) if phrase != match.phrase]
    scene += [(1.0, e) for _, _, phrase, e in lexicon.spans([w for _, w in prompt_words(prompt)])
              if phrase != match.phrase and e is not match.entry]
    match = _sense(match, scene, needs_agent)
    sized = [w for w in mods if w in lexicon.SIZE_WORDS]
    if sized and not set(lexicon.words(name)) & set(lexicon.SIZE_WORDS):  # "a giant teddy bear", "a mini fridge"
        scale = lexicon.SIZE_WORDS[sized[-1]] ** PROMPT_SIZE_POWER
        match = replace(match, size_m=match.size_m * scale, how=match.how + f", {sized[-1]}: x {scale:.2g}")
    return _modified(match, words)


def _held_in(name: str, prompt: str, mention_at: list[int]) -> lexicon.Match | None:
    """A name the lexicon does not know that the prompt calls the contents of a container ("a bottle of shower
    gel", "a tub of wood filler"): the object is that container."""
    tokens = prompt_words(prompt)
    starts = [start for start, _ in tokens]
    if not mention_at or mention_at[0] not in starts:
        return None
    i = starts.index(mention_at[0])
    own = lexicon.forms(lexicon.words(name))
    for k in range(1, 4):
        if i - k < 1 or tokens[i - k][1] != "of":
            if i - k >= 1 and tokens[i - k][1] in own:
                continue
            return None
        holder = lexicon.lookup(tokens[i - k - 1][1])
        if holder is None or not holder.has("container"):
            return None
        return replace(holder, how=holder.how + f" (the prompt says a {tokens[i - k - 1][1]} of the {name!r})")
    return None


def _head_first(name: str, prompt: str, mention_at: list[int], match: lexicon.Match | None, said: list[str],
                plain: lexicon.Match | None) -> lexicon.Match | None:
    """A file stem that puts its head first ("Owl_Barn_01", "SM_Candle_Birthday"): the prompt's own phrase
    of the name's words ("a birthday candle"), or the one word of the name the prompt calls it by ("an owl"
    for "Owl_Barn_01", where the stem's last word, "barn", is nowhere in the prompt)."""
    name_words = [w for w in lexicon.words(name) if w not in lexicon.NON_HEAD_WORDS and len(w) > 2]
    if len(name_words) < 2 or (match is not None and match.phrase in lexicon.PART_SIZES):
        return match
    tokens = [w for _, w in prompt_words(prompt)]
    for i in range(len(tokens) - len(name_words) + 1):
        run = tokens[i:i + len(name_words)]
        if run != name_words and sorted(lexicon.singulars(w)[-1] for w in run) == sorted(
                lexicon.singulars(w)[-1] for w in name_words):
            phrased = lexicon.lookup(" ".join(run))
            if phrased is not None and phrased.phrase.split()[-1] in lexicon.singulars(run[-1]):
                return replace(phrased, how=phrased.how + f" (the prompt calls {name!r} a {' '.join(run)})")
    head = match.phrase.split()[-1] if match is not None else ""
    said_forms = lexicon.forms(tokens)
    if (plain is not None and said and said[0] in name_words and (match is None or plain.entry is not match.entry)
            and not {head, *name_words} - {said[0]} & said_forms):
        return replace(plain, how=plain.how + f" (the prompt calls {name!r} a {said[0]})")
    return match


def _affinity(a: str, b: str) -> float:
    if a == b:
        return 1.0
    if any({a, b} <= near for near in _NEAR):
        return 0.75
    return 0.25 if {a, b} <= _INDOOR else 0.0


def _sense(match: lexicon.Match, scene: list[tuple[float, lexicon.Entry]], needs_agent: bool) -> lexicon.Match:
    senses = lexicon.SENSES.get(match.phrase)
    if not senses or match.entry not in senses:
        return match

    def fit(entry: lexicon.Entry) -> float:
        score = 3.0 * (needs_agent and "agent" in entry.tags)
        return score + sum(weight * _affinity(entry.domain, e.domain) for weight, e in scene)

    best = max(senses, key=fit)  # ties keep the first (the plain row)
    if best is match.entry:
        return match
    return lexicon.Match(match.phrase, best, best.size_m, best.tags,
                         f"'{match.phrase}' as a {best.name} ({best.size_m:g} m; the sense that fits the scene)")


def _modified(match: lexicon.Match, words: list[str]) -> lexicon.Match:
    entry = match.entry
    qualifiers = {w for w in words if w not in match.phrase.split()}  # "toy box" is a lexicon phrase of its own
    if qualifiers & TOY_WORDS and entry.domain != "toys and figures" and match.size_m > TOY_SIZE_M:
        match = replace(match, size_m=TOY_SIZE_M, how=match.how + f", a toy: {TOY_SIZE_M:g} m")
    toy_made = qualifiers & TOY_MATERIALS - ({"rubber"} if entry.domain == "vehicles" else set())  # a dinghy
    if toy_made and (entry.domain == "vehicles" or "agent" in entry.tags) and match.size_m > TOY_SIZE_M:
        match = replace(match, size_m=TOY_SIZE_M, how=match.how + f", {min(toy_made)}: a toy, {TOY_SIZE_M:g} m")
    if qualifiers & CRAFT_WORDS and entry.domain in _CRAFT_DOMAINS and match.size_m > CRAFT_SIZE_M:
        match = replace(match, size_m=CRAFT_SIZE_M, how=match.how + f", folded paper: {CRAFT_SIZE_M:g} m")
    elif "paper" in qualifiers and match.size_m > PAPER_LARGE_M and "agent" not in entry.tags:
        match = replace(match, size_m=CRAFT_SIZE_M, how=match.how + f", a paper one: {CRAFT_SIZE_M:g} m")
    young = qualifiers & YOUNG_WORDS
    if young and (entry.domain == "food and drink" or "agent" in entry.tags) and entry.name not in YOUNG_WORDS:
        match = replace(match, size_m=match.size_m * YOUNG_SCALE, how=match.how + f", {min(young)}: x {YOUNG_SCALE:g}")
    if qualifiers & FOLDED_WORDS and ("soft" in entry.tags or "flat" in entry.tags) and not match.has("agent"):
        match = replace(match, size_m=match.size_m * FOLDED_SCALE, how=match.how + f", folded: x {FOLDED_SCALE:g}")
    if entry.domain == "clothing and accessories" and "wrap" not in entry.tags:
        wearers = [m for w in qualifiers if (m := lexicon.lookup(w)) is not None and m.has("agent")]
        if wearers and wearers[-1].size_m < PERSON_M:
            scale = wearers[-1].size_m / PERSON_M
            match = replace(match, size_m=match.size_m * scale,
                            how=match.how + f", made for a {wearers[-1].phrase}: x {scale:.2g}")
    foods = [m for w in qualifiers if (m := lexicon.lookup(w)) is not None and m.entry.domain == "food and drink"]
    built = bool(qualifiers & CONFECTIONS) and entry.domain in {"buildings and places", "vehicles"}
    if foods and (match.has("agent") or built):
        size = TOY_SIZE_M if built else FOOD_FIGURE_M  # a gingerbread house is bigger than a gingerbread man
        match = replace(match, size_m=min(match.size_m, size), tags=match.tags - {"agent", "container"} | {"food"},
                        how=match.how + f", made of {foods[-1].phrase}: {size:g} m")
    if qualifiers & HOLLOW_WORDS and not match.has("container"):
        match = replace(match, tags=match.tags | {"container"}, how=match.how + ", hollow")
    return match


# Parts that are openings: "a bit in the chuck of a drill" goes into the chuck, not into the drill's material.
OPENINGS = lexicon.word_set("""
chuck slot socket hole keyhole mouth opening holder compartment pocket drawer tray slit spout neck
""")


def opening_after(prompt: str, cue_end: int) -> str | None:
    """The opening part a cue leads into ("in the slot of ..."), when the prompt names one right after it."""
    after = [w for start, w in prompt_words(prompt) if start >= cue_end][:3]
    while after and after[0] in _STOP:
        after.pop(0)
    return after[0] if after and after[0] in OPENINGS else None


def contents(prompt: str, mention_at: list[int], match: lexicon.Match | None, figure_name: str = "") -> str | None:
    """What fills the object, when it is ``filled`` or the prompt says so ("a mug of hot cocoa", "full of water");
    never the figure itself ("a wheelbarrow full of pumpkins" holds the pumpkins that are placed)."""
    found = _contents(prompt, mention_at, match)
    figure = lexicon.lookup(figure_name)
    head = figure.phrase.split()[-1] if figure is not None else (lexicon.words(figure_name) or [""])[-1]
    if found is not None and set(lexicon.singulars(head)) & set(lexicon.singulars(found)):
        return None  # the head only: a "paint roller" in a tray full of paint is no paint
    return found


def _object_of(prompt: str, cue_end: int, most: int = 3) -> list[tuple[int, str]]:
    """The cue's object: the first run of (at most ``most``) words after it that are no function words."""
    phrase: list[tuple[int, str]] = []
    for start, word in (t for t in prompt_words(prompt) if t[0] >= cue_end):
        if word in _STOP:
            if phrase:
                break
            continue
        phrase.append((start, word))
        if len(phrase) == most:
            break
    return phrase


def names_next(prompt: str, cue_end: int, mention_at: list[int]) -> bool:
    """Whether the noun phrase right after the cue (the cue's object) mentions the object."""
    return bool({start for start, _ in _object_of(prompt, cue_end, most=99)} & set(mention_at))


def about_another(prompt: str, cue_end: int, mention_at: list[int]) -> bool:
    """Whether the cue's object is a third thing: a noun phrase that mentions neither object, where the prompt
    mentions them elsewhere ("a cup on the table to the left of the plate": left of the plate, on the table); a
    pronoun ("behind it") is about them."""
    if not mention_at or _PRONOUN.match(prompt.lower(), cue_end):
        return False
    phrase = _object_of(prompt, cue_end)
    return bool(phrase) and not {start for start, _ in phrase} & set(mention_at)


_PRONOUN = re.compile(r"\s+(?:it|them|him|her|each other|one another)(?![a-z])")


def other_container(prompt: str, cue_end: int, mention_at: list[int]) -> bool:
    """Whether the cue leads into a third object, a container neither name mentions and no container "of" what
    fills it ("a candle in a bucket on the table": the candle is in the bucket, the bucket on the table)."""
    phrase = _object_of(prompt, cue_end)
    if not phrase or {start for start, _ in phrase} & set(mention_at):
        return False
    following = [w for start, w in prompt_words(prompt) if start > phrase[-1][0]][:1]
    known = lexicon.lookup(" ".join(w for _, w in phrase))
    return following != ["of"] and known is not None and known.has("container")


def substance_object(prompt: str, cue_end: int) -> bool:
    """Whether the cue's object is a bare substance ("above the water", "on the sand"), no object."""
    phrase = _object_of(prompt, cue_end)
    return bool(phrase) and phrase[-1][1] in CONTENTS


def contents_after(prompt: str, cue_end: int, figure_name: str = "", container: bool = False) -> str | None:
    """The contents the cue itself leads into, when its object is a substance or a drink rather than the ground
    ("dipped in melted chocolate in a bowl", "buried in the sand" of a beach, "stuck in a pina colada" in a glass),
    or, when the ground is a ``container``, what fills the one the cue leads into ("stuck in a bag of compost",
    a mesh named after a bucket)."""
    found = _object_of(prompt, cue_end)
    phrase = [word for _, word in found]
    if not phrase or set(phrase) & set(lexicon.words(figure_name)):
        return None
    if phrase[-1] in CONTENTS or (len(phrase) > 1 and phrase[-2] in _MELTED):  # its head: no "wine bottle"
        return phrase[-1]
    known = lexicon.lookup(" ".join(phrase))
    if known is not None and known.has("filled") and known.entry.domain == "food and drink":
        return " ".join(phrase)
    return contents(prompt, [found[-1][0]], None, figure_name) if container else None  # "a bag of compost"


def contents_named(prompt: str, mentions: list[int], figure_name: str = "") -> str | None:
    """A contents word the prompt says outside the objects' noun phrases ("a chip scooping salsa from a bowl",
    "a ladle stirring the soup in a pot"): what the ground holds, when the figure goes in it. A word right before
    a mention is that object's modifier ("a soup spoon"), never its contents, and so is the figure's own name."""
    tokens = prompt_words(prompt)
    starts = [start for start, _ in tokens]
    taken = {starts.index(at) - k for at in mentions if at in starts for k in range(3)}
    own = lexicon.forms(lexicon.words(figure_name))
    for i, (_, word) in enumerate(tokens):
        if i not in taken and word not in own and (word in CONTENTS or is_drink(word)):
            return word
    return None


def contents_in_name(name: str, figure_name: str = "") -> str | None:
    """The contents a container is named for ("compost_bin", "ink_pot"), not the figure's own name: what something
    stuck or buried in it goes into."""
    own = lexicon.forms(lexicon.words(figure_name))
    parts = [part for word in lexicon.words(name) for part in _compound(word)]
    found = [w for w in parts[:-1] if w not in own and (w in CONTENTS or is_drink(w))]
    return found[-1] if found else None


def _compound(word: str) -> list[str]:
    """A one-word compound of a contents word and a place or a receptacle that holds it, split in two ("sandpit",
    "snowbank", "mudflat", "inkwell"); any other word whole (a "sandwich", a "watermelon", a "teaspoon")."""
    for first in _CONTENTS_LONGEST_FIRST:
        if word.startswith(first) and word[len(first):] in HOLDS_CONTENTS:
            return [first, word[len(first):]]
    return [word]


def _contents(prompt: str, mention_at: list[int], match: lexicon.Match | None) -> str | None:
    if match is not None and match.has("filled"):
        return "its contents"
    if match is not None and match.phrase.split()[-1] in HEAPS:
        return f"the {match.phrase}"
    tokens = prompt_words(prompt)
    starts = [start for start, _ in tokens]
    for at in mention_at:
        if at not in starts:
            continue
        i = starts.index(at)
        if tokens[i][1] in HEAPS:
            return f"the {tokens[i][1]}"
        before = [w for _, w in tokens[max(0, i - 3):i]]
        if len(before) == 3 and before[1] == "of" and before[2] in _STOP and (
                before[0] in CONTENTS or is_drink(before[0])):
            return before[0]  # "in the sand of a sandbox", "the water of the pool"
        after = [w for _, w in tokens[i + 1:i + 6]]
        if after[:1] in (["full"], ["filled"]):
            after = after[1:]
        if after and after[0] in _FILL_WORDS:
            phrase = []
            for word in after[1:4]:  # the noun phrase after "of"/"with": its last word is its head
                if word in _STOP:
                    break
                phrase.append(word)
            for before, word in zip([None, *phrase], phrase, strict=False):
                if word in CONTENTS or before in _MELTED:
                    return word
            if phrase and _is_contents(phrase[-1], phrase[-2] if len(phrase) > 1 else None):
                return phrase[-1]
    return None
