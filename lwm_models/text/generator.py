"""The project's own Messenger description generator: a lexicon and sentence templates.

Every description names the entity (through a synonym of its identity), its role and its
movement, in varied word order, so that the project works with no outside text. The lexicon is
exposed for the rule-based parser (`parser.py`). Synonyms are unique across identities.
"""

from __future__ import annotations

import itertools
from functools import lru_cache

import numpy as np

from ..errors import InvalidSpecError
from ..messenger.constants import IDENTITIES, MOVEMENTS, ROLES, Triple

IDENTITY_SYNONYMS: dict[str, tuple[str, ...]] = {
    "airplane": ("airplane", "plane", "jet", "aircraft", "airliner"),
    "mage": ("mage", "wizard", "sorcerer", "magician", "warlock"),
    "dog": ("dog", "hound", "puppy", "canine", "mutt"),
    "bird": ("bird", "sparrow", "songbird", "feathered creature", "pigeon"),
    "fish": ("fish", "salmon", "trout", "swimmer with fins", "goldfish"),
    "scientist": ("scientist", "researcher", "chemist", "lab worker", "professor"),
    "thief": ("thief", "burglar", "robber", "pickpocket", "crook"),
    "ship": ("ship", "boat", "vessel", "sailboat", "steamer"),
    "ball": ("ball", "sphere", "orb", "round toy", "globe"),
    "robot": ("robot", "android", "automaton", "machine man", "droid"),
    "queen": ("queen", "monarch", "empress", "royal lady", "ruler"),
    "sword": ("sword", "blade", "saber", "longsword", "cutlass"),
}

# Noun phrases naming the role ("the deadly enemy"), and predicates ("is deadly to touch").
ROLE_NOUNS: dict[str, tuple[str, ...]] = {
    "enemy": ("enemy", "deadly enemy", "lethal opponent", "dangerous adversary", "hostile foe", "killer"),
    "message": ("message", "secret message", "important note", "classified document", "vital letter",
                "hidden parcel"),
    "goal": ("goal", "destination", "target receiver", "final objective", "recipient", "drop-off point"),
}
ROLE_PREDICATES: dict[str, tuple[str, ...]] = {
    "enemy": ("will kill you on contact", "is deadly to touch", "must be avoided"),
    "message": ("holds the secret you must grab", "carries the message you need", "has the note to pick up"),
    "goal": ("is where the message must be brought", "waits to receive the message", "is the place to deliver to"),
}
MOVEMENT_CLAUSES: dict[str, tuple[str, ...]] = {
    "chaser": ("comes toward you", "is chasing you", "pursues you", "keeps approaching you", "hunts you down"),
    "fleeing": ("runs away from you", "is fleeing from you", "avoids you", "keeps moving away", "escapes from you"),
    "immovable": ("never moves", "stays put", "is stationary", "does not move", "remains still"),
}
MOVEMENT_ADJECTIVES: dict[str, tuple[str, ...]] = {
    "chaser": ("approaching", "pursuing", "charging"),
    "fleeing": ("fleeing", "escaping", "retreating"),
    "immovable": ("motionless", "stationary", "unmoving"),
}

# Sentence templates over: {i} identity synonym, {r} role noun, {p} role predicate,
# {m} movement clause, {a} movement adjective.
TEMPLATES: tuple[str, ...] = (
    "the {i} is the {r} and {m}.",
    "the {i} that {m} is the {r}.",
    "the {r} is the {i}, which {m}.",
    "the {a} {i} is the {r}.",
    "the {r} is the {a} {i}.",
    "a {i} {m}; it is the {r}.",
    "the {i} {m} and {p}.",
    "beware: the {i} {p}, and it {m}.",
    "the {a} {r} is a {i}.",
    "it is the {i} that {p}; it {m}.",
    "you will find that the {i} {m}. it is the {r}.",
    "the {r}, a {i}, {m}.",
)


def _phrases(triple: Triple) -> list[str]:
    ident, mov, role = triple
    out = []
    for template in TEMPLATES:
        fields = {
            "i": IDENTITY_SYNONYMS[ident],
            "r": ROLE_NOUNS[role] if "{r}" in template else ("",),
            "p": ROLE_PREDICATES[role] if "{p}" in template else ("",),
            "m": MOVEMENT_CLAUSES[mov] if "{m}" in template else ("",),
            "a": MOVEMENT_ADJECTIVES[mov] if "{a}" in template else ("",),
        }
        for i, r, p, m, a in itertools.product(fields["i"], fields["r"], fields["p"], fields["m"], fields["a"]):
            out.append(template.format(i=i, r=r, p=p, m=m, a=a))
    return out


@lru_cache(maxsize=None)
def _all_for(triple: Triple) -> tuple[str, ...]:
    return tuple(sorted(set(_phrases(triple))))


def generate_descriptions(triple: Triple, per_triple: int = 120, seed: int = 0) -> list[str]:
    """Distinct descriptions of one (identity, movement, role) triple, in a fixed order.

    The full cross-product of the lexicon is large; a seeded sample of `per_triple` keeps the
    pools (and the text-encoder cache) small while every template and synonym still appears.
    """
    ident, mov, role = triple
    if ident not in IDENTITIES or mov not in MOVEMENTS or role not in ROLES:
        raise InvalidSpecError(f"unknown triple {triple!r}")
    everything = _all_for((ident, mov, role))
    if per_triple >= len(everything):
        return list(everything)
    rng = np.random.default_rng([seed, *(ord(c) for c in f"{ident}|{mov}|{role}")])
    chosen = np.sort(rng.choice(len(everything), size=per_triple, replace=False))
    return [everything[i] for i in chosen]


def add_typos(text: str, rng: np.random.Generator, rate: float) -> str:
    """Character-level typos (swap, drop or double a letter) in words chosen with probability
    `rate`; words of fewer than 3 letters are left alone, so the text never empties."""
    if rate <= 0:
        return text
    words = text.split(" ")
    for k, word in enumerate(words):
        if len(word) < 3 or rng.random() >= rate:
            continue
        j = int(rng.integers(len(word) - 1))
        kind = int(rng.integers(3))
        if kind == 0:
            word = word[:j] + word[j + 1] + word[j] + word[j + 2 :]
        elif kind == 1:
            word = word[:j] + word[j + 1 :]
        else:
            word = word[: j + 1] + word[j] + word[j + 1 :]
        words[k] = word
    return " ".join(words)
