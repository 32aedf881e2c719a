"""An offline rule-based parser of Messenger descriptions: which identity, movement and role a
description states. It stands in for the paper's ChatGPT in the GPTHard baseline (which only uses
the identity, to route a description to an entity), so call it what it is: a keyword parser.

Identity: the longest keyword match from a hand-written synonym list (wider than the generator's
lexicon, since people write "falcon", "scholar" or "humanoid"), earliest in the text on ties. A
description with no known keyword falls back to the nearest identity name in the frozen text
encoder's embedding space, when an encoder is given. Movement and role: ordered keyword rules
(negated motion before motion, "away" before "toward", enemy cues before goal and message cues).
Its accuracy on the human-written descriptions is measured by `lwm parser-accuracy` and in the
README.
"""

from __future__ import annotations

import re
from functools import lru_cache

import numpy as np

from ..messenger.constants import IDENTITIES, Triple
from .generator import IDENTITY_SYNONYMS

IDENTITY_KEYWORDS: dict[str, tuple[str, ...]] = {
    "airplane": (
        "airplane",
        "aeroplane",
        "plane",
        "jet",
        "aircraft",
        "airliner",
        "flying machine",
        "flying vessel",
        "flying vehicle",
        "glider",
        "bomber",
        "fighter jet",
        "airbus",
        "boeing",
        "flyer",
    ),
    "mage": (
        "mage",
        "wizard",
        "sorcerer",
        "sorceress",
        "magician",
        "warlock",
        "witch",
        "enchanter",
        "enchantress",
        "spellcaster",
        "spell caster",
        "conjurer",
        "necromancer",
        "shaman",
        "druid",
        "magic user",
        "illusionist",
        "mystic",
        "wizzard",
        "magic",
    ),
    "dog": (
        "dog",
        "hound",
        "puppy",
        "pup",
        "canine",
        "mutt",
        "pooch",
        "doggy",
        "doggo",
        "poodle",
        "terrier",
        "retriever",
        "beagle",
        "bulldog",
        "labrador",
        "mongrel",
        "cur",
    ),
    "bird": (
        "bird",
        "hawk",
        "falcon",
        "eagle",
        "sparrow",
        "pigeon",
        "parrot",
        "crow",
        "raven",
        "owl",
        "robin",
        "seagull",
        "gull",
        "songbird",
        "avian",
        "dove",
        "finch",
        "canary",
        "vulture",
        "fowl",
        "swallow",
    ),
    "fish": (
        "fish",
        "whale",
        "shark",
        "dolphin",
        "salmon",
        "trout",
        "tuna",
        "goldfish",
        "minnow",
        "carp",
        "cod",
        "guppy",
        "eel",
        "sea creature",
        "swimmer",
    ),
    "scientist": (
        "scientist",
        "researcher",
        "scholar",
        "professor",
        "chemist",
        "physicist",
        "biologist",
        "doctor",
        "academic",
        "inventor",
        "genius",
        "nerd",
        "man of science",
        "lab worker",
        "technician",
        "scientific",
        "science",
        "researches",
    ),
    "thief": (
        "thief",
        "burglar",
        "robber",
        "bandit",
        "criminal",
        "crook",
        "pickpocket",
        "stealer",
        "outlaw",
        "rogue",
        "looter",
        "mugger",
        "felon",
        "swindler",
        "thug",
        "kleptomaniac",
        "pilfer",
        "pilferer",
        "stealing",
        "steals",
    ),
    "ship": (
        "ship",
        "boat",
        "vessel",
        "sailboat",
        "yacht",
        "ferry",
        "steamer",
        "cruiser",
        "canoe",
        "submarine",
        "barge",
        "frigate",
        "schooner",
        "galleon",
        "tanker",
        "raft",
        "ocean liner",
    ),
    "ball": (
        "ball",
        "sphere",
        "orb",
        "globe",
        "football",
        "soccer ball",
        "basketball",
        "baseball",
        "round object",
        "beach ball",
        "round toy",
    ),
    "robot": (
        "robot",
        "android",
        "droid",
        "automaton",
        "cyborg",
        "machine",
        "mech",
        "bot",
        "humanoid",
        "robotic",
        "hominid",
    ),
    "queen": (
        "queen",
        "monarch",
        "empress",
        "princess",
        "royal",
        "royalty",
        "ruler",
        "sovereign",
        "majesty",
        "duchess",
        "regal",
        "crowned",
    ),
    "sword": (
        "sword",
        "blade",
        "saber",
        "sabre",
        "longsword",
        "katana",
        "cutlass",
        "rapier",
        "dagger",
        "knife",
        "scimitar",
        "broadsword",
    ),
}

