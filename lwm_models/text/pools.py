"""Per-split description pools, disjoint across splits (§2).

Allocation (the same for generated and human-written text, deterministic in `seed`): every
distinct description belongs to one triple and goes to exactly one split. A training triple's
descriptions are shuffled and cut 50% / 25% / 25% among train, newcombo-dev and newcombo-test
(the splits that use training triples); any other triple's 1/6, 1/6, 1/3, 1/3 among newattr-dev,
newattr-test, newall-dev and newall-test. Each receiving split gets at least one description when
the triple has enough. With human-written files some (split, triple) pools come out empty; they
are filled from the generated pool of the same split and triple and counted in `fallbacks`.
"""

from __future__ import annotations

import hashlib
from functools import lru_cache
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from ..errors import LwmError
from ..messenger.constants import ALL_TRIPLES, SPLITS, TRAIN_TRIPLES, Triple
from .generator import add_typos, generate_descriptions
from .human import load_description_files

TRAIN_SHARE = {"train": 2, "newcombo-dev": 1, "newcombo-test": 1}
UNSEEN_SHARE = {"newattr-dev": 1, "newattr-test": 1, "newall-dev": 2, "newall-test": 2}


class PoolError(LwmError, KeyError):
    """A split or triple that has no description pool."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0])


def receiving_splits(triple: Triple) -> dict[str, int]:
    """The splits whose games can contain `triple`, with their relative shares."""
    return TRAIN_SHARE if triple in TRAIN_TRIPLES else UNSEEN_SHARE


def _triple_seed(seed: int, triple: Triple) -> list[int]:
    digest = hashlib.sha256("|".join(triple).encode()).digest()
    return [seed, int.from_bytes(digest[:8], "little")]


def _cut(texts: list[str], shares: dict[str, int], rng: np.random.Generator) -> dict[str, list[str]]:
    order = [texts[i] for i in rng.permutation(len(texts))]
    names = list(shares)
    total = sum(shares.values())
    counts = [int(len(order) * shares[n] / total) for n in names]
    if len(order) >= len(names):  # every split gets one before the rest is shared out
        counts = [max(1, c) for c in counts]
    while sum(counts) > len(order):
        counts[int(np.argmax(counts))] -= 1
    k = 0
    while sum(counts) < len(order):  # rounding leftovers go round-robin
        counts[k % len(counts)] += 1
        k += 1
    out, lo = {}, 0
    for name, c in zip(names, counts):
        out[name] = order[lo : lo + c]
        lo += c
    return out


def allocate(texts_by_triple: dict[Triple, list[str]], seed: int) -> dict[str, dict[Triple, tuple[str, ...]]]:
    """Split every triple's descriptions among its receiving splits (see module docstring)."""
    seen: set[str] = set()
    pools: dict[str, dict[Triple, tuple[str, ...]]] = {s: {} for s in SPLITS}
    for triple in ALL_TRIPLES:
        unique = [t for t in dict.fromkeys(texts_by_triple.get(triple, ())) if t not in seen]
        seen.update(unique)
        rng = np.random.default_rng(_triple_seed(seed, triple))
        for split, texts in _cut(unique, receiving_splits(triple), rng).items():
            if texts:
                pools[split][triple] = tuple(texts)
    return pools


class DescriptionPools:
    """Description pools of every split; `draw` gives one description per entity."""

    def __init__(self, pools: dict[str, dict[Triple, tuple[str, ...]]], source: str, typo_rate: float = 0.0,
                 fallbacks: list[tuple[str, Triple]] | None = None) -> None:
        self.pools = pools
        self.source = source
        self.typo_rate = typo_rate
        self.fallbacks = fallbacks or []

    @property
    def fallback_count(self) -> int:
        return len(self.fallbacks)

    @classmethod
    def generated(cls, seed: int = 0, typo_rate: float = 0.0) -> "DescriptionPools":
        return cls(_generated_pools(seed), "generated", typo_rate)

    @classmethod
    def from_files(cls, paths: Iterable[str | Path], seed: int = 0) -> "DescriptionPools":
        paths = [Path(p) for p in paths]
        pools = allocate(load_description_files(paths), seed)
        generated = _generated_pools(seed)
        fallbacks = []
        for triple in ALL_TRIPLES:
            for split in receiving_splits(triple):
                if triple not in pools[split]:
                    pools[split][triple] = generated[split][triple]
                    fallbacks.append((split, triple))
        return cls(pools, ",".join(str(p) for p in paths), 0.0, fallbacks)

    def pool(self, split: str, triple: Sequence[str]) -> tuple[str, ...]:
        if split not in self.pools:
            raise PoolError(f"unknown split {split!r}; known: {list(self.pools)}")
        found = self.pools[split].get(tuple(triple))  # type: ignore[arg-type]
        if not found:
            raise PoolError(f"split {split!r} has no descriptions of {tuple(triple)}: games of that split never have it")
        return found

    def draw(self, split: str, triples: Sequence[Sequence[str]], rng: np.random.Generator) -> list[str]:
        """One description per triple, uniformly from its pool in `split`, aligned with `triples`."""
        out = []
        for triple in triples:
            pool = self.pool(split, triple)
            text = pool[int(rng.integers(len(pool)))]
            out.append(add_typos(text, rng, self.typo_rate) if self.typo_rate else text)
        return out

    def summary(self) -> dict[str, int]:
        return {split: sum(len(v) for v in triples.values()) for split, triples in self.pools.items()}


@lru_cache(maxsize=4)
def _generated_pools(seed: int) -> dict[str, dict[Triple, tuple[str, ...]]]:
    return allocate({t: generate_descriptions(t) for t in ALL_TRIPLES}, seed)


@lru_cache(maxsize=1)
def default_pools() -> DescriptionPools:
    """The generated pools with seed 0, built once per process."""
    return DescriptionPools.generated()
