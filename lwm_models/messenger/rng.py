"""Counter-based randomness: every random draw of an episode is a pure function of
(episode seed, step, slot).

Why not a stateful generator: the single-game and the batched engines must produce identical
episodes from the same seed, whatever the batch size or the other games in the batch. Hashing the
draw's coordinates (splitmix64 finaliser) gives that for free, vectorises over numpy arrays, and
makes each episode reproducible on its own from its seed.

Slots in use (keep them disjoint):
- step 0: SLOT_START (which of the 24 starts), SLOT_CHANNELS (channel permutation);
- step t >= 1: 0..2 the movement choice of the enemy, message and goal entities;
- POLICY_SLOT_BASE + k: behaviour policies' draws when choosing the action that leads to step t.
"""

from __future__ import annotations

import numpy as np

SLOT_START = 0
SLOT_CHANNELS = 1
POLICY_SLOT_BASE = 16

_MASK = (1 << 64) - 1
_GOLDEN = 0x9E3779B97F4A7C15
_M1 = 0xBF58476D1CE4E5B9
_M2 = 0x94D049BB133111EB


def _mix(z: int) -> int:
    z = ((z ^ (z >> 30)) * _M1) & _MASK
    z = ((z ^ (z >> 27)) * _M2) & _MASK
    return z ^ (z >> 31)


def uniform(seed: int, step: int, slot: int) -> float:
    """A number in [0, 1) fixed by (seed, step, slot): the scalar reference implementation."""
    key = (_mix((seed * _GOLDEN) & _MASK) + (step << 8) + slot) & _MASK
    return (_mix(key) >> 11) * (1.0 / (1 << 53))


def _mix_np(z: np.ndarray) -> np.ndarray:
    z = (z ^ (z >> np.uint64(30))) * np.uint64(_M1)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(_M2)
    return z ^ (z >> np.uint64(31))


def seed_keys(seeds: np.ndarray) -> np.ndarray:
    """Pre-mixed seeds (uint64), to be passed to uniform_np; computing them once per episode
    saves a third of the work of every later draw."""
    s = np.asarray(seeds).astype(np.int64).astype(np.uint64)
    return _mix_np(s * np.uint64(_GOLDEN))


def uniform_np(keys: np.ndarray, step: np.ndarray | int, slot: np.ndarray | int) -> np.ndarray:
    """Vectorised `uniform`; `keys` from seed_keys, `step` and `slot` broadcast against it.

    uint64 arithmetic in numpy wraps modulo 2**64 exactly like the masked Python ints above.
    """
    step_u = np.asarray(step).astype(np.uint64)
    slot_u = np.asarray(slot).astype(np.uint64)
    key = keys + (step_u << np.uint64(8)) + slot_u
    return (_mix_np(key) >> np.uint64(11)).astype(np.float64) * (1.0 / (1 << 53))


def choice_index(u: np.ndarray | float, count: np.ndarray | int) -> np.ndarray | int:
    """floor(u * count): the index of a uniform choice among `count` options."""
    if isinstance(u, float):
        return min(int(u * count), int(count) - 1)
    return np.minimum((u * count).astype(np.int64), np.asarray(count) - 1)