# Checked in this order; the first rule with a match wins.
MOVEMENT_RULES: tuple[tuple[str, tuple[str, ...]], ...] = (
    (
        "immovable",
        (
            "not moving",
            "not move",
            "n't move",
            "never move",
            "doesn't move",
            "won't move",
            "isn't moving",
            "stationary",
            "still",
            "immobile",
            "motionless",
            "unmoving",
            "static",
            "stays put",
            "stay put",
            "in place",
            "fixed",
            "stuck",
            "rooted",
            "frozen",
            "idle",
            "standing",
            "sitting",
            "sits",
            "remains",
            "stays",
            "immovable",
            "not going anywhere",
            "planted",
            "parked",
            "budge",
            "cannot be moved",
            "can't move",
            "cannot move",
            "can not move",
            "unable to move",
            "relocat",
            "standstill",
            "stand still",
            "immobil",
            "unmov",
            "inert",
            "stopped",
            "resting",
            "rests",
            "at rest",
            "stationery",
            "stand",
            "stuck",
            "doesn't movie",
        ),
    ),
    (
        "fleeing",
        (
            "flee",
            "fleeing",
            "flees",
            "run away",
            "runs away",
            "running away",
            "ran away",
            "escape",
            "escaping",
            "avoid",
            "away from",
            "evad",
            "retreat",
            "dodg",
            "run from",
            "runs from",
            "running from",
            "moving away",
            "moves away",
            "getting away",
            "get away",
            "gets away",
            "scared",
            "afraid",
            "fled",
            "elusive",
            "backing",
            "shy",
            "on the run",
            "runs off",
            "running off",
            "withdraw",
            "leaving",
            "keeps its distance",
            "distanc",
            "run off",
        ),
    ),
    (
        "chaser",
        (
            "chas",
            "approach",
            "toward",
            "towards",
            "pursu",
            "follow",
            "coming",
            "come at",
            "comes at",
            "hunt",
            "after you",
            "closer",
            "advanc",
            "stalk",
            "track",
            "heading for you",
            "heads to you",
            "moving to you",
            "moves to you",
            "coming at",
            "charging",
            "charges",
            "near you",
            "nearer",
            "heading",
            "on its way",
            "draws near",
            "getting close",
            "comes for you",
            "coming for you",
            "moving",
            "moves",
            "mobile",
        ),
    ),
)
ROLE_RULES: tuple[tuple[str, tuple[str, ...]], ...] = (
    (
        "enemy",
        (
            "enemy",
            "enemies",
            "deadly",
            "lethal",
            "danger",
            "kill",
            "opponent",
            "adversary",
            "foe",
            "hostile",
            "threat",
            "harm",
            "attacker",
            "assassin",
            "fatal",
            "death",
            "evil",
            "villain",
            "antagonist",
            "poison",
            "murder",
            "menace",
            "avoid at all",
            "hurt",
            "bad guy",
            "rival",
            "perilous",
            "inimical",
            "hazard",
            "risk",
            "venom",
            "destroy",
            "unfriendly",
        ),
    ),
    (
        "goal",
        (
            "goal",
            "destination",
            "objective",
            "target",
            "receiver",
            "recipient",
            "deliver",
            "receive",
            "drop off",
            "drop-off",
            "end point",
            "endpoint",
            "bring the",
            "take the message",
            "finish",
            "where the message",
            "aim",
            "send",
        ),
    ),
    (
        "message",
        (
            "message",
            "note",
            "document",
            "letter",
            "secret",
            "information",
            "intel",
            "memo",
            "mail",
            "parcel",
            "package",
            "classified",
            "report",
            "data",
            "code",
            "file",
            "paper",
            "scroll",
            "item",
            "news",
            "communiqu",
            "dossier",
            "missive",
            "text",
            "communication",
            "object",
            "crucial",
            "important",
        ),
    ),
)


