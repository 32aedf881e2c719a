"""What makes a compact observation [4, 3] a real game state.

The JSON Schemas check shapes; this checks meaning, for every state a node takes as real (the
environment's states, the starts of imagination): entity ids 2..13 and distinct in channels 0-2,
15/16 or empty in the avatar channel, cells on the grid, an empty channel all zero. Imagined
observations are not checked: a world model may imagine an impossible state, and showing it is
the point of review.
"""

from __future__ import annotations

import numpy as np

from ..errors import LwmError
from .constants import AVATAR_NO_MESSAGE, AVATAR_WITH_MESSAGE, GRID, NUM_CHANNELS


class InvalidObservation(LwmError, ValueError):
    """A compact observation that no game can be in."""


def check_observation(obs: list | np.ndarray, where: str = "observation") -> np.ndarray:
    """The observation as uint8 [4, 3]; InvalidObservation (naming `where`) if it is no game state."""
    a = np.asarray(obs)
    if a.shape != (NUM_CHANNELS, 3) or not np.issubdtype(a.dtype, np.integer):
        raise InvalidObservation(f"{where}: a compact observation is 4 rows of [id, row, col] integers")
    for c in range(NUM_CHANNELS):
        i, r, col = (int(v) for v in a[c])
        if i == 0:
            if r or col:
                raise InvalidObservation(f"{where}: channel {c} is empty (id 0) but has a cell ({r}, {col})")
            continue
        if not (0 <= r < GRID and 0 <= col < GRID):
            raise InvalidObservation(f"{where}: channel {c} cell ({r}, {col}) is off the {GRID}x{GRID} grid")
        if c < 3 and not 2 <= i <= 13:
            raise InvalidObservation(f"{where}: channel {c} holds id {i}; entity channels hold ids 2..13 or 0")
        if c == 3 and i not in (AVATAR_NO_MESSAGE, AVATAR_WITH_MESSAGE):
            raise InvalidObservation(f"{where}: the avatar channel holds id {i}; it holds 15, 16 or 0")
    present = [int(i) for i in a[:3, 0] if i]
    if len(present) != len(set(present)):
        raise InvalidObservation(
            f"{where}: the entity channels repeat an id ({present}); a game has 3 distinct entities"
        )
    return a.astype(np.uint8)


__all__ = ["InvalidObservation", "check_observation"]
