"""Decoding constraints: the game's rules as masks over the tokens a world model may sample.

A world model samples each block's 14 tokens from its own beliefs, and a model that is not sharp
enough imagines what no Messenger game can do: a bird that becomes a dog, an entity that vanishes
with nothing near it, an avatar that jumps three cells, a reward with nothing in reach. For plans
shown to a person these are worse than noise: they make a plan look possible or doomed for a
reason the game does not have. With constraints, each token is sampled from the model's
distribution restricted to the tokens the rules allow after what the row has imagined so far
(the model's probabilities renormalised over them), so the model still decides everything the
rules leave open: where a chaser goes, whether a collision in reach happens.

The rules (docs/game.md, "The game"), from the previous observation and the action:
- an entity channel keeps its identity or becomes empty, and only when the entity was within
  collision reach of the avatar's new cell (`_could_collide`: the most any movement allows when
  the entities' half-cell positions are unknown); an empty channel stays empty;
- an entity moves at most one cell (one half-cell a step); the avatar moves exactly by its
  action (its half-cell position is always even), a move off the board undone;
- the avatar may die (empty channel) only when an entity now overlaps it; it takes the message (15 to
  16) exactly when an entity vanished (the message is picked up) and never puts it down;
- the reward follows from what the observation shows: -1 when the avatar died, +0.5 when it took
  the message, +1 when an entity vanished beside an avatar that carries the message (the goal,
  delivered), otherwise 0; the episode ends exactly with a -1 or +1, or at the time limit.

Constraints are for plans shown to people; the paper's figures (Table 2) are raw sampling, and
`lwm eval --constrained` reports the constrained ones beside them.
"""

from __future__ import annotations

import numpy as np
import torch

from ..messenger.constants import (
    ACTION_DELTAS,
    AVATAR_NO_MESSAGE,
    AVATAR_WITH_MESSAGE,
    DEFAULT_MAX_STEPS,
    GRID,
    NUM_ACTIONS,
)
from .tokens import (
    COL_OFFSET,
    DONE_VOCAB,
    OBS_TOKENS,
    OBS_VOCAB,
    REWARD_VOCAB,
    ROW_OFFSET,
    obs_to_tokens,
    reward_label,
)


def _could_collide(dr: torch.Tensor, dc: torch.Tensor) -> torch.Tensor:
    """Whether an entity (dr, dc) cells from the avatar's new cell before its own move of one
    half-cell can overlap the avatar after it: sprites overlap when under one cell apart on both
    axes, i.e. the entity's new cell is the avatar's or the one above or left of it, and one
    half-cell on one axis reaches that from one cell further on that axis. Within 2 cells
    (Manhattan), but never from the cell diagonally below and right.
    """
    return (dr.abs() <= 1) & (dc.abs() <= 1) & ~((dr == 1) & (dc == 1))


_DELTAS = torch.tensor(ACTION_DELTAS + ((0, 0),), dtype=torch.long)  # the dummy action stays
_DEATH, _PICKUP, _WIN, _NONE = (int(reward_label(r)) for r in (-1.0, 0.5, 1.0, 0.0))