def _pattern(words: tuple[str, ...]) -> re.Pattern:
    return re.compile(r"\b(" + "|".join(re.escape(w) for w in sorted(words, key=len, reverse=True)) + r")")


_IDENTITY_PATTERNS = {
    ident: re.compile(r"\b(" + "|".join(re.escape(w) for w in sorted(kws, key=len, reverse=True)) + r")s?\b")
    for ident, kws in IDENTITY_KEYWORDS.items()
}
_MOVEMENT_PATTERNS = [(m, _pattern(w)) for m, w in MOVEMENT_RULES]
_ROLE_PATTERNS = [(r, _pattern(w)) for r, w in ROLE_RULES]


def parse_identity(text: str, encoder=None) -> str | None:
    """The identity a description is about: longest keyword, earliest on ties; else nearest name
    in the encoder's embedding space (if given); else None."""
    lowered = text.lower()
    best = None
    for ident, pattern in _IDENTITY_PATTERNS.items():
        for m in pattern.finditer(lowered):
            key = (-(m.end() - m.start()), m.start())
            if best is None or key < best[0]:
                best = (key, ident)
    if best is not None:
        return best[1]
    if encoder is not None:
        return _nearest_identity(text, encoder)
    return None


def _first_rule(text: str, rules) -> str | None:
    lowered = text.lower()
    for name, pattern in rules:
        if pattern.search(lowered):
            return name
    return None


def parse_movement(text: str) -> str | None:
    return _first_rule(text, _MOVEMENT_PATTERNS)


def parse_role(text: str) -> str | None:
    return _first_rule(text, _ROLE_PATTERNS)


def parse_description(text: str, encoder=None) -> tuple[str | None, str | None, str | None]:
    """(identity, movement, role) as the parser reads them; None where it finds no cue."""
    return parse_identity(text, encoder), parse_movement(text), parse_role(text)


def route_identity_id(text: str) -> int:
    """GPTHard's routing: the observation id of the parsed identity, 0 when there is none."""
    ident = parse_identity(text)
    return IDENTITIES[ident] if ident else 0


@lru_cache(maxsize=2)
def _prototypes(encoder) -> tuple[list[str], np.ndarray]:
    names, texts = [], []
    for ident, synonyms in IDENTITY_SYNONYMS.items():
        for s in synonyms:
            names.append(ident)
            texts.append(f"the {s}.")
    feats, lengths = encoder.encode_arrays(texts)
    return names, _mean_unit(feats, lengths)


def _mean_unit(feats: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    mask = np.arange(feats.shape[1])[None, :] < lengths[:, None]
    mean = (feats.astype(np.float32) * mask[..., None]).sum(1) / np.maximum(lengths[:, None], 1)
    return mean / np.linalg.norm(mean, axis=-1, keepdims=True).clip(1e-6)


def _nearest_identity(text: str, encoder) -> str:
    names, protos = _prototypes(encoder)
    feats, lengths = encoder.encode_arrays([text])
    return names[int(np.argmax(protos @ _mean_unit(feats, lengths)[0]))]


def parser_accuracy(texts_by_triple: dict[Triple, list[str]], encoder=None) -> dict[str, float | int]:
    """Identity, movement and role accuracy of the parser on labelled descriptions."""
    n = correct_i = correct_m = correct_r = 0
    for (ident, mov, role), texts in texts_by_triple.items():
        for t in texts:
            pi, pm, pr = parse_description(t, encoder)
            n += 1
            correct_i += pi == ident
            correct_m += pm == mov
            correct_r += pr == role
    return {
        "descriptions": n,
        "identity": correct_i / max(n, 1),
        "movement": correct_m / max(n, 1),
        "role": correct_r / max(n, 1),
    }
