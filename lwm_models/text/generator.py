"""The project's own Messenger description generator: a lexicon and sentence templates.

The benchmark's human-written descriptions may not be shipped with the project, so the project
writes its own: short lower-case sentences that each name one entity (through a synonym of its
identity), its role and its movement, in varied word order ("the stationary jet is the deadly
adversary.", "the receiver is a hound that runs away from you."). The wording is this module's
own; the lexicon is exposed so that a rule-based parser can map a description back to its triple.

Lexicon guarantees (checked by tests/test_text.py):
- no identity synonym belongs to two identities, and no role or movement phrase contains an
  identity synonym as a word, so the identity of a description is unambiguous;
- role and movement phrases can overlap in words ("message" is a message noun, and "is where the
  message must go" a goal predicate), so a parser must prefer the longest phrase that matches.
"""

from __future__ import annotations

from functools import cache

import numpy as np

from ..errors import InvalidSpecError
from ..messenger.constants import IDENTITIES, MOVEMENTS, ROLES, Triple

IDENTITY_SYNONYMS: dict[str, tuple[str, ...]] = {
    "airplane": ("airplane", "plane", "jet", "aircraft", "airliner", "flying machine"),
    "mage": ("mage", "wizard", "sorcerer", "magician", "warlock", "spellcaster"),
    "dog": ("dog", "hound", "puppy", "canine", "mutt", "pooch"),
    "bird": ("bird", "eagle", "hawk", "sparrow", "songbird", "pigeon"),
    "fish": ("fish", "trout", "salmon", "goldfish", "minnow", "carp"),
    "scientist": ("scientist", "researcher", "chemist", "lab worker", "professor", "physicist"),
    "thief": ("thief", "burglar", "robber", "pickpocket", "crook", "bandit"),
    "ship": ("ship", "boat", "vessel", "sailboat", "yacht", "ferry"),
    "ball": ("ball", "sphere", "orb", "football", "beach ball", "round toy"),
    "robot": ("robot", "android", "automaton", "droid", "cyborg", "mech"),
    "queen": ("queen", "monarch", "empress", "royal lady", "ruler", "sovereign"),
    "sword": ("sword", "blade", "saber", "longsword", "cutlass", "katana"),
}
"""Identity -> synonyms (the identity's own name first). Unique across identities."""

ROLE_NOUNS: dict[str, tuple[str, ...]] = {
    "enemy": ("enemy", "deadly enemy", "lethal opponent", "deadly adversary", "dangerous foe", "killer"),
    "message": (
        "message",
        "secret document",
        "crucial message",
        "important note",
        "classified letter",
        "vital information",
    ),
    "goal": ("goal", "objective", "destination", "receiver", "recipient", "final target"),
}
"""Noun phrases naming a role, used after "the" ("the deadly adversary")."""

ROLE_PREDICATES: dict[str, tuple[str, ...]] = {
    "enemy": (
        "will kill you on contact",
        "is deadly to touch",
        "must never be touched",
        "kills you if you bump into it",
    ),
    "message": (
        "carries the secret you must grab",
        "holds the note you need",
        "has the document to pick up",
        "is the item you must collect first",
    ),
    "goal": (
        "is where the message must go",
        "is where you deliver the message",
        "receives the message",
        "is the place to drop off the message",
    ),
}
"""Verb phrases stating a role, used after a subject ("the jet will kill you on contact")."""

MOVEMENT_CLAUSES: dict[str, tuple[str, ...]] = {
    "chaser": (
        "comes toward you",
        "is chasing you",
        "pursues you",
        "keeps approaching you",
        "hunts you down",
        "follows you around",
    ),
    "fleeing": (
        "runs away from you",
        "is fleeing",
        "avoids you",
        "keeps moving away",
        "escapes from you",
        "tries to get away",
    ),
    "immovable": (
        "stays put",
        "never moves",
        "is stationary",
        "does not move",
        "remains still",
        "is rooted to the spot",
    ),
}
"""Verb phrases stating a movement, used after a subject ("the jet pursues you")."""

MOVEMENT_ADJECTIVES: dict[str, tuple[str, ...]] = {
    "chaser": ("pursuing", "chasing", "charging"),
    "fleeing": ("fleeing", "escaping", "retreating"),
    "immovable": ("motionless", "stationary", "unmoving"),
}
"""Adjectives stating a movement, used before a noun ("the motionless jet")."""

ROLE_PHRASES: dict[str, tuple[str, ...]] = {r: ROLE_NOUNS[r] + ROLE_PREDICATES[r] for r in ROLES}
"""Every phrase that states a role (nouns and predicates), for a parser."""
MOVEMENT_PHRASES: dict[str, tuple[str, ...]] = {m: MOVEMENT_CLAUSES[m] + MOVEMENT_ADJECTIVES[m] for m in MOVEMENTS}
"""Every phrase that states a movement (clauses and adjectives), for a parser."""

