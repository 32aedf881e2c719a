"""The world models' tokenizer (docs/world-models.md): a step is a block of 15 tokens,

    [action that led here, 12 observation tokens, reward label, done label]

with, per observation channel, an id token (0..16), a row token (17 + row) and a column token
(27 + column); an empty channel is (0, 17, 27). Each slot kind has its own vocabulary and its own
embedding table in the models, so the action, reward and done tokens are small integers.
"""

from __future__ import annotations

import numpy as np

from ..errors import ShapeError
from ..messenger.constants import GRID, NUM_ACTIONS, NUM_CHANNELS, NUM_IDS

ROW_OFFSET = NUM_IDS  # 17
COL_OFFSET = NUM_IDS + GRID  # 27
OBS_VOCAB = NUM_IDS + 2 * GRID  # 37
OBS_TOKENS = 3 * NUM_CHANNELS  # 12
BLOCK = OBS_TOKENS + 3  # 15
ACTION_VOCAB = NUM_ACTIONS + 1  # 5 actions and the dummy of an episode's first block
DUMMY_ACTION = NUM_ACTIONS
REWARD_VOCAB = 5
DONE_VOCAB = 2
REWARD_VALUES = np.array([-1.0, -0.5, 0.0, 0.5, 1.0], dtype=np.float32)
"""Reward label k means reward REWARD_VALUES[k] (label = (r + 1) * 2; -0.5 never occurs)."""
FIRST_REWARD_LABEL = 2
"""The first block's reward label: 2 (reward 0), as in training (the original imagined with 0)."""
MAX_BLOCKS = 33

# Slot kinds within a block.
SLOT_ACTION, SLOT_OBS, SLOT_REWARD, SLOT_DONE = 0, 1, 2, 3
SLOT_KIND = np.array([SLOT_ACTION] + [SLOT_OBS] * OBS_TOKENS + [SLOT_REWARD, SLOT_DONE], dtype=np.int64)
ID_SLOTS = np.array([1 + 3 * c for c in range(NUM_CHANNELS - 1)], dtype=np.int64)
"""Positions (within a block) of the entity channels' id tokens: EMMA conditions these."""


def reward_label(reward: np.ndarray | float) -> np.ndarray:
    """(r + 1) * 2: -1 -> 0, 0 -> 2, 0.5 -> 3, 1 -> 4."""
    labels = np.rint((np.asarray(reward, dtype=np.float64) + 1.0) * 2.0).astype(np.int64)
    if ((labels < 0) | (labels >= REWARD_VOCAB)).any():
        raise ValueError(f"rewards must lie in [-1, 1], got {np.asarray(reward)}")
    return labels


def obs_to_tokens(compact: np.ndarray) -> np.ndarray:
    """Compact observations [..., 4, 3] (id, row, col) -> [..., 12] observation tokens."""
    compact = np.asarray(compact)
    if compact.shape[-2:] != (NUM_CHANNELS, 3):
        raise ShapeError(f"compact observations end in ({NUM_CHANNELS}, 3), got {compact.shape}")
    c = compact.astype(np.int64)
    tokens = np.stack([c[..., 0], ROW_OFFSET + c[..., 1], COL_OFFSET + c[..., 2]], axis=-1)
    return tokens.reshape(*compact.shape[:-2], OBS_TOKENS)


def first_block_tokens(first: np.ndarray) -> np.ndarray:
    """The block imagination feeds first [n, 14] for start observations [n, 4, 3]: the dummy
    action, the observation's tokens and the first reward label; its done token is fed with the
    first action, as every later block's is."""
    block = np.zeros((len(first), BLOCK - 1), dtype=np.int64)
    block[:, 0] = DUMMY_ACTION
    block[:, 1 : 1 + OBS_TOKENS] = obs_to_tokens(first)
    block[:, -1] = FIRST_REWARD_LABEL
    return block


def _slot_values() -> np.ndarray:
    """[3, OBS_VOCAB]: what each token means in an id, row and column slot (clipped into range;
    an id token out of the ids' range is 0, an empty channel)."""
    v = np.arange(OBS_VOCAB)
    ids = np.where(v < NUM_IDS, v, 0)
    return np.stack([ids, np.clip(v - ROW_OFFSET, 0, GRID - 1), np.clip(v - COL_OFFSET, 0, GRID - 1)]).astype(np.uint8)


_SLOT_VALUES = _slot_values()


def tokens_to_obs(tokens: np.ndarray) -> np.ndarray:
    """[..., 12] observation tokens -> compact observations [..., 4, 3].

    Tokens out of their slot's range (a model can sample a row token where an id belongs) are
    clipped into range; an id of 0 empties the channel whatever its row and column say. (A table
    lookup: imagination calls this at every step, where numpy's per-call cost dominates.)
    """
    tokens = np.asarray(tokens)
    if tokens.shape[-1] != OBS_TOKENS:
        raise ShapeError(f"observation tokens end in {OBS_TOKENS}, got {tokens.shape}")
    t = tokens.reshape(*tokens.shape[:-1], NUM_CHANNELS, 3).astype(np.int64, copy=False)
    if t.size and (t.min() < 0 or t.max() >= OBS_VOCAB):
        t = np.clip(t, 0, OBS_VOCAB - 1)  # below or above every slot's range: its first or last value
    out = _SLOT_VALUES[np.arange(3), t]
    out[..., 1:] *= out[..., :1] > 0
    return out
