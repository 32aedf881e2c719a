"""The expert and the simulated human's action labels: a behaviour policy (go_to_goal by default)
that reads observations knowing each entity's true role (it reads the true manual)."""

from __future__ import annotations

import numpy as np

from ..messenger.constants import AVATAR_WITH_MESSAGE, IDENTITIES
from ..messenger.policies import behaviour_actions, greedy_choices, policy_index
from ..messenger.rng import seed_keys
from ..messenger.spec import GameSpec


def role_ids(game: GameSpec) -> np.ndarray:
    """Observation ids of the game's entities in role order (enemy, message, goal)."""
    return np.array([IDENTITIES[e.identity] for e in game.entities], dtype=np.int64)


def role_view(obs: np.ndarray, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """From compact observations [n, 4, 3] and role ids [3] or [n, 3]: avatar cells [n, 2], entity
    cells in role order [n, 3, 2], which entities are shown [n, 3], whether the avatar carries the
    message [n]."""
    n = obs.shape[0]
    ids = np.broadcast_to(ids, (n, 3))
    avatar = obs[:, 3, 1:].astype(np.int64)
    hit = obs[:, None, :3, 0] == ids[:, :, None]  # [n, role, channel]
    present = hit.any(-1)
    channel = hit.argmax(-1)
    entities = obs[np.arange(n)[:, None], channel, 1:].astype(np.int64)
    return avatar, entities, present, obs[:, 3, 0] == AVATAR_WITH_MESSAGE


def expert_actions(
    obs: np.ndarray, ids: np.ndarray, t: int, seeds: np.ndarray | int = 0, policy: str = "go_to_goal"
) -> np.ndarray:
    """The expert's action for each observation [n, 4, 3] at step t (1 for the first action)."""
    n = obs.shape[0]
    avatar, entities, present, carrying = role_view(np.asarray(obs), ids)
    keys = seed_keys(np.broadcast_to(np.asarray(seeds), (n,)))
    return behaviour_actions(np.full(n, policy_index(policy)), avatar, entities, present, carrying, keys, t)


def expert_choices(obs: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """[n, 5]: the actions among which go_to_goal chooses (uniformly) in each observation [n, 4, 3]:
    the greedy steps toward the message while it is on the board and not carried, else toward the
    goal. What it would do, without the draw that breaks its ties."""
    avatar, entities, present, carrying = role_view(np.asarray(obs), ids)
    seek_message = ~carrying & present[:, 1]
    target = np.where(seek_message[:, None], entities[:, 1], entities[:, 2])
    return greedy_choices(avatar, target)


def expert_policy(game: GameSpec, seed: int = 0, policy: str = "go_to_goal"):
    """An imagination policy callback (see world.imagine.Policy): the behaviour policy reading the
    imagined observations with the game's true roles."""
    policy_index(policy)  # a clear error for unknown names, before imagining
    ids = role_ids(game)

    def act(obs: np.ndarray, idx: np.ndarray, t: int) -> np.ndarray:
        return expert_actions(obs[:, -1], ids, t, np.asarray(idx) + seed, policy)

    return act
