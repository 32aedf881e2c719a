"""Per-split description pools, disjoint across splits (docs/game.md, "Descriptions").

A description seen in training must never appear in an evaluation manual, otherwise the
generalisation splits would partly test memorised text. So every distinct description is given to
exactly one split, by one rule used for generated and human-written text alike and deterministic
in `seed`:

- descriptions are deduplicated globally (exact string; a string listed under two triples stays
  with the first triple in ALL_TRIPLES order);
- a training triple's descriptions are shuffled and cut 50% / 25% / 25% among train,
  newcombo-dev and newcombo-test, the only splits whose games contain training triples;
- any other triple's are cut 1/6, 1/6, 1/3, 1/3 among newattr-dev, newattr-test, newall-dev
  and newall-test;
- the shuffle uses a numpy Generator seeded by `seed` and a SHA-256 of the triple (not Python's
  salted hash()), and the cut rounds by largest remainder, then moves descriptions so that each
  receiving split gets at least one whenever the triple has at least as many as receiving splits.

The human-written files leave some triples empty or too small; those (split, triple) pools are
filled from the generated pool of the same split and triple and listed in `fallbacks`.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable, Mapping, Sequence
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..errors import LwmError
from ..messenger.constants import ALL_TRIPLES, SPLITS, TRAIN_TRIPLES, Triple
from .generator import add_typos, generate_descriptions
from .human import load_description_files

TRAIN_SHARE: dict[str, int] = {"train": 2, "newcombo-dev": 1, "newcombo-test": 1}
"""Relative shares of a training triple's descriptions."""
UNSEEN_SHARE: dict[str, int] = {"newattr-dev": 1, "newattr-test": 1, "newall-dev": 2, "newall-test": 2}
"""Relative shares of any other triple's descriptions."""

Pools = dict[str, dict[Triple, tuple[str, ...]]]


class PoolError(LwmError, KeyError):
    """A split or (split, triple) that has no description pool."""

    def __str__(self) -> str:  # KeyError would print the message quoted
        return str(self.args[0])


def receiving_splits(triple: Triple) -> dict[str, int]:
    """The splits whose games can contain `triple`, with their relative shares."""
    return TRAIN_SHARE if tuple(triple) in TRAIN_TRIPLES else UNSEEN_SHARE


def _triple_rng(seed: int, triple: Triple) -> np.random.Generator:
    digest = hashlib.sha256("|".join(triple).encode("utf-8")).digest()
    return np.random.default_rng([seed, int.from_bytes(digest[:8], "little")])