# Sentence templates. Slots: {i} identity synonym after "the"; {ai} the synonym with "a"/"an";
# {r} role noun; {p} role predicate; {m} movement clause; {a} movement adjective; {aa} the
# adjective with "a"/"an". Every template has exactly one identity, one role and one movement slot.
TEMPLATES: tuple[str, ...] = (
    # identity first
    "the {i} is the {r} and it {m}.",
    "the {i} {m} and is the {r}.",
    "the {i}, which {m}, is the {r}.",
    "the {i} that {m} is the {r}.",
    "the {a} {i} is the {r}.",
    "the {i} {p} and {m}.",
    "the {i} {m}. it {p}.",
    "the {i} plays the role of the {r} and {m}.",
    "{ai} that {m} {p}.",
    # role first
    "the {r} is the {i}, and it {m}.",
    "the {r} is {ai} that {m}.",
    "the {r} is the {a} {i}.",
    "the {a} {r} is the {i}.",
    "the {r}, {ai}, {m}.",
    # movement first
    "there is {aa} {i}; it is the {r}.",
    "the one that {m} is the {i}, and it {p}.",
    "you will meet the {i}, the {r}, which {m}.",
)


def _with_article(phrase: str) -> str:
    return ("an " if phrase[0] in "aeiou" else "a ") + phrase


def _check_triple(triple: Triple) -> Triple:
    if len(triple) != 3:
        raise InvalidSpecError(f"a triple is (identity, movement, role), got {triple!r}")
    ident, mov, role = triple
    if ident not in IDENTITIES:
        raise InvalidSpecError(f"unknown identity {ident!r}; known: {sorted(IDENTITIES)}")
    if mov not in MOVEMENTS:
        raise InvalidSpecError(f"unknown movement {mov!r}; known: {list(MOVEMENTS)}")
    if role not in ROLES:
        raise InvalidSpecError(f"unknown role {role!r}; known: {list(ROLES)}")
    return (ident, mov, role)


@cache
def _descriptions(triple: Triple) -> tuple[str, ...]:
    """Each template is filled once per identity synonym; the role and movement phrase rotate
    with the synonym and the template, so every phrase of the lexicon is used while a triple keeps
    about a hundred descriptions (the full cross-product would be thousands, all near-duplicates)."""
    ident, mov, role = triple
    out: dict[str, None] = {}
    for t, template in enumerate(TEMPLATES):
        for s, syn in enumerate(IDENTITY_SYNONYMS[ident]):
            nouns, preds = ROLE_NOUNS[role], ROLE_PREDICATES[role]
            clauses, adjs = MOVEMENT_CLAUSES[mov], MOVEMENT_ADJECTIVES[mov]
            adj = adjs[(s + 2 * t) % len(adjs)]
            text = template.format(
                i=syn,
                ai=_with_article(syn),
                r=nouns[(s + t) % len(nouns)],
                p=preds[(s + t) % len(preds)],
                m=clauses[(s + 2 * t + 1) % len(clauses)],
                a=adj,
                aa=_with_article(adj),
            )
            out[text] = None
    return tuple(out)


def generate_descriptions(triple: Triple) -> list[str]:
    """All distinct generated descriptions of one (identity, movement, role) triple.

    The order is fixed (template by template, synonym by synonym), so pools built from it depend
    only on their seed. Raises InvalidSpecError for unknown names.
    """
    return list(_descriptions(_check_triple(tuple(triple))))  # type: ignore[arg-type]


def add_typos(text: str, rng: np.random.Generator, rate: float) -> str:
    """Character-level typos, like those of the human-written manuals.

    Each word with at least 3 letters is hit with probability `rate` by one of: swapping two
    adjacent different letters, dropping a letter, or doubling a letter. Only letters are touched
    (punctuation such as the final period stays) and a word keeps at least 2 letters, so the text
    never empties. `rate` <= 0 returns the text unchanged without using `rng`.
    """
    if rate <= 0:
        return text
    words = text.split(" ")
    for k, word in enumerate(words):
        letters = [j for j, c in enumerate(word) if c.isalpha()]
        if len(letters) < 3 or rng.random() >= rate:
            continue
        kind = int(rng.integers(3))
        if kind == 0:
            pairs = [j for j in letters[:-1] if word[j + 1].isalpha() and word[j + 1] != word[j]]
            if pairs:
                j = pairs[int(rng.integers(len(pairs)))]
                words[k] = word[:j] + word[j + 1] + word[j] + word[j + 2 :]
                continue
            kind = 2  # nothing to swap ("zzz"): double a letter instead
        j = letters[int(rng.integers(len(letters)))]
        if kind == 1:
            words[k] = word[:j] + word[j + 1 :]
        else:
            words[k] = word[: j + 1] + word[j] + word[j + 1 :]
    return " ".join(words)
