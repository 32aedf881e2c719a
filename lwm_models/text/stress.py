"""The project's free-form stress set (stress_set.json, built by scripts/make_stress_set.py).

Descriptions in seven styles (casual, long-winded, negation, typos, rare synonyms, reordered
clauses, several facts per sentence), each labelled with its (identity, movement, role), its style
and its part: "tune" may be tuned or trained on; "dev" may choose between ways of reading but is
never trained or tuned on; "heldout" is never used for either. The parts were written with
different templates and phrases, so a figure on "heldout" is one on wording its tuning never saw.
"written" is a second dev part: one description per style and triple, each written by hand, not
from a template, by a writer who saw neither the other parts nor the parser's rules
(stress_written.json). The parser's rules were tuned on "dev"'s phrasings, so "written" is the
part where a choice between ways of reading is still made on wording nothing was tuned on.

`stress_pools` turns one style of one part into description pools of the same shape as the
benchmark's (`DescriptionPools`), so a world model can be evaluated with manuals in that style
(`lwm eval --stress STYLE`). Those pools are for evaluation only: every split gets the same texts,
which would break the pools' train/test disjointness if anyone trained on them.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

from ..errors import LwmError
from ..messenger.constants import ALL_TRIPLES, SPLITS, Triple
from .pools import DescriptionPools, receiving_splits

STRESS_FILE = Path(__file__).with_name("stress_set.json")
FRESH_FILE = Path(__file__).with_name("stress_fresh.json")
VARIED_FILE = Path(__file__).with_name("stress_varied.json")
PARTS = ("tune", "dev", "heldout", "written")


@dataclass(frozen=True)
class StressEntry:
    text: str
    identity: str
    movement: str
    role: str
    style: str
    split: str

    @property
    def triple(self) -> Triple:
        return (self.identity, self.movement, self.role)


@lru_cache(maxsize=2)
def _load(path: Path) -> tuple[tuple[str, ...], tuple[StressEntry, ...]]:
    doc = json.loads(path.read_text(encoding="utf-8"))
    fields = ("text", "identity", "movement", "role", "style", "split")
    entries = tuple(StressEntry(**{k: e[k] for k in fields}) for e in doc["entries"])
    return tuple(doc["styles"]), entries


def stress_styles(path: str | Path = STRESS_FILE) -> tuple[str, ...]:
    """The styles of the stress set, in its order."""
    return _load(Path(path))[0]


def load_stress(part: str | None = None, style: str | None = None, path: str | Path = STRESS_FILE) -> list[StressEntry]:
    """Entries of the stress set, optionally only one part (`PARTS`) and one style."""
    styles, entries = _load(Path(path))
    if part is not None and part not in PARTS:
        raise LwmError(f"unknown stress-set part {part!r}; known: {', '.join(PARTS)}")
    if style is not None and style not in styles:
        raise LwmError(f"unknown stress-set style {style!r}; known: {', '.join(styles)}")
    return [e for e in entries if (part is None or e.split == part) and (style is None or e.style == style)]


def load_fresh(unusable: bool = False, path: str | Path = FRESH_FILE) -> list:
    """The fresh held-out part (stress_fresh.json): descriptions of all 108 triples, three each in
    three of the seven styles, written from the game's facts alone by a writer who never saw the
    parser, the reading code or the other parts; reported on, never fitted or tuned on. With
    `unusable`, its descriptions that carry no usable fact or only some (dicts with `kind`:
    "gibberish", "other-game" or "vague")."""
    doc = json.loads(Path(path).read_text(encoding="utf-8"))
    if unusable:
        return list(doc["unusable"])
    fields = ("text", "identity", "movement", "role", "style")
    return [StressEntry(**{k: e[k] for k in fields}, split="fresh") for e in doc["entries"]]


def load_varied(path: str | Path = VARIED_FILE) -> list[StressEntry]:
    """The varied part (stress_varied.json): 1,296 hand-written descriptions, four per triple from
    each of three writers in twelve styles, written from the game's facts alone, for fitting the
    manual's reading. A description that leaves its movement out has movement "?"."""
    doc = json.loads(Path(path).read_text(encoding="utf-8"))
    return [StressEntry(e["text"], e["identity"], e["movement"] if e.get("movement_stated", True) else "?",
                        e["role"], e["style"], "varied") for e in doc["entries"]]  # fmt: skip


def stress_texts(
    part: str | None = None, style: str | None = None, path: str | Path = STRESS_FILE
) -> dict[Triple, list[str]]:
    """Descriptions by triple, the shape `parser_accuracy` and `allocate` take."""
    out: dict[Triple, list[str]] = {}
    for e in load_stress(part, style, path):
        out.setdefault(e.triple, []).append(e.text)
    return out


def stress_pools(style: str, part: str = "heldout", path: str | Path = STRESS_FILE) -> DescriptionPools:
    """Pools holding one style of one part for every triple in every split that can contain it
    (evaluation only, see the module docstring)."""
    by_triple = stress_texts(part, style, path)
    missing = [t for t in ALL_TRIPLES if t not in by_triple]
    if missing:
        raise LwmError(f"the stress set's {part} part has no {style} description of {missing[0]}")
    pools: dict[str, dict[Triple, tuple[str, ...]]] = {split: {} for split in SPLITS}
    for triple in ALL_TRIPLES:
        for split in receiving_splits(triple):
            pools[split][triple] = tuple(by_triple[triple])
    return DescriptionPools(pools, f"stress:{part}:{style}")


FRESH_SOURCE = "stress:fresh"


def fresh_pools(path: str | Path = FRESH_FILE) -> DescriptionPools:
    """Pools of the fresh held-out part: every split that can contain a triple gets its three
    descriptions (evaluation only, as `stress_pools`)."""
    by_triple: dict[Triple, list[str]] = {}
    for e in load_fresh(path=path):
        by_triple.setdefault(e.triple, []).append(e.text)
    pools: dict[str, dict[Triple, tuple[str, ...]]] = {split: {} for split in SPLITS}
    for triple in ALL_TRIPLES:
        for split in receiving_splits(triple):
            pools[split][triple] = tuple(by_triple[triple])
    return DescriptionPools(pools, FRESH_SOURCE)


def description_pools(sources: Sequence[str]) -> DescriptionPools:
    """The pools a game draws its manuals from: human-written description files, or
    `FRESH_SOURCE` (the fresh held-out part, in a person's own words)."""
    if list(sources) == [FRESH_SOURCE]:
        return fresh_pools()
    if FRESH_SOURCE in sources:
        raise LwmError(f"{FRESH_SOURCE} is a source of its own: give it alone, not beside files")
    return DescriptionPools.from_files(sources)


def manual_sources(path: str | Path = STRESS_FILE) -> tuple[str, ...]:
    """Where a benchmark's manuals can come from: "dataset" (the dataset's own descriptions),
    "generated" (the project's generator), "stress:STYLE" (one style of the held-out part)."""
    return ("dataset", "generated", *(f"stress:{style}" for style in stress_styles(path)))


def source_pools(source: str, seed: int = 0) -> DescriptionPools | None:
    """The pools to re-draw manuals from for `source` (`manual_sources`); None for "dataset", whose
    manuals stay the dataset's."""
    if source == "dataset":
        return None
    if source == "generated":
        return DescriptionPools.generated(seed=seed)
    if source.startswith("stress:"):
        return stress_pools(source.split(":", 1)[1])
    raise LwmError(f"unknown manual source {source!r}; known: {', '.join(manual_sources())}")