def split_counts(n: int, shares: Sequence[int]) -> list[int]:
    """How many of `n` items each share gets: proportional, largest remainder first (ties to the
    earlier share), then at least one each when n allows, taken from the largest count."""
    total = sum(shares)
    counts = [n * w // total for w in shares]
    by_remainder = sorted(range(len(shares)), key=lambda k: (-(n * shares[k] % total), k))
    for k in by_remainder[: n - sum(counts)]:
        counts[k] += 1
    if n >= len(shares):
        for k in range(len(counts)):
            if counts[k] == 0:
                donor = max(range(len(counts)), key=lambda j: (counts[j], -j))
                counts[donor] -= 1
                counts[k] = 1
    return counts


def allocate(texts_by_triple: Mapping[Triple, Sequence[str]], seed: int) -> Pools:
    """Split every triple's descriptions among its receiving splits (see the module docstring).

    Only non-empty pools are stored: a split that gets nothing of a triple has no entry for it.
    """
    if not isinstance(seed, (int, np.integer)) or seed < 0:
        raise LwmError(f"the pool seed must be a non-negative integer, got {seed!r}")
    seen: set[str] = set()
    pools: Pools = {split: {} for split in SPLITS}
    for triple in ALL_TRIPLES:
        unique = [t for t in dict.fromkeys(texts_by_triple.get(triple, ())) if t not in seen]
        seen.update(unique)
        shares = receiving_splits(triple)
        order = [unique[i] for i in _triple_rng(int(seed), triple).permutation(len(unique))]
        lo = 0
        for split, count in zip(shares, split_counts(len(order), list(shares.values()))):
            if count:
                pools[split][triple] = tuple(order[lo : lo + count])
            lo += count
    return pools


@lru_cache(maxsize=4)
def _generated_pools(seed: int) -> Pools:
    return allocate({t: generate_descriptions(t) for t in ALL_TRIPLES}, seed)


class DescriptionPools:
    """Description pools of every split; `draw` gives one description per entity of a game.

    Attributes:
        pools: split -> triple -> descriptions; a split only has the triples its games can contain.
        source: "generated", or the human-written file paths joined by ",".
        typo_rate: probability of a typo per word, applied at draw time (0 = none).
        fallbacks: (split, triple) pools that the human-written files could not fill and that hold
            the generated descriptions instead; empty for generated pools.
    """

    def __init__(
        self,
        pools: Pools,
        source: str,
        typo_rate: float = 0.0,
        fallbacks: list[tuple[str, Triple]] | None = None,
    ) -> None:
        if not 0.0 <= typo_rate <= 1.0:
            raise LwmError(f"typo_rate must be in [0, 1], got {typo_rate}")
        self.pools = pools
        self.source = source
        self.typo_rate = float(typo_rate)
        self.fallbacks: list[tuple[str, Triple]] = list(fallbacks or [])
        self._every_split: dict[Triple, tuple[str, ...]] | None = None

    @property
    def fallback_count(self) -> int:
        """Number of (split, triple) pools filled with generated text."""
        return len(self.fallbacks)

    @classmethod
    def generated(cls, seed: int = 0, typo_rate: float = 0.0) -> DescriptionPools:
        """Pools of the project's own generated descriptions."""
        return cls(
            {split: dict(by_triple) for split, by_triple in _generated_pools(seed).items()}, "generated", typo_rate
        )

    @classmethod
    def from_files(cls, paths: Iterable[str | Path], seed: int = 0, typo_rate: float = 0.0) -> DescriptionPools:
        """Pools of human-written descriptions; empty (split, triple) pools come from the generator.

        A generated fallback text that also occurs in the human-written pools is left out, so the
        splits stay disjoint.
        """
        paths = [Path(p) for p in paths]
        pools = allocate(load_description_files(paths), seed)
        human = {text for by_triple in pools.values() for texts in by_triple.values() for text in texts}
        generated = _generated_pools(seed)
        fallbacks: list[tuple[str, Triple]] = []
        for triple in ALL_TRIPLES:
            for split in receiving_splits(triple):
                if triple not in pools[split]:
                    texts = tuple(t for t in generated[split][triple] if t not in human)
                    if not texts:
                        raise LwmError(f"no description left for {triple} in {split}")
                    pools[split][triple] = texts
                    fallbacks.append((split, triple))
        return cls(pools, ",".join(str(p) for p in paths), typo_rate, fallbacks)

    def _union(self) -> dict[Triple, tuple[str, ...]]:
        if self._every_split is None:
            union: dict[Triple, dict[str, None]] = {}
            for split in self.pools:
                for triple, texts in self.pools[split].items():
                    union.setdefault(triple, {}).update(dict.fromkeys(texts))
            self._every_split = {triple: tuple(texts) for triple, texts in union.items()}
        return self._every_split

    def pool(self, split: str | None, triple: Sequence[str]) -> tuple[str, ...]:
        """The descriptions of `triple` in `split`; PoolError if that split never has the triple.

        `split=None` means every split's descriptions of the triple together: a game played outside
        the benchmark (e.g. an interactive one) is in no split.
        """
        by_triple = self._union() if split is None else self.pools.get(split)
        if by_triple is None:
            raise PoolError(f"unknown split {split!r}; known: {list(self.pools)}")
        found = by_triple.get(tuple(triple))  # type: ignore[arg-type]
        if not found:
            raise PoolError(
                f"split {split!r} has no descriptions of {tuple(triple)}: the games of that split never contain it"
            )
        return found

    def draw(self, split: str | None, triples: Sequence[Sequence[str]], rng: np.random.Generator) -> list[str]:
        """One description per triple, uniformly from its pool in `split`, aligned with `triples`
        (the caller shuffles the manual's order); `split=None` draws from every split's pools.
        Typos are added here when typo_rate > 0."""
        out = []
        for triple in triples:
            pool = self.pool(split, triple)
            text = pool[int(rng.integers(len(pool)))]
            out.append(add_typos(text, rng, self.typo_rate) if self.typo_rate > 0 else text)
        return out

    def summary(self) -> dict[str, int]:
        """Number of distinct descriptions per split."""
        return {
            split: len({t for texts in by_triple.values() for t in texts}) for split, by_triple in self.pools.items()
        }