class StepRules:
    """The tokens the rules allow at each of one step's 14 sampled slots, for every row.

    prev: [rows, 12] the rows' last observation tokens; actions: [rows] the actions just taken;
    at_limit: [rows] whether this is the row's last step (the time limit).
    Call `allowed(k, sampled)` for k = 0..13 in order, `sampled` holding the tokens of slots 0..k-1
    of this block; it returns a [rows, vocab] boolean mask (the observation, reward or done
    vocabulary) with at least one token allowed in every row.
    """

    def __init__(self, prev: torch.Tensor, actions: torch.Tensor, at_limit: torch.Tensor | None = None) -> None:
        self.prev = prev.long()
        self.at_limit = torch.zeros(len(prev), dtype=torch.bool) if at_limit is None else at_limit
        ids = self.prev[:, 0::3]  # [rows, 4]
        rows, cols = self.prev[:, 1::3] - ROW_OFFSET, self.prev[:, 2::3] - COL_OFFSET
        delta = _DELTAS[actions.long().clamp(0, NUM_ACTIONS)]
        self.avatar_row = (rows[:, 3] + delta[:, 0]).clamp(0, GRID - 1)
        self.avatar_col = (cols[:, 3] + delta[:, 1]).clamp(0, GRID - 1)
        dr, dc = rows[:, :3] - self.avatar_row[:, None], cols[:, :3] - self.avatar_col[:, None]
        self.alive = ids[:, 3] > 0
        # Without an avatar nothing can be judged in reach; such a row's trajectory has ended.
        self.in_reach = (ids[:, :3] > 0) & (_could_collide(dr, dc) | ~self.alive[:, None])  # [rows, 3]
        self.ids, self.rows, self.cols = ids, rows, cols
        self._arange = torch.arange(len(prev))

    def allowed(self, k: int, sampled: list[torch.Tensor]) -> torch.Tensor:
        if k < OBS_TOKENS:
            return self._obs(k // 3, k % 3, sampled)
        if k == OBS_TOKENS:
            return self._reward(sampled)
        return self._done(sampled)

    def _one_hot(self, token: torch.Tensor, vocab: int) -> torch.Tensor:
        mask = torch.zeros(len(token), vocab, dtype=torch.bool)
        mask[self._arange, token] = True
        return mask

    def _obs(self, channel: int, part: int, sampled: list[torch.Tensor]) -> torch.Tensor:
        prev_id = self.ids[:, channel]
        if part == 0:
            mask = self._one_hot(prev_id, OBS_VOCAB)
            if channel < 3:
                mask[:, 0] |= self.in_reach[:, channel]
            else:
                self._avatar_ids(mask, prev_id, sampled)
            return mask
        now_id = sampled[3 * channel]
        empty = now_id == 0
        if channel == 3:  # the avatar: exactly where its action takes it
            offset = ROW_OFFSET if part == 1 else COL_OFFSET
            cell = self.avatar_row if part == 1 else self.avatar_col
            return self._one_hot(torch.where(empty, offset, offset + cell), OBS_VOCAB)
        mask = torch.zeros(len(prev_id), OBS_VOCAB, dtype=torch.bool)
        if part == 1:
            base, offset, moved = self.rows[:, channel], ROW_OFFSET, torch.ones_like(empty)
        else:
            base, offset = self.cols[:, channel], COL_OFFSET
            # One half-cell a step: a row that changed leaves the column as it was.
            moved = sampled[3 * channel + 1] - ROW_OFFSET == self.rows[:, channel]
        for d in (-1, 0, 1):
            cell = base + d
            ok = (cell >= 0) & (cell < GRID) & (moved | (d == 0))
            mask[self._arange[ok], offset + cell[ok]] = True
        mask[empty] = False
        mask[:, offset] |= empty  # an empty channel reads (0, 0, 0)
        return mask

    def _avatar_ids(self, mask: torch.Tensor, prev_id: torch.Tensor, sampled: list[torch.Tensor]) -> None:
        vanished = self._vanished(sampled)
        # A death needs an entity that overlaps the avatar now: its cell is the avatar's or the one
        # above or left of it (a sprite half a cell off shows in the lower cell index).
        overlaps = torch.zeros_like(vanished)
        for c in range(3):
            dr = sampled[3 * c + 1] - ROW_OFFSET - self.avatar_row
            dc = sampled[3 * c + 2] - COL_OFFSET - self.avatar_col
            overlaps |= (sampled[3 * c] > 0) & (dr >= -1) & (dr <= 0) & (dc >= -1) & (dc <= 0)
        reach = overlaps
        carrying = prev_id == AVATAR_WITH_MESSAGE
        taking = (prev_id == AVATAR_NO_MESSAGE) & vanished
        # An entity gone beside an avatar without the message was the message: picked up (16), or
        # removed by a death in the same step.
        mask[taking, AVATAR_NO_MESSAGE] = False
        mask[taking, AVATAR_WITH_MESSAGE] = True
        mask[:, 0] |= self.alive & (reach | vanished)
        # A win leaves the avatar on the board: the goal vanished beside an avatar carrying the message.
        mask[carrying & vanished, 0] = False

    def _vanished(self, sampled: list[torch.Tensor]) -> torch.Tensor:
        now = torch.stack([sampled[0], sampled[3], sampled[6]], 1)
        return ((self.ids[:, :3] > 0) & (now == 0)).any(1)

    def _reward_label(self, sampled: list[torch.Tensor]) -> torch.Tensor:
        avatar = sampled[9]
        label = torch.full_like(avatar, _NONE)
        label = torch.where(self._vanished(sampled) & (avatar == AVATAR_WITH_MESSAGE), _WIN, label)
        label = torch.where((self.ids[:, 3] == AVATAR_NO_MESSAGE) & (avatar == AVATAR_WITH_MESSAGE), _PICKUP, label)
        label = torch.where(self.alive & (avatar == 0), _DEATH, label)
        return label

    def _reward(self, sampled: list[torch.Tensor]) -> torch.Tensor:
        return self._one_hot(self._reward_label(sampled), REWARD_VOCAB)

    def _done(self, sampled: list[torch.Tensor]) -> torch.Tensor:
        ends = (sampled[OBS_TOKENS] == _DEATH) | (sampled[OBS_TOKENS] == _WIN)
        mask = self._one_hot(ends.long(), DONE_VOCAB)
        mask[:, 1] |= self.at_limit  # the last step may read done: the game's data marks it so
        return mask


def rule_breaks(
    observations: np.ndarray,
    actions: np.ndarray,
    rewards: np.ndarray,
    dones: np.ndarray,
    lengths: np.ndarray,
    max_steps: int = DEFAULT_MAX_STEPS,
) -> tuple[np.ndarray, int]:
    """How many tokens of trajectories ([n, T + 1, ...] as imagined or played) break a rule, per
    slot of the step ([14]), and the number of steps: 0 everywhere for the real game."""
    prev, act, block, limit = [], [], [], []
    for i in range(len(lengths)):
        for t in range(1, int(lengths[i])):
            prev.append(obs_to_tokens(observations[i, t - 1]))
            act.append(int(actions[i, t]))
            label = int(reward_label(float(rewards[i, t])))
            block.append(np.concatenate([obs_to_tokens(observations[i, t]), [label, int(dones[i, t])]]))
            limit.append(t >= max_steps)
    breaks = np.zeros(OBS_TOKENS + 2, dtype=np.int64)
    if not block:
        return breaks, 0
    tokens = torch.tensor(np.array(block), dtype=torch.long)
    rules = StepRules(torch.tensor(np.array(prev)), torch.tensor(act), torch.tensor(limit))
    sampled: list[torch.Tensor] = []
    for k in range(OBS_TOKENS + 2):
        breaks[k] = int((~rules.allowed(k, sampled)[torch.arange(len(tokens)), tokens[:, k]]).sum())
        sampled.append(tokens[:, k])
    return breaks, len(tokens)


__all__ = ["StepRules", "rule_breaks"]
