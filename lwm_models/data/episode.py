"""Which real episode a review is about: its game (split and index), seed and attempt.

The id travels as a string in every message (`episode_id` of a state, `review_id` of a plan,
feedback, labels and reports) and names the episode's records in the ledger:

    newall-test:0:3      the episode of seed 3 of game 0 of newall-test, first attempt
    newall-test:0:3#2    the same episode reviewed afresh ("restart this game"): attempt 2

An episode is a function of its game and seed, so a restarted one starts from the same board;
the attempt only makes its review a new one (a finished review is never redone). Everything that
needs a part of the id parses it here instead of splitting the string itself.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from ..errors import LwmError

_ID = re.compile(r"(?P<split>[A-Za-z0-9_-]+):(?P<index>\d+):(?P<seed>\d+)(?:#(?P<attempt>\d+))?")


@dataclass(frozen=True)
class Episode:
    split: str
    index: int
    seed: int
    attempt: int = 1  # 1 for an episode's first review; each restart of it counts one more

    @property
    def game(self) -> str:
        """The game, `split:index`: what learnt policies and a person's manual belong to."""
        return f"{self.split}:{self.index}"

    @property
    def id(self) -> str:
        return f"{self.game}:{self.seed}" + (f"#{self.attempt}" if self.attempt > 1 else "")

    def __str__(self) -> str:
        return self.id

    def next(self, seed: int | None = None) -> Episode:
        """The next episode of this game (the next seed, or `seed`), a first attempt."""
        return Episode(self.split, self.index, self.seed + 1 if seed is None else seed)

    def restarted(self) -> Episode:
        """This episode again, as a new review."""
        return Episode(self.split, self.index, self.seed, self.attempt + 1)

    @classmethod
    def parse(cls, text: str) -> Episode:
        m = _ID.fullmatch(text or "")
        if m is None:
            raise LwmError(f"{text!r} is not an episode id (split:index:seed, or split:index:seed#attempt)")
        attempt = int(m["attempt"] or 1)
        if attempt < 1:
            raise LwmError(f"{text!r}: an attempt counts from 1")
        return cls(m["split"], int(m["index"]), int(m["seed"]), attempt)


def game_of(episode_id: str) -> str:
    """`split:index` of an episode id."""
    return Episode.parse(episode_id).game


__all__ = ["Episode", "game_of"]
