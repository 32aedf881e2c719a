"""An offline rule-based parser of Messenger descriptions: which identity, movement and role a
description states. It stands in for the paper's ChatGPT in the GPTHard baseline (which only uses
the identity, to route a description to an entity), so call it what it is: a keyword parser.

Identity: the longest keyword match from a hand-written synonym list (wider than the generator's
lexicon, since people write "falcon", "scholar" or "humanoid"), earliest in the text on ties. A
description with no known keyword falls back to the nearest identity name in the frozen text
encoder's embedding space, when an encoder is given. Movement and role: ordered keyword rules
(negated motion before motion, "away" before "toward", enemy cues before goal and message cues).
Its accuracy on the human-written descriptions is measured by `lwm parser-accuracy`
(docs/world-models.md, results/parser/accuracy.txt).
"""

from __future__ import annotations

import json
import re
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..messenger.constants import IDENTITIES, Triple
from .generator import IDENTITY_SYNONYMS

# The keyword tables are data beside the code (what each rule means is in the file's _comment).
_TABLES = json.loads((Path(__file__).with_name("parser_keywords.json")).read_text(encoding="utf-8"))
IDENTITY_KEYWORDS: dict[str, tuple[str, ...]] = {k: tuple(v) for k, v in _TABLES["identity"].items()}
# Checked in this order; the first rule with a match wins.
MOVEMENT_RULES: tuple[tuple[str, tuple[str, ...]], ...] = tuple((m, tuple(w)) for m, w in _TABLES["movement"])
ROLE_RULES: tuple[tuple[str, tuple[str, ...]], ...] = tuple((r, tuple(w)) for r, w in _TABLES["role"])


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
