"""The batched Messenger engine: N games stepped in lockstep with numpy.

It implements the same rules as the single-game reference (`env.py`) with array operations; tests
check that both produce identical episodes from the same seeds. State layout (role order is
enemy, message, goal throughout):

- `entity_row`, `entity_col` [N, 3] half-cells; `avatar_row`, `avatar_col` [N] (always even);
- `movement` [N, 3] index into MOVEMENTS; `entity_ids` [N, 3] observation ids;
- `channel_roles` [N, 3]: entity channel c shows role channel_roles[n, c];
- `present` [N, 3] (the message disappears when the avatar overlaps it, the goal on a win),
  `has_message`, `alive`, `won`, `t`.

Games that have ended stay frozen: later actions are ignored and give reward 0.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import numpy as np

from ..errors import GameStateError, InvalidActionError, ShapeError
from . import rng
from .constants import (
    ACTION_DELTAS,
    AVATAR_CHANNEL,
    AVATAR_NO_MESSAGE,
    AVATAR_WITH_MESSAGE,
    DEFAULT_MAX_STEPS,
    GRID,
    HALF_MAX,
    MOVEMENTS,
    NUM_ACTIONS,
    NUM_CHANNELS,
    REWARD_DEATH,
    REWARD_PICKUP,
    REWARD_WIN,
    STARTS,
)
from .spec import GameSpec

CHASER, FLEEING, IMMOVABLE = (MOVEMENTS.index(m) for m in ("chaser", "fleeing", "immovable"))
ENEMY, MESSAGE, GOAL = 0, 1, 2

# A uniform choice among the qualifying directions enumerates them in the order up, down, left,
# right. With a qualifying set as a 4-bit mask (bit d = direction d), two lookup tables give the
# number of choices and the k-th direction, which keeps the movement rule a handful of array ops.
_DIR_DR = np.array([-1, 1, 0, 0], dtype=np.int64)
_DIR_DC = np.array([0, 0, -1, 1], dtype=np.int64)
_MASK_COUNT = np.array([bin(m).count("1") if m else 4 for m in range(16)], dtype=np.int64)
_MASK_KTH = np.array(
    [[[d for d in range(4) if (m or 15) >> d & 1][min(k, _MASK_COUNT[m] - 1)] for k in range(4)] for m in range(16)],
    dtype=np.int64,
)  # [16 masks, 4 picks] -> direction; mask 0 (nothing qualifies) behaves as all four
_ACTION_DR = 2 * np.array([d[0] for d in ACTION_DELTAS], dtype=np.int64)
_ACTION_DC = 2 * np.array([d[1] for d in ACTION_DELTAS], dtype=np.int64)
_STARTS = np.array(STARTS, dtype=np.int64) * 2  # [24, 4 (avatar, enemy, message, goal), 2]
CHANNEL_PERMUTATIONS: tuple[tuple[int, int, int], ...] = tuple(itertools.permutations(range(3)))
_CHANNEL_PERMS = np.array(CHANNEL_PERMUTATIONS, dtype=np.int64)


def entity_moves(
    rows: np.ndarray,
    cols: np.ndarray,
    avatar_row: np.ndarray,
    avatar_col: np.ndarray,
    movement: np.ndarray,
    u: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Half-cell (rows, cols) [N, 3] after every entity's 1-half-cell move, decided from the
    avatar's position before it moves. `u` [N, 3] are the uniform draws that pick a direction.

    A 1-half-cell move changes the Manhattan distance by exactly one, so the directions that
    increase it (fleeing) are the complement of those that decrease it (chasing).
    """
    dr = avatar_row[:, None] - rows
    dc = avatar_col[:, None] - cols
    closer = (dr < 0) * 1 | (dr > 0) * 2 | (dc < 0) * 4 | (dc > 0) * 8
    mask = np.where(movement == FLEEING, 15 - closer, closer)
    pick = rng.choice_index(u, _MASK_COUNT[mask])
    direction = _MASK_KTH[mask, pick]
    new_r = rows + _DIR_DR[direction]
    new_c = cols + _DIR_DC[direction]
    moves = (movement != IMMOVABLE) & (new_r >= 0) & (new_r <= HALF_MAX) & (new_c >= 0) & (new_c <= HALF_MAX)
    return np.where(moves, new_r, rows), np.where(moves, new_c, cols)


def overlaps(rows: np.ndarray, cols: np.ndarray, avatar_row: np.ndarray, avatar_col: np.ndarray) -> np.ndarray:
    """[N, 3] whether each entity's sprite overlaps the avatar's (< 1 cell apart on both axes)."""
    return (np.abs(rows - avatar_row[:, None]) < 2) & (np.abs(cols - avatar_col[:, None]) < 2)


