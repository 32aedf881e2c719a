"""An offline rule-based parser of Messenger descriptions: which identity, movement and role a
description states. It stands in for the paper's ChatGPT in the GPTHard baseline (which only uses
the identity, to route a description to an entity), so call it what it is: a keyword parser.

Identity: the longest keyword match from a hand-written synonym list (wider than the generator's
lexicon, since people write "falcon", "scholar" or "humanoid"; a plural or a pet form such as
"birdie" counts), earliest in the text on ties. A word one typo away from a keyword (a letter
swapped, dropped, doubled or changed; five letters or more, swaps only for four) counts as that
keyword. A description with no known keyword falls back, when an encoder is given, to a misspelt
name (a word the encoder's vocabulary lacks, one typo from a keyword of three letters or more:
"dgo", "quen"), else to the nearest identity name in the frozen text encoder's embedding space.

Movement and role: ordered keyword rules (negated motion before motion, "away" before "toward",
enemy cues before goal and message cues), read after the same typo correction. Idioms that hold
another value's cue come first ("stays away" before "stays", "where the message is" before "where
the message goes"); common words one letter from a keyword are correction targets of their own, so
that "carried" stays "carried". A cue inside a
negation's scope does not count: "the hound is not the goal" says nothing for goal. A scope runs
from "not", "n't", "never", "no", "nor", "neither" to the end of its clause (punctuation, a
conjunction such as "and" or "but", or a verb starting a new predicate: in "the bird that doesn't
move is the goal" only "move" is negated), six words at most. When a field's cues are all negated
and they rule out two of its three values ("neither the enemy nor the goal"), the third is the
answer. Cues that only occur negated ("won't budge") are the table's "negative_polarity", which a
negation does not cancel. With an encoder, a field no rule decides gets the value of the known
phrase (the generator's lexicon and the table's whole-word cues) nearest to one of the
description's clauses in embedding space, instead of None.

Accuracy: `lwm parser-accuracy` (human-written files, the stress set) and docs/language.md.
"""

from __future__ import annotations

import json
import re
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..messenger.constants import IDENTITIES, Triple
from .generator import (
    IDENTITY_SYNONYMS,
    MOVEMENT_ADJECTIVES,
    MOVEMENT_CLAUSES,
    MOVEMENT_PHRASES,
    ROLE_NOUNS,
    ROLE_PHRASES,
    ROLE_PREDICATES,
)

# The keyword tables are data beside the code (what each rule means is in the file's _comment).
_TABLES = json.loads((Path(__file__).with_name("parser_keywords.json")).read_text(encoding="utf-8"))
IDENTITY_KEYWORDS: dict[str, tuple[str, ...]] = {k: tuple(v) for k, v in _TABLES["identity"].items()}
# Checked in this order; the first rule with a match wins.
MOVEMENT_RULES: tuple[tuple[str, tuple[str, ...]], ...] = tuple((m, tuple(w)) for m, w in _TABLES["movement"])
ROLE_RULES: tuple[tuple[str, tuple[str, ...]], ...] = tuple((r, tuple(w)) for r, w in _TABLES["role"])


def _pattern(words: tuple[str, ...]) -> re.Pattern:
    return re.compile(r"\b(" + "|".join(re.escape(w) for w in sorted(words, key=len, reverse=True)) + r")")


# A plural or a pet form ("birdie", "fishy", "doggies") names the same sprite.
_IDENTITY_PATTERNS = {
    ident: re.compile(
        r"\b(" + "|".join(re.escape(w) for w in sorted(kws, key=len, reverse=True)) + r")(?:s|es|ie|ies|y)?\b"
    )
    for ident, kws in IDENTITY_KEYWORDS.items()
}
_MOVEMENT_PATTERNS = [(m, _pattern(w)) for m, w in MOVEMENT_RULES]
_ROLE_PATTERNS = [(r, _pattern(w)) for r, w in ROLE_RULES]
_NEGATIVE_POLARITY = _pattern(tuple(_TABLES.get("negative_polarity", ())))

_NEGATOR = re.compile(r"\b(not|never|no|nor|neither|nowhere)\b|n't\b")
# Where a negation's scope ends: punctuation, a conjunction, or a verb that starts a new predicate.
_SCOPE_END = re.compile(
    r"[.,;:!?()\u2014]|\b(but|and|so|while|yet|whereas|though|although|instead|rather|"
    r"is|are|was|has|have|holds|carries|contains|possesses|bears|keeps|receives|will|must)\b"
)
_SCOPE_WORDS = 6
# "still" as an adverb and "remains" as a linking verb, followed by what they qualify or link.
_NOT_STILLNESS = re.compile(r"(?:still|remains?)\s+(?:a|an|the|is|are|be|of|your|its|has|have|holds|carries|very)\b")


