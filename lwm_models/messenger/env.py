"""One Messenger game with a gymnasium-style API: the readable reference implementation of the rules.

It is written with plain Python integers, independently of the batched engine, so that a test
comparing the two checks the rules twice. Every random draw comes from `rng.uniform(seed, step,
slot)`, which makes an episode a function of its seed alone.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import numpy as np

from ..errors import GameStateError, InvalidActionError
from . import rng
from .constants import (
    ACTION_DELTAS,
    AVATAR_CHANNEL,
    AVATAR_NO_MESSAGE,
    AVATAR_WITH_MESSAGE,
    DEFAULT_MAX_STEPS,
    GRID,
    HALF_MAX,
    NUM_ACTIONS,
    NUM_CHANNELS,
    REWARD_DEATH,
    REWARD_PICKUP,
    REWARD_WIN,
    ROLES,
    STARTS,
)
from .engine import CHANNEL_PERMUTATIONS
from .spec import GameSpec

# Entity directions in half-cells, in the order a uniform choice enumerates them.
_DIRECTIONS = ((-1, 0), (1, 0), (0, -1), (0, 1))


def _manhattan(a: tuple[int, int], b: tuple[int, int]) -> int:
    return abs(a[0] - b[0]) + abs(a[1] - b[1])


def _on_board(p: tuple[int, int]) -> bool:
    return 0 <= p[0] <= HALF_MAX and 0 <= p[1] <= HALF_MAX


class ManualSource(Protocol):
    """Where a game's manual comes from (lwm_models.text.DescriptionPools): the game itself knows
    no text, so that it stays the ground floor that text, data and models build on."""

    def draw(self, split: str | None, triples: Sequence[Sequence[str]], rng: np.random.Generator) -> list[str]: ...


class MessengerEnv:
    """A single Messenger stage-2 game.

    Args:
        spec: the three entities of the game.
        pools: where the manual is drawn from (lwm_models.text.DescriptionPools); None: the
            game has no manual (info["manual"] is None; the true parse is still given).
        split: which split's pool the manual is drawn from; None draws from every split's.
        max_steps: time limit in actions (the paper: 32).

    `reset(seed, options={"start": i})` and `step(action)` follow gymnasium; `info` holds the
    manual, the true parse of each description, the hidden half-cell positions and more.
    """

    def __init__(
        self,
        spec: GameSpec,
        pools: ManualSource | None = None,
        split: str | None = None,
        max_steps: int = DEFAULT_MAX_STEPS,
    ) -> None:
        if max_steps < 1:
            raise ValueError(f"max_steps must be >= 1, got {max_steps}")
        self.spec = spec
        self.pools = pools
        self.split = split
        self.max_steps = max_steps
        self._started = False

    # ----------------------------------------------------------------- gymnasium API
    def reset(self, seed: int = 0, options: dict | None = None) -> tuple[np.ndarray, dict]:
        options = options or {}
        self.seed = int(seed)
        start = options.get("start")
        if start is None:
            start = rng.choice_index(rng.uniform(self.seed, 0, rng.SLOT_START), len(STARTS))
        if not 0 <= int(start) < len(STARTS):
            raise ValueError(f"start must be in 0..{len(STARTS) - 1}, got {start}")
        self.start = int(start)
        cells = STARTS[self.start]
        self.avatar = (2 * cells[0][0], 2 * cells[0][1])
        self.positions: list[tuple[int, int] | None] = [(2 * r, 2 * c) for r, c in cells[1:]]
        perm = rng.choice_index(rng.uniform(self.seed, 0, rng.SLOT_CHANNELS), len(CHANNEL_PERMUTATIONS))
        self.channel_roles = CHANNEL_PERMUTATIONS[perm]
        self.has_message = False
        self.alive = True
        self.won = False
        self.t = 0
        self.done = False
        self._started = True
        self._draw_manual()
        return self.observation(), self.info()

    def step(self, action: int) -> tuple[np.ndarray, float, bool, bool, dict]:
        if not self._started:
            raise GameStateError("step() before reset()")
        if self.done:
            raise GameStateError("the episode has ended; call reset()")
        if isinstance(action, (bool, np.bool_)) or not isinstance(action, (int, np.integer)):
            raise InvalidActionError(f"an action is an integer in 0..{NUM_ACTIONS - 1}, got {action!r}")
        if not 0 <= int(action) < NUM_ACTIONS:
            raise InvalidActionError(f"action must be in 0..{NUM_ACTIONS - 1}, got {action}")
        self.t += 1

        # (1) Entities move, deciding from where the avatar is before it moves.
        for k, entity in enumerate(self.spec.entities):
            pos = self.positions[k]
            if pos is None or entity.movement == "immovable":
                continue
            self.positions[k] = self._move_entity(pos, entity.movement, rng.uniform(self.seed, self.t, k))

        # (2) The avatar moves one cell (two half-cells) unless that leaves the board.
        dr, dc = ACTION_DELTAS[int(action)]
        target = (self.avatar[0] + 2 * dr, self.avatar[1] + 2 * dc)
        if _on_board(target):
            self.avatar = target

        # (3) Collisions in priority order: enemy, goal without message, message, goal with it.
        # What the last frame shows (docs/game.md): a message the avatar overlaps leaves the board even
        # when the avatar dies in the same step (it is removed before the avatar is), and on a win
        # the goal leaves the board while the avatar (carrying the message) stays.
        enemy, message, goal = (self._overlaps(k) for k in range(3))
        reward = 0.0
        if enemy or (goal and not self.has_message):
            reward = REWARD_DEATH
            self.alive = False
            if message:  # only possible without the message: a carried message is off the board
                self.positions[1] = None
        elif message and not self.has_message:
            reward = REWARD_PICKUP
            self.has_message = True
            self.positions[1] = None
        elif goal and self.has_message:
            reward = REWARD_WIN
            self.won = True
            self.positions[2] = None

        terminated = not self.alive or self.won
        truncated = not terminated and self.t >= self.max_steps
        self.done = terminated or truncated
        return self.observation(), reward, terminated, truncated, self.info()

    # ----------------------------------------------------------------- rules
    def _move_entity(self, pos: tuple[int, int], movement: str, u: float) -> tuple[int, int]:
        now = _manhattan(pos, self.avatar)
        candidates = [(pos[0] + dr, pos[1] + dc) for dr, dc in _DIRECTIONS]
        if movement == "chaser":
            allowed = [p for p in candidates if _manhattan(p, self.avatar) < now]
        else:
            allowed = [p for p in candidates if _manhattan(p, self.avatar) > now]
        if not allowed:
            allowed = candidates
        new = allowed[rng.choice_index(u, len(allowed))]
        return new if _on_board(new) else pos

    def _overlaps(self, k: int) -> bool:
        pos = self.positions[k]
        return pos is not None and abs(pos[0] - self.avatar[0]) < 2 and abs(pos[1] - self.avatar[1]) < 2

    def _draw_manual(self) -> None:
        generator = np.random.default_rng([self.seed, 0x4D414E])  # "MAN": manual draws
        triples = list(self.spec.triples)
        order = generator.permutation(3)
        ordered = [triples[i] for i in order]
        self.manual = None if self.pools is None else list(self.pools.draw(self.split, ordered, generator))
        self.parse = ordered

    # ----------------------------------------------------------------- views
    def observation(self) -> np.ndarray:
        """10 x 10 x 4 uint8: entity channels in this episode's order, then the avatar."""
        obs = np.zeros((GRID, GRID, NUM_CHANNELS), dtype=np.uint8)
        for channel, k in enumerate(self.channel_roles):
            pos = self.positions[k]
            if pos is not None:
                obs[pos[0] // 2, pos[1] // 2, channel] = self.spec.entities[k].entity_id
        if self.alive:
            avatar_id = AVATAR_WITH_MESSAGE if self.has_message else AVATAR_NO_MESSAGE
            obs[self.avatar[0] // 2, self.avatar[1] // 2, AVATAR_CHANNEL] = avatar_id
        return obs

    def info(self) -> dict:
        return {
            "manual": None if self.manual is None else list(self.manual),
            "parse": [list(t) for t in self.parse],
            "half_cell_positions": {
                "avatar": self.avatar,
                **{role: self.positions[k] for k, role in enumerate(ROLES)},
            },
            "channel_identities": [self.spec.entities[k].identity for k in self.channel_roles],
            "start": self.start,
            "has_message": self.has_message,
            "t": self.t,
        }