class BatchedMessenger:
    """N Messenger games in lockstep.

    `reset(specs, seeds, starts=None)` starts one episode per spec; `step(actions)` advances all
    games that are still running. Observations can be read as 10x10x4 grids (`observation()`) or
    in the compact per-channel form (id, row, col) used by the dataset (`compact_observation()`).
    """

    def __init__(self, max_steps: int = DEFAULT_MAX_STEPS) -> None:
        if max_steps < 1:
            raise ValueError(f"max_steps must be >= 1, got {max_steps}")
        self.max_steps = max_steps
        self.n = 0

    def reset(
        self,
        specs: Sequence[GameSpec],
        seeds: Sequence[int] | np.ndarray,
        starts: Sequence[int] | np.ndarray | None = None,
    ) -> np.ndarray:
        """Start one episode per game; returns the first grid observations [N, 10, 10, 4]."""
        seeds = np.asarray(seeds, dtype=np.int64)
        n = len(specs)
        if seeds.shape != (n,):
            raise ShapeError(f"need one seed per game: {n} specs, seeds of shape {seeds.shape}")
        self.n = n
        self.seeds = seeds
        self.keys = rng.seed_keys(seeds)
        if starts is None:
            starts = rng.choice_index(rng.uniform_np(self.keys, 0, rng.SLOT_START), len(STARTS))
        starts = np.asarray(starts, dtype=np.int64)
        if starts.shape != (n,) or (starts < 0).any() or (starts >= len(STARTS)).any():
            raise ShapeError(f"starts must be {n} indices in 0..{len(STARTS) - 1}")
        self.starts = starts
        perm_idx = rng.choice_index(rng.uniform_np(self.keys, 0, rng.SLOT_CHANNELS), len(_CHANNEL_PERMS))
        self.channel_roles = _CHANNEL_PERMS[perm_idx]
        self.entity_ids = np.array([[e.entity_id for e in s.entities] for s in specs], dtype=np.int64).reshape(n, 3)
        self.movement = np.array(
            [[MOVEMENTS.index(e.movement) for e in s.entities] for s in specs], dtype=np.int64
        ).reshape(n, 3)
        cells = _STARTS[starts]  # [N, 4, 2]
        self.avatar_row, self.avatar_col = cells[:, 0, 0].copy(), cells[:, 0, 1].copy()
        self.entity_row, self.entity_col = cells[:, 1:, 0].copy(), cells[:, 1:, 1].copy()
        self.present = np.ones((n, 3), dtype=bool)
        self.has_message = np.zeros(n, dtype=bool)
        self.alive = np.ones(n, dtype=bool)
        self.won = np.zeros(n, dtype=bool)
        self.done = np.zeros(n, dtype=bool)
        self.t = 0
        return self.observation()

    def step(self, actions: np.ndarray | Sequence[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Advance every running game by one action.

        Returns (rewards [N] float32, terminated [N], truncated [N], running_before [N]): the flags
        are those of this step; games that had already ended get reward 0 and False flags, and
        `running_before` says which games this step applied to.
        """
        if self.n == 0:
            raise GameStateError("step() before reset()")
        actions = np.asarray(actions)
        if actions.shape != (self.n,):
            raise InvalidActionError(f"need one action per game, shape ({self.n},), got {actions.shape}")
        if not np.issubdtype(actions.dtype, np.integer):
            raise InvalidActionError(f"actions must be integers, got dtype {actions.dtype}")
        if ((actions < 0) | (actions >= NUM_ACTIONS)).any():
            bad = actions[(actions < 0) | (actions >= NUM_ACTIONS)]
            raise InvalidActionError(f"actions must be in 0..{NUM_ACTIONS - 1}, got {bad[:5].tolist()}")
        actions = actions.astype(np.int64)
        running = ~self.done
        self.t += 1

        # (1) Entities move, deciding from the avatar's position before it moves.
        u = rng.uniform_np(self.keys[:, None], self.t, np.arange(3)[None, :])
        new_r, new_c = entity_moves(
            self.entity_row, self.entity_col, self.avatar_row, self.avatar_col, self.movement, u
        )
        active = running[:, None] & self.present
        self.entity_row = np.where(active, new_r, self.entity_row)
        self.entity_col = np.where(active, new_c, self.entity_col)

        # (2) The avatar moves one cell; a move off the board is undone.
        new_r = self.avatar_row + _ACTION_DR[actions]
        new_c = self.avatar_col + _ACTION_DC[actions]
        ok = running & (new_r >= 0) & (new_r <= HALF_MAX) & (new_c >= 0) & (new_c <= HALF_MAX)
        self.avatar_row = np.where(ok, new_r, self.avatar_row)
        self.avatar_col = np.where(ok, new_c, self.avatar_col)

        # (3) Collisions, in priority order.
        hit = overlaps(self.entity_row, self.entity_col, self.avatar_row, self.avatar_col)
        hit &= self.present & running[:, None]
        dies = hit[:, ENEMY] | (~self.has_message & hit[:, GOAL])
        picks = ~dies & ~self.has_message & hit[:, MESSAGE]
        wins = ~dies & self.has_message & hit[:, GOAL]
        rewards = np.zeros(self.n, dtype=np.float32)
        rewards[dies] = REWARD_DEATH
        rewards[picks] = REWARD_PICKUP
        rewards[wins] = REWARD_WIN
        # The message leaves the board on any overlap (a pick-up, or a death in the same step:
        # it is removed before the avatar is); on a win the goal leaves it (docs/game.md, "The last frame").
        self.present[hit[:, MESSAGE], MESSAGE] = False
        self.present[wins, GOAL] = False
        self.has_message |= picks
        self.alive &= ~dies
        self.won |= wins

        terminated = running & (dies | wins)
        truncated = running & ~terminated & (self.t >= self.max_steps)
        self.done |= terminated | truncated
        return rewards, terminated, truncated, running

    def compact_observation(self) -> np.ndarray:
        """[N, 4, 3] uint8: per channel (id, row, col) in cells; an empty channel is (0, 0, 0).

        This is exactly the information of the grid observation (one sprite per channel), in the
        form the tokenizer and the dataset use.
        """
        out = np.empty((self.n, NUM_CHANNELS, 3), dtype=np.uint8)
        rows = np.arange(self.n)[:, None]
        roles = self.channel_roles
        shown = self.present[rows, roles]
        out[:, :3, 0] = np.where(shown, self.entity_ids[rows, roles], 0)
        out[:, :3, 1] = np.where(shown, self.entity_row[rows, roles] // 2, 0)
        out[:, :3, 2] = np.where(shown, self.entity_col[rows, roles] // 2, 0)
        avatar_id = np.where(self.has_message, AVATAR_WITH_MESSAGE, AVATAR_NO_MESSAGE)
        out[:, AVATAR_CHANNEL, 0] = np.where(self.alive, avatar_id, 0)
        out[:, AVATAR_CHANNEL, 1] = np.where(self.alive, self.avatar_row // 2, 0)
        out[:, AVATAR_CHANNEL, 2] = np.where(self.alive, self.avatar_col // 2, 0)
        return out

    def observation(self) -> np.ndarray:
        """[N, 10, 10, 4] uint8 grid observations."""
        return compact_to_grid(self.compact_observation())

    def role_cells(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """What the behaviour policies read off the observation, in role order:
        (avatar cell [N, 2], entity cells [N, 3, 2], entity shown [N, 3])."""
        avatar = np.stack([self.avatar_row, self.avatar_col], axis=-1) // 2
        entities = np.stack([self.entity_row, self.entity_col], axis=-1) // 2
        return avatar, entities, self.present.copy()


def compact_to_grid(compact: np.ndarray) -> np.ndarray:
    """[..., 4, 3] (id, row, col) per channel -> [..., 10, 10, 4] grids."""
    compact = np.asarray(compact)
    if compact.shape[-2:] != (NUM_CHANNELS, 3):
        raise ShapeError(f"compact observations end in ({NUM_CHANNELS}, 3), got {compact.shape}")
    lead = compact.shape[:-2]
    flat = compact.reshape(-1, NUM_CHANNELS, 3).astype(np.int64)
    grid = np.zeros((flat.shape[0], GRID, GRID, NUM_CHANNELS), dtype=np.uint8)
    b, c = np.nonzero(flat[:, :, 0])
    grid[b, flat[b, c, 1], flat[b, c, 2], c] = flat[b, c, 0]
    return grid.reshape(*lead, GRID, GRID, NUM_CHANNELS)


def grid_to_compact(grid: np.ndarray) -> np.ndarray:
    """[..., 10, 10, 4] grids -> [..., 4, 3]; raises ShapeError if a channel holds two sprites."""
    grid = np.asarray(grid)
    if grid.shape[-3:] != (GRID, GRID, NUM_CHANNELS):
        raise ShapeError(f"grid observations end in ({GRID}, {GRID}, {NUM_CHANNELS}), got {grid.shape}")
    lead = grid.shape[:-3]
    flat = grid.reshape(-1, GRID * GRID, NUM_CHANNELS)
    nonzero = (flat != 0).sum(1)
    if (nonzero > 1).any():
        raise ShapeError("a channel of a Messenger observation holds at most one sprite")
    where = (flat != 0).argmax(1)  # [B, 4]
    ids = np.take_along_axis(flat, where[:, None, :], axis=1)[:, 0]
    out = np.stack([ids, where // GRID, where % GRID], axis=-1)
    out[nonzero == 0] = 0
    return out.astype(np.uint8).reshape(*lead, NUM_CHANNELS, 3)