def _negated_spans(lowered: str) -> list[tuple[int, int]]:
    """Character spans of the text that lie inside a negation's scope."""
    spans = []
    for m in _NEGATOR.finditer(lowered):
        lo = m.end()
        rest = lowered[lo:]
        end = len(rest)
        stop = _SCOPE_END.search(rest)
        if stop:
            end = stop.start()
        words = list(re.finditer(r"\S+", rest[:end]))
        if len(words) > _SCOPE_WORDS:
            end = words[_SCOPE_WORDS - 1].end()
        spans.append((lo, lo + end))
    return spans


def _is_negated(spans: list[tuple[int, int]], start: int) -> bool:
    return any(lo <= start < hi for lo, hi in spans)


@lru_cache(maxsize=1)
def _vocabulary() -> dict[int, tuple[str, ...]]:
    """Whole-word keywords by length, the targets of typo correction."""
    words: set[str] = set()
    tables = [w for kws in IDENTITY_KEYWORDS.values() for w in kws]
    tables += [w for _, kws in MOVEMENT_RULES for w in kws] + [w for _, kws in ROLE_RULES for w in kws]
    tables += list(_TABLES.get("typo_targets", ()))
    for phrase in tables:
        words.update(t for t in re.findall(r"[a-z']+", phrase) if len(t) >= 4)
    by_len: dict[int, list[str]] = {}
    for w in sorted(words):
        by_len.setdefault(len(w), []).append(w)
    return {n: tuple(ws) for n, ws in by_len.items()}


def _one_typo(word: str, target: str, shortest: int = 5) -> bool:
    """Is `word` one swap, drop, doubling or change of a letter away from `target`? A change, drop or
    doubling counts between words of `shortest` letters or more (a swap at any length)."""
    if word == target:
        return False
    n, m = len(word), len(target)
    if n == m:
        diff = [i for i in range(n) if word[i] != target[i]]
        if len(diff) == 1:
            return n >= shortest
        i, j = diff if len(diff) == 2 else (0, 0)
        return len(diff) == 2 and j == i + 1 and word[i] == target[j] and word[j] == target[i]
    if abs(n - m) != 1 or min(n, m) < shortest:
        return False
    short, long_ = (word, target) if n < m else (target, word)
    i = 0
    while i < len(short) and short[i] == long_[i]:
        i += 1
    return short[i:] == long_[i + 1 :]


@lru_cache(maxsize=4096)
def _correct_word(word: str) -> str:
    vocab = _vocabulary()
    if len(word) < 4 or word in vocab.get(len(word), ()):
        return word
    for n in (len(word), len(word) - 1, len(word) + 1):
        for target in vocab.get(n, ()):
            if _one_typo(word, target):
                return target
    return word


# "doesnt", "does'nt", "doesnt'": a misplaced or missing apostrophe must not hide a negation.
_CONTRACTION = re.compile(r"\b(does|do|did|is|are|was|were|has|have|had|can|could|would|should|wo|ca)'?n'?t'?(?=\W|$)")


def normalise(text: str) -> str:
    """Lowercase text with contractions mended and each word that is one typo from a keyword
    replaced by the keyword."""
    lowered = _CONTRACTION.sub(lambda m: m.group(1) + "n't", text.lower())
    return re.sub(r"[a-z]+", lambda m: _correct_word(m.group(0)), lowered)


def _find_identity(lowered: str) -> str | None:
    best = None
    for ident, pattern in _IDENTITY_PATTERNS.items():
        for m in pattern.finditer(lowered):
            key = (-(m.end() - m.start()), m.start())
            if best is None or key < best[0]:
                best = (key, ident)
    return None if best is None else best[1]


def parse_identity(text: str, encoder=None) -> str | None:
    """The identity a description is about: longest keyword, earliest on ties (as written, else
    after typo correction); else, with an encoder, a misspelt name (`_misspelt_identity`) or the
    nearest name in the encoder's embedding space; else None."""
    lowered = text.lower()
    found = _find_identity(lowered) or _find_identity(normalise(lowered))
    if found is not None:
        return found
    if encoder is not None:
        return _misspelt_identity(lowered, encoder) or _nearest_identity(text, encoder)
    return None


@lru_cache(maxsize=1)
def _name_words() -> dict[str, str]:
    """One-word identity keywords of three letters or more, by the identity they name."""
    return {w: ident for ident, kws in IDENTITY_KEYWORDS.items() for w in kws if " " not in w and len(w) >= 3}


