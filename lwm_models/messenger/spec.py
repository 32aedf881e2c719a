"""Game specs: which three entities a game has, what they are and how they move."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from ..errors import InvalidSpecError
from .constants import IDENTITIES, MOVEMENTS, ROLES, Triple


@dataclass(frozen=True)
class EntitySpec:
    """One entity of a game: its identity (e.g. "airplane"), movement and role."""

    identity: str
    movement: str
    role: str

    def __post_init__(self) -> None:
        if self.identity not in IDENTITIES:
            raise InvalidSpecError(f"unknown identity {self.identity!r}; known: {sorted(IDENTITIES)}")
        if self.movement not in MOVEMENTS:
            raise InvalidSpecError(f"unknown movement {self.movement!r}; known: {list(MOVEMENTS)}")
        if self.role not in ROLES:
            raise InvalidSpecError(f"unknown role {self.role!r}; known: {list(ROLES)}")

    @property
    def triple(self) -> Triple:
        return (self.identity, self.movement, self.role)

    @property
    def entity_id(self) -> int:
        return IDENTITIES[self.identity]


@dataclass(frozen=True)
class GameSpec:
    """Three entities in role order (enemy, message, goal) with distinct identities."""

    entities: tuple[EntitySpec, EntitySpec, EntitySpec]

    def __post_init__(self) -> None:
        if len(self.entities) != 3:
            raise InvalidSpecError(f"a game has 3 entities, got {len(self.entities)}")
        roles = tuple(e.role for e in self.entities)
        if roles != ROLES:
            raise InvalidSpecError(f"entities must be in role order {ROLES}, got {roles}")
        identities = [e.identity for e in self.entities]
        if len(set(identities)) != 3:
            raise InvalidSpecError(f"the three identities must be distinct, got {identities}")

    @classmethod
    def from_triples(cls, triples: Iterable[Sequence[str]]) -> GameSpec:
        """Build from (identity, movement, role) triples in any order; validates everything."""
        try:
            items = [tuple(t) for t in triples]
        except TypeError as exc:
            raise InvalidSpecError(f"a game spec is a list of (identity, movement, role) triples: {exc}") from None
        for t in items:
            if len(t) != 3 or not all(isinstance(x, str) for x in t):
                raise InvalidSpecError(f"each entity is an (identity, movement, role) triple of strings, got {t!r}")
        if len(items) != 3:
            raise InvalidSpecError(f"a game has 3 entities, got {len(items)}")
        by_role: dict[str, EntitySpec] = {}
        for ident, mov, role in items:
            ent = EntitySpec(ident, mov, role)
            if role in by_role:
                raise InvalidSpecError(f"role {role!r} appears twice; a game has one enemy, message and goal")
            by_role[role] = ent
        return cls(tuple(by_role[r] for r in ROLES))  # type: ignore[arg-type]

    @property
    def triples(self) -> tuple[Triple, Triple, Triple]:
        return tuple(e.triple for e in self.entities)  # type: ignore[return-value]

    @property
    def identity_set(self) -> frozenset[str]:
        return frozenset(e.identity for e in self.entities)

    def to_json(self) -> list[list[str]]:
        return [list(t) for t in self.triples]

    def __str__(self) -> str:
        return ", ".join(f"{e.identity} ({e.movement} {e.role})" for e in self.entities)
