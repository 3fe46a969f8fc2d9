"""Typical real sizes of common objects, and how object names map onto them.

The rule-based prior needs a size for each named object (the size ratio is their quotient) and a few
coarse shape facts that decide contact and penetration (is it a container, is it pointed, flat, round,
soft, does it wrap around what wears it, is it someone who can hold or wear things). A language model
knows these; without one, this table is the knowledge.

Sizes are the *longest side* of the object's bounding box in metres, for a typical real instance (a
guess good to a factor of about two). The table is a data file beside this module, ``lexicon.txt``; its rows:
``name[/alias...] size [tag,tag...]`` with ``_`` for spaces; plurals are handled by ``singular`` so rows list
singular forms only.

Tags:
- ``container``: has a cavity or opening things go into without cutting (cup, box, bun, keyhole).
- ``pointed``: thin or sharp enough to be pushed into a solid (knife, arrow, nail, candle, flag).
- ``staked``: pointed and made to stand stuck in what it is put on (candle, flag, toothpick): "on" a
  pierceable solid (a cake, a sandcastle) it goes into it, where a knife or a fork would lie on top.
- ``flat``: a sheet or slice that lies on one face (pepperoni, poster, sticker).
- ``round``: ball-like; touches a support at a point.
- ``soft``: drapes or settles onto a support (cushion, cat, towel).
- ``wrap``: a garment or band that hugs what wears it (scarf, glove, collar).
- ``agent``: a person, character or animal that can hold, wear, ride.
- ``aquatic``: a creature that lives under water (a fish, a jellyfish): in a liquid it is wholly under.
- ``pierceable``: a solid a pointed thing goes into when pushed (wood, soil, foam, a dartboard, fabric); solid
  food, plants and ``soft`` things are pierceable without the tag.
- ``bites``: a creature whose bite or sting pierces the skin (a mosquito, a tick, a wasp): biting or stinging
  someone, it goes into them.
- ``filled``: holds contents that close its opening off (a drink, a soup, a pond): what goes *in* it passes
  below the surface of the contents, so it penetrates (the prompt can say so too: "a mug of cocoa").

Each row belongs to the section it is listed under (``Entry.domain``): the domain decides between the senses of
a word listed in more than one row (``~mouse`` in a later row: the computer mouse is another sense of "mouse";
``SENSES``), by the other object of the prompt.

Names like ``rooster_comb`` or ``teapot_lid`` are parts: ``PART_SIZES`` gives a part's size as a fraction
of its owner's, so any owner in the table works without listing every pair.
"""

from __future__ import annotations

import re
import unicodedata
from collections.abc import Iterable
from dataclasses import dataclass
from importlib import resources

# A part's size as a fraction of its owner's ("teapot lid": 0.6 of a teapot); a holder named for what it holds
# ("ring box", "guitar case") is sized from that.
PART_SIZES: dict[str, float] = {
    "lid": 0.6, "cap": 0.4, "cover": 1.0, "case": 1.0, "box": 1.5, "sheath": 1.0, "holder": 1.3, "base": 0.7,
    "stand": 0.8, "handle": 0.4, "jar": 0.6, "tank": 0.6, "container": 0.6, "comb": 0.15, "top": 0.5,
    "seat": 0.4, "wheel": 0.3, "door": 0.5, "roof": 1.0, "blade": 0.6, "tip": 0.1, "head": 0.3,
    "leg": 0.5, "shade": 0.4, "bulb": 0.2, "slice": 0.5, "piece": 0.3, "half": 0.8, "wing": 0.4,
    "tail": 0.4, "nose": 0.1, "cube": 0.3, "chunk": 0.3, "stick": 1.0,
}
# A holder of a long thin thing (a toothbrush, a pen, a brush) is a cup shorter than what it holds.
POINTED_HOLDER = 0.6
# Pieces only a food is cut into ("a bread cube", "a carrot stick"; a "wood cube" is a block).
FOOD_PIECES = frozenset({"cube", "chunk", "stick"})
# The parts a person, character or animal has (a "hamster wheel" is no part of a hamster).
AGENT_PARTS = frozenset({"head", "leg", "tail", "wing", "nose", "comb", "tip"})
# The parts a food has, and what holds one (a "pizza box"; a "wheel of cheese" is a whole cheese, no cheese's wheel).
FOOD_PARTS = frozenset({"slice", "piece", "half", "top", "tip", "base", "wing", "leg", "lid", "box", "cube", "chunk",
                        "stick"})