def _misspelt_identity(lowered: str, encoder) -> str | None:
    """The identity of the words that are no word the encoder knows whole (a typo, not "make" or
    "call") and one typo from a one-word identity keyword, three letters or more ("dgo", "quen",
    "fissh"); a word one typo from an identity's own name and from another's synonym ("robit":
    robot, robin) is the name's. None unless the words name exactly one identity this way.
    Keyword typo correction stops at five letters, since short real words lie one letter from
    short keywords; a word the encoder's vocabulary lacks is seldom a real word."""
    names, found = _name_words(), set()
    for word in dict.fromkeys(re.findall(r"[a-z]+", lowered)):
        if len(word) < 3 or encoder.knows_word(word):
            continue
        near = [w for w in names if _one_typo(word, w, shortest=3)]
        own = [w for w in near if w == names[w]]  # an identity's own name ("robot")
        idents = {names[w] for w in own or near}
        if len(idents) == 1:
            found |= idents
    return found.pop() if len(found) == 1 else None


def _decide(lowered: str, rules) -> tuple[str | None, list[str]]:
    """The first rule with a cue outside every negation; else the one value no negated cue rules
    out when the other two are; else None. Also the values that negated cues rule out."""
    spans = _negated_spans(lowered)
    ruled_out = []
    for name, pattern in rules:
        negated = False
        for m in pattern.finditer(lowered):
            if lowered.startswith("less", m.end()):
                continue  # "harmless", "aimless": the cue's opposite
            if _NOT_STILLNESS.match(lowered, m.start()):
                continue  # "it is still a deadly opponent", "remains the goal": no movement said
            if not _is_negated(spans, m.start()) or _NEGATIVE_POLARITY.match(lowered, m.start()):
                return name, ruled_out
            negated = True
        if negated:
            ruled_out.append(name)
    left = list(dict.fromkeys(name for name, _ in rules if name not in ruled_out))  # a value may head two rules
    return (left[0] if len(left) == 1 else None), ruled_out


def _parse_field(text: str, rules, field: str, encoder) -> str | None:
    lowered = normalise(text)
    found, ruled_out = _decide(lowered, rules)
    if found is None and encoder is not None:
        return _nearest_value(lowered, field, encoder, ruled_out)
    return found


def parse_movement(text: str, encoder=None) -> str | None:
    """The movement by keyword rules; with an encoder, when no rule decides, the movement of the
    nearest known phrase in embedding space."""
    return _parse_field(text, _MOVEMENT_PATTERNS, "movement", encoder)


def parse_role(text: str, encoder=None) -> str | None:
    """The role by keyword rules; with an encoder, when no rule decides, the role of the nearest
    known phrase in embedding space."""
    return _parse_field(text, _ROLE_PATTERNS, "role", encoder)


def parse_description(text: str, encoder=None) -> tuple[str | None, str | None, str | None]:
    """(identity, movement, role) as the parser reads them; None where it finds no cue (with an
    encoder, an embedding-space guess instead of None)."""
    return parse_identity(text, encoder), parse_movement(text, encoder), parse_role(text, encoder)


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


@lru_cache(maxsize=4)
def _value_prototypes(encoder, field: str) -> tuple[list[str], np.ndarray]:
    """Phrases that state a movement (or role): the generator's and the keyword table's own
    phrases (whole words only, not stems), with their value; not the cues that only occur negated
    ("leaves its spot" says the opposite of "never leaves its spot")."""
    if field == "movement":
        lexicons, rules = (MOVEMENT_PHRASES, MOVEMENT_CLAUSES, MOVEMENT_ADJECTIVES), MOVEMENT_RULES
    else:
        lexicons, rules = (ROLE_PHRASES, ROLE_PREDICATES, ROLE_NOUNS), ROLE_RULES
    pairs = [(value, phrase) for lexicon in lexicons for value, phrases in lexicon.items() for phrase in phrases]
    negated_only = set(_TABLES.get("negative_polarity", ()))
    stated = [(value, w) for value, words in rules for w in words if w not in negated_only]
    pairs += [(value, w) for value, w in stated if " " in w or len(w) >= 5]
    feats, lengths = encoder.encode_arrays([phrase for _, phrase in pairs])
    return [value for value, _ in pairs], _mean_unit(feats, lengths)


_CLAUSE = re.compile(r"[.,;:!?()\u2014]|\b(?:and|but|while|so)\b")


def _nearest_value(lowered: str, field: str, encoder, ruled_out: list[str]) -> str | None:
    # Clause by clause, so that the identity and the other field's words in the sentence do not
    # pull the embedding; the best clause-phrase pair decides. A negated clause would pull
    # towards what it denies, so it is left out, and so are the values negated cues rule out.
    clauses = [c.strip() for c in _CLAUSE.split(lowered) if c and c.strip() and not _NEGATOR.search(c)]
    values, protos = _value_prototypes(encoder, field)
    allowed = np.array([v not in ruled_out for v in values])
    if not clauses or not allowed.any():
        return None
    feats, lengths = encoder.encode_arrays(clauses)
    sims = np.where(allowed[None, :], _mean_unit(feats, lengths) @ protos.T, -np.inf)
    return values[int(np.argmax(sims)) % len(values)]


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
