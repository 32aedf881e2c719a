"""The five behaviour policies that generate Messenger-WM trajectories (docs/game.md), vectorised over games.

They read the observation with privileged knowledge of each entity's role (they play the true
manual): positions are cells, distances Manhattan in cells. Every random draw comes from the
episode's counter-based stream (`rng.uniform_np` with POLICY_SLOT_BASE slots), so a trajectory is
a function of its seed and policy only, whatever the batch it was generated in.
"""

from __future__ import annotations

import numpy as np

from . import rng
from .constants import ACTION_DELTAS, GRID, NUM_ACTIONS

POLICIES: tuple[str, ...] = ("random", "suicide", "survive", "get_message", "go_to_goal")

_DELTAS = np.array(ACTION_DELTAS, dtype=np.int64)  # [5, 2] in cells
_SLOT_RANDOM = rng.POLICY_SLOT_BASE
_SLOT_CHOICE = rng.POLICY_SLOT_BASE + 1
SURVIVE_SAFE = 6
"""survive acts randomly while every threat is at least this far."""
SURVIVE_KEEP = 3
"""otherwise it prefers actions that keep every threat at least this far."""


def _next_cells(avatar: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cells after each of the 5 actions [N, 5, 2] and whether that move stays on the board."""
    nxt = avatar[:, None, :] + _DELTAS[None]
    valid = ((nxt >= 0) & (nxt < GRID)).all(-1)
    return nxt, valid


def _uniform_among(mask: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Index of a uniformly chosen True entry of each row of `mask` [N, 5] (rows have one)."""
    pick = rng.choice_index(u, mask.sum(-1))
    return (np.cumsum(mask, axis=-1) > pick[:, None]).argmax(-1)


def greedy_choices(avatar: np.ndarray, target: np.ndarray) -> np.ndarray:
    """[N, 5]: the on-board actions that reach the smallest distance to `target`."""
    nxt, valid = _next_cells(avatar)
    dist = np.abs(nxt - target[:, None, :]).sum(-1)
    dist = np.where(valid, dist, np.iinfo(np.int64).max)
    return dist == dist.min(-1, keepdims=True)


def greedy_step(avatar: np.ndarray, target: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Among on-board actions, one that reaches the smallest distance to `target`, ties uniform
    (the same distribution as trying the 5 actions in random order and taking the first best)."""
    return _uniform_among(greedy_choices(avatar, target), u)


def behaviour_actions(
    policy: np.ndarray,
    avatar: np.ndarray,
    entities: np.ndarray,
    present: np.ndarray,
    has_message: np.ndarray,
    keys: np.ndarray,
    t: int,
) -> np.ndarray:
    """Actions [N] for games that each follow `policy` [N] (indices into POLICIES).

    avatar [N, 2] and entities [N, 3, 2] are cells in role order (enemy, message, goal), present
    [N, 3] says which entities are shown, keys are the episodes' rng keys and t the step whose
    action is chosen (1 for the first action).
    """
    n = avatar.shape[0]
    u_random = rng.uniform_np(keys, t, _SLOT_RANDOM)
    u_choice = rng.uniform_np(keys, t, _SLOT_CHOICE)
    actions = rng.choice_index(u_random, NUM_ACTIONS)  # policy 0, and the default of the others
    enemy, message, goal = entities[:, 0], entities[:, 1], entities[:, 2]

    to_enemy = greedy_step(avatar, enemy, u_choice)
    to_message = greedy_step(avatar, message, u_choice)
    to_goal = greedy_step(avatar, goal, u_choice)
    seek_message = ~has_message & present[:, 1]

    actions = np.where(policy == 1, to_enemy, actions)
    actions = np.where((policy == 3) & seek_message, to_message, actions)
    actions = np.where((policy == 4), np.where(seek_message, to_message, to_goal), actions)

    is_survive = policy == 2
    if is_survive.any():
        actions = np.where(is_survive, _survive(avatar, enemy, goal, has_message, u_random, u_choice), actions)
    return actions.astype(np.int64).reshape(n)


def _survive(
    avatar: np.ndarray,
    enemy: np.ndarray,
    goal: np.ndarray,
    has_message: np.ndarray,
    u_random: np.ndarray,
    u_choice: np.ndarray,
) -> np.ndarray:
    big = 4 * GRID
    # Threats: the enemy always, the goal only while the avatar does not carry the message.
    threat_goal = ~has_message
    d_enemy = np.abs(avatar - enemy).sum(-1)
    d_goal = np.where(threat_goal, np.abs(avatar - goal).sum(-1), big)
    calm = np.minimum(d_enemy, d_goal) >= SURVIVE_SAFE

    nxt, valid = _next_cells(avatar)
    nd_enemy = np.abs(nxt - enemy[:, None]).sum(-1)
    nd_goal = np.where(threat_goal[:, None], np.abs(nxt - goal[:, None]).sum(-1), big)
    nearest = np.where(valid, np.minimum(nd_enemy, nd_goal), -1)
    keeps = nearest >= SURVIVE_KEEP
    any_keeps = keeps.any(-1)
    best = nearest == nearest.max(-1, keepdims=True)
    escape = _uniform_among(np.where(any_keeps[:, None], keeps, best), u_choice)
    return np.where(calm, rng.choice_index(u_random, NUM_ACTIONS), escape)


def policy_index(name: str) -> int:
    """Index of a policy by name, with a clear error for unknown names."""
    if name not in POLICIES:
        raise ValueError(f"unknown behaviour policy {name!r}; known: {list(POLICIES)}")
    return POLICIES.index(name)