# Holders named for what they hold ("ring box", "pizza box"): only things small enough to be held ("roof box").
HOLDERS = frozenset({"box", "case", "holder"})
HOLDER_MAX_M = 1.2
# Parts made to come off their owner: a name that is only one of these ("lid") is sized from the other object.
DETACHABLE = frozenset({"lid", "cap", "cover", "case", "sheath", "stand", "base", "handle", "top"})
# Parts that hold their owner (a lipstick's cover, a blender's jar) are containers.
CONTAINER_PARTS = frozenset({"cover", "case", "sheath", "holder", "jar", "tank", "container", "cap", "box"})
# Parts that hug their owner's surface (a car cover).
WRAPPING_PARTS = frozenset({"cover"})

# Size adjectives in a name ("ball_small", "BigRock").
SIZE_WORDS: dict[str, float] = {
    "tiny": 0.3, "mini": 0.5, "miniature": 0.3, "small": 0.5, "little": 0.5,
    "big": 2.0, "large": 2.0, "huge": 4.0, "giant": 5.0, "enormous": 5.0,
}

# Materials name the object only when nothing else does ("table wood" is a table, "wood" is wood).
# Substances: an unknown thing named after one ("sand dune", "snow bank") says nothing about its size.
SUBSTANCES = frozenset({"sand", "dirt", "soil", "snow", "mud", "water", "ice", "grass", "hay", "sugar", "salt"})
MATERIALS = frozenset({"wood", "stone", "glass", "metal", "gold", "silver", "plastic", "paper", "marble", "clay",
                       "steel", "iron", "leather", "rock", "fabric", "cloth", "felt", "cotton", "denim", "silk",
                       "velvet", "linen", "wool", "yarn", "oak", "pine", "walnut", "maple", "birch", "teak", "mahogany",
                       "cedar", "bamboo", "brass", "copper", "bronze", "chrome", "porcelain", "ceramic", "rubber",
                       "resin"})


def word_set(text: str) -> frozenset[str]:
    """The whitespace-separated words of a table of words."""
    return frozenset(text.split())


# Words a file name or a prompt puts around an object's head noun that do not name an object: colours, styles,
# file-format and asset-pipeline words ("Rubber_Duck_Yellow", "old_lamp_lowpoly", "SM_Chair_02").
NON_HEAD_WORDS = word_set("""
red green blue yellow white black brown grey gray pink purple beige golden dark light bright pale striped
old new vintage antique modern classic rusty broken clean dirty simple cartoon stylized stylised realistic cute
low high poly lowpoly highpoly hi res detailed model mesh obj fbx glb gltf stl ply sm geo lod copy asset prop
final version var variant wooden metallic plastic ceramic round square tall short long wide empty open closed
""")


@dataclass(frozen=True)
class Entry:
    """One table row: the canonical name (first alias), its longest side in metres and its tags."""

    name: str
    size_m: float
    tags: frozenset[str]
    domain: str = ""  # the table section: "animals", "vehicles" ...


@dataclass(frozen=True)
class Match:
    """What a name resolved to: the matched phrase, its size after part/adjective scaling, tags, how."""

    phrase: str
    entry: Entry  # the head's row; for a part ("teapot lid"), the owner's
    size_m: float
    tags: frozenset[str]
    how: str  # e.g. "lid of a teapot (0.6 x 0.25 m)"

    def has(self, tag: str) -> bool:
        return tag in self.tags


def _parse_table(text: str) -> tuple[dict[str, Entry], dict[str, list[Entry]]]:
    """Rows to (alias -> entry, word -> its senses, the plain row first): ``~word`` in a row adds a sense."""
    table: dict[str, Entry] = {}
    senses: dict[str, list[Entry]] = {}
    domain = ""
    for line in text.splitlines():
        line = line.strip()
        if line.startswith("# ---"):
            domain = line.strip("#- ")
        if not line or line.startswith("#"):
            continue
        names, size, *tags = line.split()
        aliases = [a.replace("_", " ") for a in names.split("/")]
        entry = Entry(aliases[0], float(size), frozenset(tags[0].split(",")) if tags else frozenset(), domain)
        for alias in aliases:
            if alias.startswith("~"):
                senses.setdefault(alias[1:], []).append(entry)
                continue
            if alias in table:
                raise ValueError(f"lexicon alias {alias!r} listed twice")
            table[alias] = entry
    return table, {word: [table[word], *others] for word, others in senses.items()}


LEXICON, SENSES = _parse_table((resources.files(__package__) / "lexicon.txt").read_text(encoding="utf-8"))
MAX_WORDS = max(len(k.split()) for k in LEXICON)

_IRREGULAR = {
    "people": "person", "men": "man", "women": "woman", "children": "child", "teeth": "tooth", "feet": "foot",
    "mice": "mouse", "geese": "goose", "knives": "knife", "leaves": "leaf", "loaves": "loaf", "wolves": "wolf",
    "shelves": "shelf", "halves": "half", "scarves": "scarf", "calves": "calf", "cacti": "cactus",
}


def singulars(word: str) -> list[str]:
    """The word and its plausible English singulars, most likely first ("boxes" -> box, boxe)."""
    if word in _IRREGULAR:
        return [_IRREGULAR[word], word]
    forms = [word]
    if len(word) > 3 and word.endswith("s") and not word.endswith(("ss", "us", "is")):
        if word.endswith("ies"):
            forms.append(word[:-3] + "y")
        if word.endswith("es"):
            forms.append(word[:-2])
        forms.append(word[:-1])
    return forms


def forms(tokens: Iterable[str]) -> set[str]:
    """All the forms ``singulars`` gives of the tokens: to match words whatever their number."""
    return {form for token in tokens for form in singulars(token)}


def words(text: str) -> list[str]:
    """Lower-case word tokens of a file-style or prose name ("CoffeeCup_02" -> ["coffee", "cup"])."""
    text = unicodedata.normalize("NFKD", text).encode("ascii", "ignore").decode()  # "Ståtue" -> "Statue"
    text = re.sub(r"(?<=[a-z])(?=[A-Z])", " ", text)  # camelCase
    text = re.sub(r"['’]s\b", " ", text)  # possessive: "the ball's head"
    return re.findall(r"[a-z]+", text.lower())


def phrase_entry(tokens: list[str]) -> tuple[str, Entry] | None:
    """(matched phrase, entry) for a token run, trying the last word's singulars and the run as one word."""
    for last in singulars(tokens[-1]):
        form = [*tokens[:-1], last]
        for candidate in (" ".join(form), "".join(form)):
            if candidate in LEXICON:
                return candidate, LEXICON[candidate]
    return None


def spans(tokens: list[str]) -> list[tuple[int, int, str, Entry]]:
    """Known phrases in ``tokens`` as (start, end, phrase, entry): longest match first, left to right."""
    found, i = [], 0
    while i < len(tokens):
        for n in range(min(MAX_WORDS + 1, len(tokens) - i), 0, -1):
            hit = phrase_entry(tokens[i:i + n])
            if hit is not None:
                found.append((i, i + n, *hit))
                i += n
                break
        else:
            i += 1
    return found


def bare_part(name: str, owner_name: str = "") -> str | None:
    """The detachable part a name is, when nothing else in it is known ("Lid_01" -> "lid", "pot_lid" -> None) or
    its other words are words of its owner's name ("soldering_stand" of a "soldering_iron")."""
    tokens = words(name)
    for i in reversed(range(len(tokens))):
        part = next((w for w in singulars(tokens[i]) if w in DETACHABLE), None)
        if part is not None:
            if any(start <= i < end and end - start > 1 for start, end, _, _ in spans(tokens)):
                return None  # a compound that is an object of its own: "spinning top", "coat stand"
            others = [t for t in tokens[:i] + tokens[i + 1:] if t not in NON_HEAD_WORDS and len(t) > 2]
            return None if set(others) - set(words(owner_name)) else part  # "music stand": not a bare part
    return None


def lookup(name: str) -> Match | None:
    """Resolve an object name to a size, or None when nothing in it is known.

    The head of an English compound is its last noun ("coffee cup" is a cup), so the rightmost known
    phrase wins (materials, wood species and metals included, only when alone: "CoffeeTable_Oak_02" is a
    coffee table); a last word naming a part after a known owner ("teapot
    lid", "blender_tank") is sized as a fraction of the owner. Size adjectives in the name
    ("ball_small") scale the result; colours, styles and file-pipeline words ("_lowpoly", "_Yellow")
    are not heads. An unknown last word is the head all the same: a closed compound ends in a known
    word ("shoebox" is a box), otherwise the object is named after the known word before it ("pencil
    sharpener"): its size is a guess from that word, and none of that word's shape tags apply.
    """
    tokens = [t for t in words(name) if t not in SIZE_WORDS]
    scale = 1.0
    for token in words(name):
        scale *= SIZE_WORDS.get(token, 1.0)
    while tokens and (tokens[-1] in NON_HEAD_WORDS or len(tokens[-1]) < 3):
        tokens.pop()
    known = spans(tokens)
    found = [f for f in known if f[2] not in MATERIALS] or known
    part = next((w for w in singulars(tokens[-1]) if w in PART_SIZES), None) if tokens else None
    if part is not None and not any(end == len(tokens) and end - start > 1 for start, end, _, _ in found):
        owners = [f for f in found if f[1] < len(tokens) and (part in AGENT_PARTS or "agent" not in f[3].tags)
                  and (part in FOOD_PARTS or f[3].domain != "food and drink")
                  and (part not in HOLDERS or f[3].size_m <= HOLDER_MAX_M)
                  and (part not in FOOD_PIECES or f[3].domain == "food and drink")]
        if owners:
            _, _, phrase, owner = owners[-1]
            fraction = POINTED_HOLDER if part == "holder" and "pointed" in owner.tags else PART_SIZES[part]
            size = owner.size_m * fraction * scale
            tags = frozenset({"container"}) if part in CONTAINER_PARTS else frozenset()
            tags |= {"wrap"} if part in WRAPPING_PARTS else set()
            return Match(part, owner, size, tags, f"{part} of a {phrase} ({fraction:g} x {owner.size_m:g} m)")
    if tokens and not any(end == len(tokens) for _, end, _, _ in known):
        head_word = tokens[-1]
        closed = closed_compound(head_word)
        if closed is not None:
            phrase, head = closed
            return Match(phrase, head, head.size_m * scale, head.tags,
                         f"'{head_word}': a kind of {phrase} ({head.size_m:g} m)")
        if (not found or found[-1][3].domain == "food and drink" or "agent" in found[-1][3].tags
                or found[-1][2] in SUBSTANCES | MATERIALS):
            return None  # a "pizza cutter" is not pizza-sized, nor a "spider web" spider-sized, nor a "sand dune" sandy
        start, _, phrase, known = found[-1]
        named = " ".join(tokens[start:])
        how = f"'{named}': unknown '{head_word}' named after a {phrase}, sized like one ({known.size_m:g} m)"
        return Match(named, known, known.size_m * scale, frozenset(), how)
    if not found:
        return None
    _, _, phrase, head = found[-1]
    how = f"'{phrase}' ({head.size_m:g} m)" + (f" x {scale:g} (size word)" if scale != 1.0 else "")
    return Match(phrase, head, head.size_m * scale, head.tags, how)


def closed_compound(word: str) -> tuple[str, Entry] | None:
    """A one-word compound's known head: the longest known word it ends in, after a known stem ("shoe|box") or
    for a head of 5+ letters, after any stem ("hour|glass"); "tur|key" is no key, "stoc|king" no king."""
    for k in range(3, len(word) - 2):
        hit = phrase_entry([word[k:]])
        if hit is not None and (len(word) - k >= 5 or phrase_entry([word[:k]]) is not None):
            return hit
    return None
